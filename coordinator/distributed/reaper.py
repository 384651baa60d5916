"""A watchdog that takes the processes a server started down with it (Linux).

A graceful stop of `tmoc serve` shuts its Ray down. After a `kill -9` nothing of the server
runs: Ray's GCS and raylet die with it, but two of Ray's agents wait a fixed 60 s for a GCS
that is gone before they exit (issue 25). The reaper is a small child process that, while
the server lives, notes the server's descendants every second; when its pipe from the
server closes without the word ``clean`` (the server died), it kills the ones it noted that
still run (each checked by its start time, so a reused pid is never hit).

    python -m coordinator.distributed.reaper PID        # stdin: the pipe from the server
"""
from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Collection

CLEAN = b"clean"


def _stat(pid: int) -> tuple[int, int, str] | None:
    """(parent pid, start time in clock ticks, state) of a live process, None if gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2:].split()     # the name may hold spaces and parentheses
    return int(fields[1]), int(fields[19]), fields[0]


def descendants(root: int) -> dict[int, int]:
    """Every live descendant of `root`: pid -> start time."""
    children: dict[int, list[int]] = {}
    starts: dict[int, int] = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            st = _stat(int(entry.name))
            if st is not None and st[2] != "Z":
                children.setdefault(st[0], []).append(int(entry.name))
                starts[int(entry.name)] = st[1]
    found, todo = {}, list(children.get(root, ()))
    while todo:
        pid = todo.pop()
        if pid in starts and pid not in found:
            found[pid] = starts[pid]
            todo.extend(children.get(pid, ()))
    return found


def alive(pid: int, start: int) -> bool:
    """Whether `pid` still runs as the process that started at `start` (not a zombie)."""
    st = _stat(pid)
    return st is not None and st[1] == start and st[2] != "Z"


def watch(server: int, every_s: float = 1.0) -> int:
    """Note `server`'s descendants until stdin closes; kill them unless told ``clean``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # Ctrl-C reaches the whole group: the server decides
    me = os.getpid()
    noted: dict[int, int] = {}
    said = b""
    while True:
        ready, _, _ = select.select([0], [], [], every_s)
        if ready:
            chunk = os.read(0, 64)
            if not chunk:
                break
            said += chunk
            continue
        noted.update({p: s for p, s in descendants(server).items() if p != me})
    if CLEAN in said:
        return 0
    for pid, start in noted.items():
        if alive(pid, start):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
    return 0


def sweep(root: int, exclude: Collection[int] = (), limit_s: float = 2.0) -> int:
    """Kill every descendant of `root` but `exclude`, round after round until none is
    left (or `limit_s` has passed); the number killed.

    For a clean exit of a process whose own Ray may not have finished starting: a process
    ``ray.init`` forks in the last moments before the exit can miss its parent-death signal
    (it is set in the child after the fork, so a parent gone first leaves it orphaned for
    good), and the workers and agents of a raylet killed that way outlive it by up to a
    minute. Killed from the top down (the whole tree is listed before the first kill, so
    an orphan is still found); a second round catches what a fork added meanwhile."""
    if not sys.platform.startswith("linux") or not Path("/proc/self/stat").exists():
        return 0
    killed, deadline = 0, time.monotonic() + limit_s
    while True:
        left = {p: s for p, s in descendants(root).items() if p not in exclude}
        if not left or time.monotonic() > deadline:
            return killed
        for pid, start in left.items():
            if alive(pid, start):
                try:
                    os.kill(pid, signal.SIGKILL)
                    killed += 1
                except OSError:
                    pass
        time.sleep(0.05)


def start_reaper() -> subprocess.Popen | None:
    """Start the reaper of this process (None where /proc is not there); tell it
    :func:`clean` at a clean exit."""
    if not sys.platform.startswith("linux") or not Path("/proc/self/stat").exists():
        return None
    return subprocess.Popen([sys.executable, "-m", "coordinator.distributed.reaper", str(os.getpid())],
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, close_fds=True)


def clean(reaper: subprocess.Popen | None) -> None:
    """A clean exit: the reaper leaves everything to the server's own shutdown."""
    if reaper is None or reaper.stdin is None:
        return
    try:
        reaper.stdin.write(CLEAN)
        reaper.stdin.close()
    except OSError:
        pass
    try:
        reaper.wait(5)
    except subprocess.TimeoutExpired:
        reaper.kill()


if __name__ == "__main__":
    raise SystemExit(watch(int(sys.argv[1])))
