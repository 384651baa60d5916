"""Kill the server (SIGKILL) mid-task and start it again on the same database (issue 5).

The running task resumes from its last checkpoint and finishes with every episode stored
exactly once, and with the same episodes as an uninterrupted run of the same spec; the task
that was queued runs; a robot session resumes at the very step it was at.
"""
from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from coordinator.loop.reality import SimulatedReality

from .conftest import Server, stream_events, wait_for

# Slow: real tasks on a served Ray. Timeout: two server starts (90 s each) and up to three event streams.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SPEC = {"agent": "tmoc", "particles": 3, "episodes": 5, "max_steps": 3, "seed": 5}
TIMINGS = ("wall_s", "physics_s", "planning_s", "counterfactual_s")


def _strip(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in TIMINGS} for r in records]


def test_sigkill_mid_task_then_restart_resumes_without_loss_or_duplicates(tmp_path):
    db = tmp_path / "restart.sqlite"
    first = Server(db, token=None).start()
    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.050)})
    try:
        with first.client() as c:
            task = c.post("/v1/tasks", json=SPEC).json()["id"]
            queued = c.post("/v1/tasks", json={"agent": "tmp_rl", "episodes": 1, "max_steps": 1,
                                               "n_blocks": 2}).json()["id"]
            # A robot session two steps in.
            obs = robot.start_episode(np.random.default_rng(0))
            r = c.post("/v1/sessions", json={"particles": 4, "episodes": 2, "max_steps": 6, "seed": 2,
                                             "observation": {"configuration": obs.configuration.to_dict()}})
            assert r.status_code == 201, r.text
            session, step = r.json()["id"], r.json()["next"]
            for _ in range(2):
                out = robot.execute(np.array(step["trajectory"]), step["action"])
                r = c.post(f"/v1/sessions/{session}/observations",
                           json={"action": step["action"], "step_id": step["step_id"],
                                 "configuration": out.configuration.to_dict()})
                assert r.status_code == 200, r.text
                step = r.json()["next"]
            wait_for(lambda: c.get(f"/v1/tasks/{task}").json()["progress"]["episodes_done"] >= 1,
                     every=0.05, what="the first episode")
        first.kill()
        with sqlite3.connect(db) as con:
            status, done = con.execute("SELECT status, episodes_done FROM tasks WHERE id = ?",
                                       (task,)).fetchone()
        assert status == "running" and 1 <= done < SPEC["episodes"], (status, done)

        second = Server(db, token=None).start()
        try:
            with second.client() as c:
                # The session is rebuilt where it was: same pending action and trajectory.
                # (it is replayed on a thread at start-up: until then, 409 "being restored")
                wait_for(lambda: c.get(f"/v1/sessions/{session}/next").status_code == 200,
                         every=0.1, what="the session's restore")
                nxt = c.get(f"/v1/sessions/{session}/next").json()["pending"]
                assert nxt["action"] == step["action"] and nxt["step"] == 2
                np.testing.assert_array_equal(nxt["trajectory"], step["trajectory"])
                out = robot.execute(np.array(nxt["trajectory"]), nxt["action"])
                r = c.post(f"/v1/sessions/{session}/observations",
                           json={"action": nxt["action"], "step_id": nxt["step_id"],
                                 "configuration": out.configuration.to_dict()})
                assert r.status_code == 200, r.text

                events = stream_events(c, task)
                assert events[-1]["data"]["status"] == "succeeded", events[-1]
                view = c.get(f"/v1/tasks/{task}").json()
                assert view["attempts"] == 2 and view["progress"]["episodes_done"] == SPEC["episodes"]
                stored = c.get(f"/v1/tasks/{task}/episodes").json()
                assert [e["episode"] for e in stored] == list(range(SPEC["episodes"]))
                assert stream_events(c, queued)[-1]["data"]["status"] == "succeeded"

                # Same episodes as a run that was never interrupted.
                again = c.post("/v1/tasks", json=SPEC).json()["id"]
                assert stream_events(c, again)[-1]["data"]["status"] == "succeeded"
                assert _strip(c.get(f"/v1/tasks/{again}/episodes").json()) == _strip(stored)
        finally:
            second.stop()
        with sqlite3.connect(db) as con:
            assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
            rows = con.execute("SELECT COUNT(*), COUNT(DISTINCT episode) FROM episodes WHERE run_id = ?",
                               (task,)).fetchone()
        assert rows == (SPEC["episodes"], SPEC["episodes"])
    finally:
        robot.close()
        first.kill()
