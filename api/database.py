"""The service's SQLite file: its tables, their in-place migration, and the lock that
keeps one server per file.

Tables:
  tasks             one row per task: spec, status, progress, latest episode record, the
                    belief summary and the runner checkpoint at the last episode boundary
  episodes          one row per (run, episode): the episode record. The primary key makes a
                    replayed episode impossible to store twice
  sessions          external-robot sessions: spec, status, checkpoint at the last episode
                    boundary, the current episode's initial observation, a mirror for reads
  frames            scene pictures of a task (PNG and metadata), at most `max_frames` per
                    task: the oldest are deleted when a new one comes
  session_steps     the observations of a session's current episode, in order; with the
                    checkpoint they rebuild the session exactly after a restart
  steps             one row per (task or session, episode, step): the step's record
                    (coordinator/step_record.py, zlib-compressed JSON) that `GET
                    .../export` writes as MCAP
"""
from __future__ import annotations

import sqlite3
from pathlib import Path

SCHEMA_VERSION = 1

SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS tasks (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE,
    spec TEXT NOT NULL,
    status TEXT NOT NULL,
    episodes INTEGER NOT NULL,
    episodes_done INTEGER NOT NULL DEFAULT 0,
    cancel_requested INTEGER NOT NULL DEFAULT 0,
    attempts INTEGER NOT NULL DEFAULT 0,
    created_at REAL NOT NULL,
    started_at REAL,
    finished_at REAL,
    updated_at REAL NOT NULL,
    error TEXT,
    latest TEXT,
    belief TEXT,
    checkpoint TEXT,
    result TEXT
);
CREATE INDEX IF NOT EXISTS tasks_status ON tasks (status, seq);
CREATE TABLE IF NOT EXISTS episodes (
    run_id TEXT NOT NULL,
    episode INTEGER NOT NULL,
    record TEXT NOT NULL,
    created_at REAL NOT NULL,
    PRIMARY KEY (run_id, episode)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS sessions (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    id TEXT NOT NULL UNIQUE,
    spec TEXT NOT NULL,
    status TEXT NOT NULL,
    created_at REAL NOT NULL,
    updated_at REAL NOT NULL,
    episodes_done INTEGER NOT NULL DEFAULT 0,
    in_episode INTEGER NOT NULL DEFAULT 0,
    step INTEGER NOT NULL DEFAULT 0,
    checkpoint TEXT NOT NULL,
    episode_start TEXT,
    pending TEXT,
    posterior TEXT,
    belief TEXT,
    latest TEXT
);
CREATE TABLE IF NOT EXISTS frames (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id TEXT NOT NULL,
    name TEXT NOT NULL,
    meta TEXT NOT NULL,
    png BLOB NOT NULL,
    created_at REAL NOT NULL,
    UNIQUE (run_id, name)
);
CREATE TABLE IF NOT EXISTS steps (
    run_id TEXT NOT NULL,
    episode INTEGER NOT NULL,
    step INTEGER NOT NULL,
    record BLOB NOT NULL,
    PRIMARY KEY (run_id, episode, step)
) WITHOUT ROWID;
CREATE TABLE IF NOT EXISTS session_steps (
    session_id TEXT NOT NULL,
    episode INTEGER NOT NULL,
    step INTEGER NOT NULL,
    observation TEXT NOT NULL,
    report TEXT NOT NULL,
    PRIMARY KEY (session_id, episode, step)
) WITHOUT ROWID;
"""


# Columns added after schema version 1 shipped: (table, column, type). Added in place at
# start-up, so a database written by an earlier version keeps working.
ADDED_COLUMNS = (
    ("sessions", "last_reply", "TEXT"),     # the last accepted observation and its reply
    ("tasks", "transition", "TEXT"),        # T per context at the last episode boundary
)


def add_missing_columns(db: sqlite3.Connection) -> None:
    for table, column, typ in ADDED_COLUMNS:
        have = {r[1] for r in db.execute(f"PRAGMA table_info({table})").fetchall()}
        if column not in have:
            db.execute(f"ALTER TABLE {table} ADD COLUMN {column} {typ}")


def create_schema(db: sqlite3.Connection) -> None:
    """Create what is missing (idempotent), stamp the schema version, add later columns."""
    db.executescript(SCHEMA)          # idempotent; executescript manages its own commit
    db.execute("INSERT OR IGNORE INTO meta (key, value) VALUES ('schema_version', ?)",
               (str(SCHEMA_VERSION),))
    add_missing_columns(db)


def lock_database(path: str | Path):
    """Hold an exclusive lock on the database file itself for this process's lifetime
    (released by the kernel when the process dies, even by SIGKILL): two servers on one
    database would both resume the same interrupted tasks.

    The lock is a ``flock`` on the file's inode, not a name: a symlink, a hard link or
    another spelling of the path reaches the same inode and is refused. (``flock`` and
    SQLite's POSIX record locks are independent on Linux; the descriptor is kept open for
    the process's life, because closing any descriptor of a file would drop SQLite's own
    POSIX locks on it.) The folder is created first. Returns the open file (keep it
    referenced, close it after the store); raises OSError if another process holds it.
    """
    import fcntl
    import os

    if str(path) == ":memory:" or str(path).startswith("file:"):
        raise OSError("an in-memory or URI database cannot be shared by the server's threads "
                      "and workers; give a file path")
    real = Path(path).expanduser().resolve()
    real.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(real, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise OSError(f"the database is in use by another tmoc serve (lock on {real})") from None
    return os.fdopen(fd, "rb", buffering=0)
