"""Issue 12: a bounded soak of a real `tmoc serve` on loopback: mixed task, session, SSE and
burst-then-idle traffic; memory and file handles stay flat and the worker never stalls.

`TMOC_SOAK_S` sets the length (default 60 s in the suite, at least five cycles: about 80 s
with the start; 100 s until the suite moved to two workers; a 600 s run was quoted when it
was written). Each cycle: a tiny task watched through its event stream, a robot session
with two observations then closed, a burst of 24 concurrent reads (unknown ids included),
then 11 s idle so that the server's thread pool retires its threads (the case that leaked
one SQLite connection per recycled thread, and that killed Ray when it was started on one).
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
import pytest

from coordinator.loop.reality import SimulatedReality

from .conftest import Server, drive_episode, stream_events

SOAK_S = float(os.environ.get("TMOC_SOAK_S", "60"))
MIN_CYCLES = 5             # three after the two warm-up cycles: a trend, not one difference
TASK = {"agent": "tmoc", "particles": 2, "episodes": 1, "max_steps": 2, "seed": 1}

pytestmark = [pytest.mark.slow, pytest.mark.timeout(int(SOAK_S) + 400)]


def _fds(pid: int) -> tuple[int, int]:
    """(all open descriptors, descriptors on the database's files) of a process."""
    fd_dir = Path(f"/proc/{pid}/fd")
    total = db = 0
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        total += 1
        db += ".sqlite" in target
    return total, db


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def _session(c: httpx.Client, robot: SimulatedReality, seed: int) -> None:
    start = robot.start_episode(np.random.default_rng(seed))
    r = c.post("/v1/sessions", json={"particles": 2, "episodes": 1, "max_steps": 2, "seed": seed,
                                     "observation": {"configuration": start.configuration.to_dict()}})
    assert r.status_code == 201, r.text
    drive_episode(c, r.json()["id"], robot, r.json()["next"])
    assert c.delete(f"/v1/sessions/{r.json()['id']}").status_code == 200


def _burst(base: str, sid_hint: str) -> list[int]:
    paths = ["/health", "/v1/tasks?limit=5", "/v1/sessions?limit=5",
             "/v1/sessions/s_unknown_{i}/next", f"/v1/tasks/{sid_hint}/curve",
             f"/v1/tasks/{sid_hint}/belief"]

    def get(i: int) -> int:
        return httpx.get(base + paths[i % len(paths)].format(i=i), timeout=60).status_code

    with ThreadPoolExecutor(8) as pool:
        return list(pool.map(get, range(24)))


def test_soak_memory_handles_and_worker_stay_flat(tmp_path):
    srv = Server(tmp_path / "soak.sqlite", "--max-queued", "16", "--max-sessions", "4",
                 token=None).start()
    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.045)})
    samples, cycle = [], 0
    try:
        with srv.client() as c:
            t_end = time.monotonic() + SOAK_S
            while time.monotonic() < t_end or cycle < MIN_CYCLES:
                task = c.post("/v1/tasks", json={**TASK, "seed": cycle}).json()["id"]
                _session(c, robot, cycle)
                events = stream_events(c, task, timeout=120)
                assert events[-1]["data"]["status"] == "succeeded", events[-1]
                codes = _burst(srv.base, task)
                assert set(codes) <= {200, 404, 409}, codes
                time.sleep(11)
                health = c.get("/health")
                assert health.status_code == 200 and health.json()["worker"]["ok"], health.text
                fds, db_fds = _fds(srv.proc.pid)
                samples.append({"cycle": cycle, "fds": fds, "db_fds": db_fds,
                                "rss_mb": _rss_mb(srv.proc.pid)})
                cycle += 1
    finally:
        robot.close()
        srv.stop()
    # The first two cycles start Ray and fill the caches: with scene pictures on (issue 16)
    # CI measured 225, 238, then a step to 268 MB at the second cycle and 268-278 MB over
    # the next ten (b5f1c31). The cause of that step is not yet pinned down (see the
    # closing note); the bound below still catches a per-cycle leak.
    warm = samples[2:]
    report = "\n".join(str(s) for s in samples)
    print(report)
    # Handles: flat (each SQLite connection holds 3: db, -wal, -shm; at most 8 idle + the
    # writer, whatever the traffic), and no growth after the warm-up.
    assert max(s["db_fds"] for s in samples) <= 3 * 9 + 1, report
    assert warm[-1]["fds"] <= warm[0]["fds"] + 4, report
    # Memory: no trend (last samples within 40 MB of the first warm ones).
    first = min(s["rss_mb"] for s in warm[:2])
    last = max(s["rss_mb"] for s in warm[-2:])
    assert last - first < 40, report
