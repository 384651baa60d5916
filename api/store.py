"""The service's durable state in one SQLite file (stdlib sqlite3, WAL mode): tasks,
their episodes and frames, robot sessions. The file itself (tables, migration, the
one-server lock) is :mod:`api.database`.

An episode row, the checkpoint it belongs to and the progress counter are written in one
transaction, so after a crash the checkpoint and the stored episodes always agree: a resumed
run starts at the first episode that is not stored, and no episode is lost or duplicated.

Every thread gets its own connection (WAL readers never block the writer); writes are
serialised by a process-wide lock and run as ``BEGIN IMMEDIATE`` transactions.
"""
from __future__ import annotations

import json
import logging
import sqlite3
import threading
import time
import uuid
import zlib
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from .database import create_schema

_log = logging.getLogger("tmoc.api")

TERMINAL = ("succeeded", "failed", "cancelled")

_TASK_JSON = ("spec", "latest", "belief", "checkpoint", "result", "transition")
_SESSION_JSON = ("spec", "checkpoint", "episode_start", "pending", "posterior", "belief", "latest",
                 "last_reply")


_INSERT_STEP = "INSERT OR IGNORE INTO steps (run_id, episode, step, record) VALUES (?, ?, ?, ?)"


def _step_row(run_id: str, record: dict) -> tuple:
    """A step record as a row of ``steps`` (its JSON zlib-compressed: trajectories are most
    of it and compress ~5x)."""
    return (run_id, int(record["episode"]), int(record["step"]),
            zlib.compress(json.dumps(record, separators=(",", ":")).encode(), 6))


def _dumps(value: Any) -> str | None:
    return None if value is None else json.dumps(value, separators=(",", ":"), allow_nan=False)


def _listed(row: sqlite3.Row, json_cols: tuple[str, ...]) -> dict | None:
    """A list's row, or None where a stored JSON column is corrupt (the list leaves it out:
    ``api.views.shown``; issue 38: one bad `pending` made the whole session list a 500)."""
    try:
        return _row(row, json_cols)
    except ValueError:
        return None


def _episode_text(run_id: str, episode: int, text: str) -> str:
    """A stored episode record's JSON text, or a small valid stand-in naming the episode
    where the stored text is not JSON (issue 38: one bad row made `GET .../episodes` a 200
    with invalid JSON and an SSE `data: {`)."""
    try:
        json.loads(text)
        return text
    except (ValueError, TypeError):
        _log.error("episode %s of %s: the stored record is not valid JSON", episode, run_id)
        return json.dumps({"episode": episode, "corrupt": "the stored record is not valid JSON"})


def _row(row: sqlite3.Row | None, json_cols: tuple[str, ...], skip: tuple[str, ...] = ()) -> dict | None:
    if row is None:
        return None
    out = {}
    for k in row.keys():
        if k in skip:
            continue
        v = row[k]
        out[k] = json.loads(v) if (k in json_cols and v is not None) else v
    return out


class QueueFull(Exception):
    def __init__(self, queued: int, limit: int) -> None:
        super().__init__(f"{queued} tasks queued, limit {limit}")
        self.queued, self.limit = queued, limit


