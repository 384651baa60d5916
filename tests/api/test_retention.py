"""Storage that can be reclaimed (issue 38, finding 6): a finished task's and a closed
session's rows are purged on request, `--retain-days` purges what is older at start-up,
a session's observations leave once its episode is recorded, and what one task or
session may store is capped at creation. In-process routes over a real SQLite store; the
sessions use an agent without particle worlds (no Ray)."""
from __future__ import annotations

import sqlite3
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from api.settings import Settings
from api.store import Store
from coordinator.loop.reality import SimulatedReality

from .conftest import drive_episode


def _count(db, table: str, column: str, run_id: str) -> int:
    with sqlite3.connect(db) as raw:
        return raw.execute(f"SELECT COUNT(*) FROM {table} WHERE {column} = ?", (run_id,)).fetchone()[0]


def _session(c: TestClient, robot, episodes: int = 2) -> tuple[str, dict]:
    start = robot.start_episode(np.random.default_rng(0))
    r = c.post("/v1/sessions", json={"agent": "tmp_rl", "episodes": episodes, "max_steps": 3, "n_blocks": 3,
                                     "observation": {"configuration": start.configuration.to_dict()}})
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["next"]


@pytest.fixture
def robot():
    r = SimulatedReality("container", {"n_blocks": 3}, {"block_sizes": np.full(3, 0.045)})
    yield r
    r.close()


def test_a_closed_session_is_purged_and_its_observations_leave_with_its_episode(tmp_path, robot):
    db = tmp_path / "purge.sqlite"
    with TestClient(create_app(Settings(db=str(db)))) as c:
        sid, nxt = _session(c, robot)
        r = c.post(f"/v1/sessions/{sid}/purge")
        assert r.status_code == 409 and "close it" in r.text                  # active: not purged
        drive_episode(c, sid, robot, nxt)
        # The episode is recorded: its observations are no longer kept (they rebuild a
        # running episode only); its step records and episode row stay readable.
        assert _count(db, "session_steps", "session_id", sid) == 0
        assert _count(db, "steps", "run_id", sid) > 0 and _count(db, "episodes", "run_id", sid) == 1
        assert c.delete(f"/v1/sessions/{sid}").status_code == 200
        purged = c.post(f"/v1/sessions/{sid}/purge")
        assert purged.status_code == 200, purged.text
        body = purged.json()
        assert body["status"] == "closed" and body["purged"]["sessions"] == 1 and body["purged"]["steps"] > 0
        assert c.get(f"/v1/sessions/{sid}").status_code == 404
        assert c.post(f"/v1/sessions/{sid}/purge").status_code == 404
        assert _count(db, "steps", "run_id", sid) == _count(db, "episodes", "run_id", sid) == 0


def test_a_finished_task_is_purged_and_a_queued_one_is_not(tmp_path):
    db = tmp_path / "tasks.sqlite"
    store = Store(str(db))
    try:
        store.create_task("t_done", {"episodes": 1})
        store.create_task("t_waits", {"episodes": 1})
        with sqlite3.connect(db) as raw:
            raw.execute("UPDATE tasks SET status = 'succeeded' WHERE id = 't_done'")
            raw.execute("INSERT INTO episodes (run_id, episode, record, created_at) VALUES ('t_done', 0, '{}', 0)")
        assert store.purge_task("t_waits") == ("queued", {})
        status, purged = store.purge_task("t_done")
        assert status == "succeeded" and purged["tasks"] == 1 and purged["episodes"] == 1
        assert store.get_task("t_done") is None and store.get_task("t_waits") is not None
        assert store.purge_task("t_nowhere") is None
    finally:
        store.close()


def test_retain_days_purges_what_is_older_at_start_up(tmp_path, robot):
    db = tmp_path / "old.sqlite"
    with TestClient(create_app(Settings(db=str(db)))) as c:
        old, nxt = _session(c, robot, episodes=1)
        drive_episode(c, old, robot, nxt)
        recent, _ = _session(c, robot, episodes=1)
        assert c.delete(f"/v1/sessions/{recent}").status_code == 200
    with sqlite3.connect(db) as raw:           # the first one finished 3 days ago
        raw.execute("UPDATE sessions SET updated_at = ? WHERE id = ?", (time.time() - 3 * 86400, old))
    with TestClient(create_app(Settings(db=str(db), retain_days=2))) as c:
        deadline = time.monotonic() + 20
        while c.get(f"/v1/sessions/{old}").status_code != 404 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert c.get(f"/v1/sessions/{old}").status_code == 404
        assert c.get(f"/v1/sessions/{recent}").status_code == 200           # 2 days not past
        assert _count(db, "steps", "run_id", old) == 0


def test_what_a_session_may_store_is_capped_at_creation(tmp_path, robot):
    with TestClient(create_app(Settings(db=str(tmp_path / "cap.sqlite"), max_stored_steps=50))) as c:
        start = robot.start_episode(np.random.default_rng(0))
        r = c.post("/v1/sessions", json={"agent": "tmp_rl", "episodes": 20, "max_steps": 3, "n_blocks": 3,
                                         "observation": {"configuration": start.configuration.to_dict()}})
        assert r.status_code == 422 and r.json()["message"].startswith("episodes:"), r.text
        assert "--max-stored-steps" in r.text
        r = c.post("/v1/tasks", json={"episodes": 20, "max_steps": 3, "particles": 2})
        assert r.status_code == 422 and r.json()["message"].startswith("episodes:"), r.text