class Store:
    """SQLite-backed store; safe to use from any thread."""

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        if self.path != ":memory:":
            Path(self.path).expanduser().resolve().parent.mkdir(parents=True, exist_ok=True)
        self._write_lock = threading.RLock()
        self._pool_lock = threading.Lock()
        self._idle: list[sqlite3.Connection] = []
        self._write_conn: sqlite3.Connection | None = None
        self._closed = False
        with self._write_lock:
            db = self._writer()
            create_schema(db)

    # -- connections ---------------------------------------------------------------------
    # Reads borrow a connection from a small pool and give it back; writes use one
    # connection under the write lock. Thread-local connections leaked: the server's
    # thread pool recycles idle threads, and each new thread opened another connection
    # (file handles 8 -> 78 over four burst/idle cycles, measured).
    MAX_IDLE = 8

    def _connect(self) -> sqlite3.Connection:
        conn = sqlite3.connect(self.path, timeout=30.0, isolation_level=None,
                               check_same_thread=False)
        conn.row_factory = sqlite3.Row
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=NORMAL")
        conn.execute("PRAGMA busy_timeout=30000")
        conn.execute("PRAGMA foreign_keys=ON")
        return conn

    @contextmanager
    def _read(self) -> Iterator[sqlite3.Connection]:
        with self._pool_lock:
            conn = self._idle.pop() if self._idle else None
        if conn is None:
            conn = self._connect()
        try:
            yield conn
        finally:
            with self._pool_lock:
                keep = not self._closed and len(self._idle) < self.MAX_IDLE
                if keep:
                    self._idle.append(conn)
            if not keep:
                conn.close()

    def _writer(self) -> sqlite3.Connection:
        if self._write_conn is None:
            self._write_conn = self._connect()
        return self._write_conn

    @contextmanager
    def _write(self) -> Iterator[sqlite3.Connection]:
        with self._write_lock:
            db = self._writer()
            db.execute("BEGIN IMMEDIATE")
            try:
                yield db
            except BaseException:
                try:
                    db.execute("ROLLBACK")
                except sqlite3.Error:        # the failed statement may have ended it already
                    pass
                raise
            else:
                db.execute("COMMIT")

    def _one(self, sql: str, args: tuple = ()) -> sqlite3.Row | None:
        with self._read() as db:
            return db.execute(sql, args).fetchone()

    def _all(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        with self._read() as db:
            return db.execute(sql, args).fetchall()

    def open_connections(self) -> int:
        """Connections this store holds open now (the pool's idle ones and the writer)."""
        with self._pool_lock:
            return len(self._idle) + (self._write_conn is not None)

    def journal_mode(self) -> str:
        with self._read() as db:
            return db.execute("PRAGMA journal_mode").fetchone()[0]

    def close(self) -> None:
        with self._pool_lock:
            self._closed = True
            conns, self._idle = self._idle, []
        with self._write_lock:
            if self._write_conn is not None:
                conns.append(self._write_conn)
                self._write_conn = None
        for c in conns:
            try:
                c.close()
            except sqlite3.Error:  # pragma: no cover
                pass

    # -- tasks ---------------------------------------------------------------------------
    def create_task(self, task_id: str, spec: dict, max_queued: int | None = None) -> dict:
        """Insert a queued task; raises QueueFull when `max_queued` tasks already wait."""
        now = time.time()
        with self._write() as db:
            if max_queued is not None:
                queued = db.execute("SELECT COUNT(*) FROM tasks WHERE status = 'queued'").fetchone()[0]
                if queued >= max_queued:
                    raise QueueFull(queued, max_queued)
            db.execute(
                "INSERT INTO tasks (id, spec, status, episodes, created_at, updated_at) "
                "VALUES (?, ?, 'queued', ?, ?, ?)",
                (task_id, _dumps(spec), int(spec["episodes"]), now, now))
        return self.get_task(task_id)

    def get_task(self, task_id: str, *, checkpoint: bool = False, belief: bool = False,
                 transition: bool = False) -> dict | None:
        cols = "*"
        row = self._one(f"SELECT {cols} FROM tasks WHERE id = ?", (task_id,))
        skip = tuple(c for c, keep in (("checkpoint", checkpoint), ("belief", belief),
                                       ("transition", transition)) if not keep)
        return _row(row, _TASK_JSON, skip)

    def task_status(self, task_id: str) -> tuple[str, int] | None:
        row = self._one("SELECT status, episodes_done FROM tasks WHERE id = ?",
                                   (task_id,))
        return None if row is None else (row[0], row[1])

    def list_tasks(self, limit: int, offset: int, status: str | None = None) -> tuple[list[dict], int]:
        cols = ("seq, id, spec, status, episodes, episodes_done, cancel_requested, attempts, "
                "created_at, started_at, finished_at, updated_at, error, latest, result")
        if status:
            rows = self._all(f"SELECT {cols} FROM tasks WHERE status = ? ORDER BY seq DESC "
                             "LIMIT ? OFFSET ?", (status, limit, offset))
            total = self._one("SELECT COUNT(*) FROM tasks WHERE status = ?", (status,))[0]
        else:
            rows = self._all(f"SELECT {cols} FROM tasks ORDER BY seq DESC LIMIT ? OFFSET ?",
                             (limit, offset))
            total = self._one("SELECT COUNT(*) FROM tasks")[0]
        return [_listed(r, _TASK_JSON) for r in rows], total

    def count_tasks(self, status: str) -> int:
        return self._one("SELECT COUNT(*) FROM tasks WHERE status = ?", (status,))[0]

    def next_runnable(self) -> str | None:
        """The task to run next: an interrupted run (status `running` while no worker runs
        it: after a restart), else the oldest queued task."""
        row = self._one(
            "SELECT id FROM tasks WHERE status IN ('running', 'queued') "
            "ORDER BY CASE status WHEN 'running' THEN 0 ELSE 1 END, seq LIMIT 1")
        return None if row is None else row[0]

    def claim_task(self, task_id: str) -> dict | None:
        """queued -> running (or pick up an interrupted running task); None if not runnable."""
        now = time.time()
        with self._write() as db:
            row = db.execute("SELECT status FROM tasks WHERE id = ?", (task_id,)).fetchone()
            if row is None or row[0] not in ("queued", "running"):
                return None
            db.execute("UPDATE tasks SET status = 'running', attempts = attempts + 1, "
                       "started_at = COALESCE(started_at, ?), updated_at = ? WHERE id = ?",
                       (now, now, task_id))
        return self.get_task(task_id, checkpoint=True)

    def record_episode(self, run_id: str, record: dict, checkpoint: dict | None,
                       belief: dict | None, transition: list | None = None,
                       steps: list[dict] | None = None) -> bool:
        """Store one task episode, its checkpoint, progress (and T per context, and its
        step records) atomically; False if the episode was already stored (nothing is
        then changed)."""
        now = time.time()
        rec, ckpt, bel = _dumps(record), _dumps(checkpoint), _dumps(belief)   # outside the lock
        trans = _dumps(transition)
        packed = [_step_row(run_id, r) for r in steps or ()]
        with self._write() as db:
            cur = db.execute("INSERT INTO episodes (run_id, episode, record, created_at) VALUES (?, ?, ?, ?) "
                             "ON CONFLICT (run_id, episode) DO NOTHING",
                             (run_id, int(record["episode"]), rec, now))
            if cur.rowcount == 0:
                return False
            db.executemany(_INSERT_STEP, packed)
            db.execute("UPDATE tasks SET episodes_done = (SELECT COUNT(*) FROM episodes WHERE run_id = ?), "
                       "latest = ?, checkpoint = COALESCE(?, checkpoint), belief = COALESCE(?, belief), "
                       "transition = COALESCE(?, transition), updated_at = ? WHERE id = ?",
                       (run_id, rec, ckpt, bel, trans, now, run_id))
        return True

    def finish_task(self, task_id: str, status: str, *, error: str | None = None,
                    result: dict | None = None) -> None:
        now = time.time()
        with self._write() as db:
            db.execute("UPDATE tasks SET status = ?, error = ?, result = COALESCE(?, result), "
                       "finished_at = ?, updated_at = ? WHERE id = ? AND status IN ('queued', 'running')",
                       (status, error, _dumps(result), now, now, task_id))

    def cancel_task(self, task_id: str) -> tuple[str, bool] | None:
        """Cancel: a queued task is cancelled at once; a running one is flagged (it stops at
        the next episode boundary). Returns (status after the call, whether this call
        changed anything); None for an unknown id. A finished task (cancelled included) is
        left as it is."""
        now = time.time()
        with self._write() as db:
            row = db.execute("SELECT status, cancel_requested FROM tasks WHERE id = ?",
                             (task_id,)).fetchone()
            if row is None:
                return None
            status = row[0]
            if status == "queued":
                db.execute("UPDATE tasks SET status = 'cancelled', cancel_requested = 1, "
                           "finished_at = ?, updated_at = ? WHERE id = ?", (now, now, task_id))
                return "cancelled", True
            if status == "running":
                db.execute("UPDATE tasks SET cancel_requested = 1, updated_at = ? WHERE id = ?",
                           (now, task_id))
                return status, True
            return status, False

    def steps(self, run_id: str, batch: int = 200) -> Iterator[dict]:
        """The step records of a task or session, in order (read `batch` rows at a time:
        an export of a long session holds one batch in memory, not the session)."""
        after = (-1, -1)
        while True:
            rows = self._all("SELECT episode, step, record FROM steps WHERE run_id = ? AND (episode, step) > (?, ?) "
                             "ORDER BY episode, step LIMIT ?", (run_id, after[0], after[1], batch))
            for _, _, blob in rows:
                yield json.loads(zlib.decompress(blob))
            if len(rows) < batch:
                return
            after = (rows[-1][0], rows[-1][1])

    def episodes(self, run_id: str, after: int = -1, limit: int | None = None) -> list[tuple[int, str]]:
        """(episode, record JSON text) with episode > `after`, in order."""
        sql = "SELECT episode, record FROM episodes WHERE run_id = ? AND episode > ? ORDER BY episode"
        args: tuple = (run_id, after)
        if limit is not None:
            sql += " LIMIT ?"
            args += (limit,)
        return [(r[0], _episode_text(run_id, r[0], r[1])) for r in self._all(sql, args)]

    # -- frames --------------------------------------------------------------------------
    def add_frame(self, run_id: str, name: str, png: bytes, meta: dict, max_frames: int) -> None:
        """Store (or replace: a resumed episode renders its frames again) one frame; keep the
        task's newest `max_frames`."""
        now = time.time()
        text = _dumps(meta)
        with self._write() as db:
            db.execute("INSERT INTO frames (run_id, name, meta, png, created_at) VALUES (?, ?, ?, ?, ?) "
                       "ON CONFLICT (run_id, name) DO UPDATE SET meta = excluded.meta, "
                       "png = excluded.png, created_at = excluded.created_at",
                       (run_id, name, text, sqlite3.Binary(png), now))
            db.execute("DELETE FROM frames WHERE run_id = ? AND seq NOT IN (SELECT seq FROM frames "
                       "WHERE run_id = ? ORDER BY seq DESC LIMIT ?)", (run_id, run_id, int(max_frames)))

    def frames(self, run_id: str) -> list[dict]:
        """The task's frames' metadata, oldest first (with `created_at`)."""
        rows = self._all("SELECT meta, created_at FROM frames WHERE run_id = ? ORDER BY seq", (run_id,))
        return [{**json.loads(r[0]), "created_at": r[1]} for r in rows]

    def frame_png(self, run_id: str, name: str) -> bytes | None:
        row = self._one("SELECT png FROM frames WHERE run_id = ? AND name = ?", (run_id, name))
        return None if row is None else bytes(row[0])

    # -- sessions ------------------------------------------------------------------------
    def create_session(self, session_id: str, spec: dict, checkpoint: dict, mirror: dict,
                       max_active: int | None = None, idle_s: float = float("inf")) -> None:
        """Store a new session; QueueFull when `max_active` sessions are active and were
        changed within the last `idle_s` seconds (idle ones do not count)."""
        now = time.time()
        with self._write() as db:
            if max_active is not None:
                active = db.execute("SELECT COUNT(*) FROM sessions WHERE status = 'active' AND updated_at > ?",
                                    (now - idle_s,)).fetchone()[0]
                if active >= max_active:
                    raise QueueFull(active, max_active)
            db.execute(
                "INSERT INTO sessions (id, spec, status, created_at, updated_at, checkpoint, "
                "episode_start, in_episode, pending, posterior, belief) "
                "VALUES (?, ?, 'active', ?, ?, ?, ?, ?, ?, ?, ?)",
                (session_id, _dumps(spec), now, now, _dumps(checkpoint),
                 _dumps(mirror.get("episode_start")), int(mirror.get("episode_start") is not None),
                 _dumps(mirror.get("pending")), _dumps(mirror.get("posterior")),
                 _dumps(mirror.get("belief"))))

    def get_session(self, session_id: str, *, checkpoint: bool = False, belief: bool = False) -> dict | None:
        row = self._one("SELECT * FROM sessions WHERE id = ?", (session_id,))
        skip = tuple(c for c, keep in (("checkpoint", checkpoint), ("episode_start", checkpoint),
                                       ("belief", belief)) if not keep)
        return _row(row, _SESSION_JSON, skip)

    def list_sessions(self, limit: int, offset: int) -> tuple[list[dict], int]:
        rows = self._all("SELECT seq, id, spec, status, created_at, updated_at, episodes_done, in_episode, "
                         "step, pending, posterior, latest, last_reply FROM sessions ORDER BY seq DESC LIMIT ? OFFSET ?",
                         (limit, offset))
        total = self._one("SELECT COUNT(*) FROM sessions")[0]
        return [_listed(r, _SESSION_JSON) for r in rows], total

    def sessions_to_restore(self, idle_s: float = float("inf")) -> list[str]:
        """Active sessions in the middle of an episode and changed within the last `idle_s`
        seconds, oldest first: after a restart their episode is replayed (see
        ``SessionManager.restore``); idle ones wait for their robot to come back."""
        since = time.time() - idle_s             # -inf when no session is ever idle
        rows = self._all("SELECT id FROM sessions WHERE status = 'active' AND in_episode = 1 "
                         "AND updated_at > ? ORDER BY seq", (since,))
        return [r[0] for r in rows]

    def session_steps(self, session_id: str, episode: int) -> list[dict]:
        rows = self._all(
            "SELECT observation FROM session_steps WHERE session_id = ? AND episode = ? ORDER BY step",
            (session_id, episode))
        return [json.loads(r[0]) for r in rows]

    def session_start_episode(self, session_id: str, episode_start: dict, pending: dict | None) -> None:
        now = time.time()
        with self._write() as db:
            db.execute("UPDATE sessions SET episode_start = ?, in_episode = 1, step = 0, pending = ?, "
                       "updated_at = ? WHERE id = ?",
                       (_dumps(episode_start), _dumps(pending), now, session_id))

    def session_set_pending(self, session_id: str, pending: dict | None) -> None:
        with self._write() as db:
            db.execute("UPDATE sessions SET pending = ?, updated_at = ? WHERE id = ?",
                       (_dumps(pending), time.time(), session_id))

    def session_record_step(self, session_id: str, episode: int, step: int, observation: dict,
                            report: dict, *, pending: dict | None, posterior: dict | None,
                            belief: dict | None, finished: dict | None = None,
                            checkpoint: dict | None = None, status: str = "active",
                            last_reply: dict | None = None, step_record: dict | None = None) -> None:
        """One observed step; when it ends the episode (`finished` is the episode record),
        also the episode row and the new checkpoint, in the same transaction. `last_reply`
        (the step id, the observation and the reply sent) answers a replay of this step."""
        now = time.time()
        packed = None if step_record is None else _step_row(session_id, step_record)
        with self._write() as db:
            db.execute("UPDATE sessions SET last_reply = ? WHERE id = ?", (_dumps(last_reply), session_id))
            if packed is not None:
                db.execute(_INSERT_STEP, packed)
            db.execute("INSERT INTO session_steps (session_id, episode, step, observation, report) "
                       "VALUES (?, ?, ?, ?, ?)",
                       (session_id, episode, step, _dumps(observation), _dumps(report)))
            if finished is not None:
                db.execute("INSERT INTO episodes (run_id, episode, record, created_at) VALUES (?, ?, ?, ?) "
                           "ON CONFLICT (run_id, episode) DO NOTHING",
                           (session_id, episode, _dumps(finished), now))
                # The episode's observations rebuild it only while it runs (with the
                # checkpoint before it); once its record and the new checkpoint are stored
                # they are dead weight (issue 38: ~1.5 KB a step, kept for ever).
                db.execute("DELETE FROM session_steps WHERE session_id = ? AND episode <= ?",
                           (session_id, episode))
                db.execute("UPDATE sessions SET checkpoint = ?, episode_start = NULL, in_episode = 0, "
                           "episodes_done = episodes_done + 1, latest = ?, status = ?, step = ?, "
                           "pending = NULL, posterior = ?, belief = COALESCE(?, belief), updated_at = ? "
                           "WHERE id = ?",
                           (_dumps(checkpoint), _dumps(finished), status, step + 1, _dumps(posterior),
                            _dumps(belief), now, session_id))
            else:
                db.execute("UPDATE sessions SET step = ?, pending = ?, posterior = ?, "
                           "belief = COALESCE(?, belief), updated_at = ? WHERE id = ?",
                           (step + 1, _dumps(pending), _dumps(posterior), _dumps(belief), now, session_id))

    def session_status(self, session_id: str) -> str | None:
        row = self._one("SELECT status FROM sessions WHERE id = ?", (session_id,))
        return None if row is None else row[0]

    def close_session(self, session_id: str) -> str | None:
        with self._write() as db:
            row = db.execute("SELECT status FROM sessions WHERE id = ?", (session_id,)).fetchone()
            if row is None:
                return None
            db.execute("UPDATE sessions SET status = 'closed', pending = NULL, updated_at = ? WHERE id = ?",
                       (time.time(), session_id))
            return "closed"


    # -- retention (issue 38) ------------------------------------------------------------
    def purge_task(self, task_id: str) -> tuple[str, dict[str, int]] | None:
        """Delete a finished task's stored rows (the task, its episodes, step records and
        frames) in one short transaction. (status, rows deleted per table); the counts are
        empty when the task has not finished (it is left as it is); None: no such task."""
        with self._write() as db:
            row = db.execute("SELECT status FROM tasks WHERE id = ?", (task_id,)).fetchone()
            if row is None:
                return None
            if row[0] not in TERMINAL:
                return row[0], {}
            return row[0], self._delete_run(db, task_id, "tasks")

    def purge_session(self, session_id: str) -> tuple[str, dict[str, int]] | None:
        """Delete a closed or finished session's stored rows (the session, its episodes,
        step records and observations). As `purge_task`: empty counts while it is active."""
        with self._write() as db:
            row = db.execute("SELECT status FROM sessions WHERE id = ?", (session_id,)).fetchone()
            if row is None:
                return None
            if row[0] == "active":
                return row[0], {}
            return row[0], self._delete_run(db, session_id, "sessions")

    @staticmethod
    def _delete_run(db: sqlite3.Connection, run_id: str, table: str) -> dict[str, int]:
        counts = {}
        for name, sql in (("episodes", "DELETE FROM episodes WHERE run_id = ?"),
                          ("steps", "DELETE FROM steps WHERE run_id = ?"),
                          ("frames", "DELETE FROM frames WHERE run_id = ?"),
                          ("session_steps", "DELETE FROM session_steps WHERE session_id = ?"),
                          (table, f"DELETE FROM {table} WHERE id = ?")):
            counts[name] = db.execute(sql, (run_id,)).rowcount
        return counts

    def export_counts(self, run_id: str) -> tuple[int, int]:
        """(step records, episode rows) stored for a run: what names its export."""
        steps = self._one("SELECT COUNT(*) FROM steps WHERE run_id = ?", (run_id,))[0]
        episodes = self._one("SELECT COUNT(*) FROM episodes WHERE run_id = ?", (run_id,))[0]
        return int(steps), int(episodes)

    def prune(self, older_than_s: float, now: float | None = None) -> dict[str, list[str]]:
        """Purge every finished task and every closed or finished session last changed more
        than `older_than_s` seconds ago (`tmoc serve --retain-days`), one run per
        transaction so that other writers wait at most one run's delete. The ids purged."""
        cutoff = (time.time() if now is None else now) - older_than_s
        marks = ", ".join("?" * len(TERMINAL))
        tasks = [r[0] for r in self._all(f"SELECT id FROM tasks WHERE status IN ({marks}) AND updated_at < ?",
                                         (*TERMINAL, cutoff))]
        sessions = [r[0] for r in self._all("SELECT id FROM sessions WHERE status != 'active' AND updated_at < ?",
                                            (cutoff,))]
        for t in tasks:
            self.purge_task(t)
        for s in sessions:
            self.purge_session(s)
        return {"tasks": tasks, "sessions": sessions}


def new_id(prefix: str) -> str:
    """A fresh task or session id (``t_...``, ``s_...``)."""
    return f"{prefix}_{uuid.uuid4().hex[:20]}"
