"""api.client against real servers: tasks end to end, events resumed across a server
crash, a robot session driven by the runnable example (issue 16 item 4)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from api.client import TMOCClient, TMOCError

from .conftest import TOKEN, Server

# Slow: real tasks on a served Ray. Timeout: the robot-loop example's subprocess may take its 600 s.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(720)]

REPO = Path(__file__).resolve().parents[2]
TINY = {"agent": "tmoc", "particles": 3, "episodes": 2, "max_steps": 3, "seed": 4}


def test_submit_wait_and_read_a_task(server):
    with TMOCClient(server.base, token=TOKEN) as tmoc:
        assert tmoc.health()["status"] == "ok"
        assert "container" in {d["name"] for d in tmoc.domains()}
        task = tmoc.submit(**TINY)
        done = tmoc.wait(task, progress=False)
        assert done["status"] == "succeeded" and done["progress"]["episodes_done"] == 2
        assert [p["episode"] for p in tmoc.curve(task)["points"]] == [0, 1]
        assert tmoc.belief(task)["episodes_done"] == 2
        assert [e["episode"] for e in tmoc.episodes(task)] == [0, 1]
        with pytest.raises(TMOCError) as err:
            tmoc.cancel(task)
        assert err.value.status == 409
        with pytest.raises(TMOCError) as err:
            tmoc.submit(particles=0)
        assert err.value.status == 422 and err.value.message.startswith("particles:")
    with TMOCClient(server.base) as anon, pytest.raises(TMOCError) as err:
        anon.submit(**TINY)
    assert err.value.status == 401


def test_events_resume_across_a_server_crash(tmp_path):
    srv = Server(tmp_path / "crash.sqlite", token=None).start()
    try:
        with TMOCClient(srv.base) as tmoc:
            task = tmoc.submit(**{**TINY, "episodes": 5})
            episodes, statuses = [], []
            for event in tmoc.events(task):
                if event["event"] == "episode":
                    episodes.append(event["data"]["episode"])
                    if len(episodes) == 1:        # kill -9 mid-task, then restart on the same db
                        srv.kill()
                        srv.start()
                else:
                    statuses.append(event["data"]["status"])
            assert episodes == [0, 1, 2, 3, 4], episodes     # each once, in order
            assert statuses[-1] == "succeeded"
    finally:
        srv.stop()


def test_the_robot_loop_example_runs_a_session_start_to_finish(server, tmp_path):
    script = REPO / "docs" / "examples" / "robot_loop.py"
    proc = subprocess.run([sys.executable, str(script), "--url", server.base, "--token", TOKEN,
                           "--episodes", "2", "--particles", "12", "--max-steps", "12"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(out["utilities"]) == 2
    assert abs(out["posterior_size_mm"] - out["true_size_mm"]) < 3.0, out
    with TMOCClient(server.base, token=TOKEN) as tmoc:
        closed = tmoc._call("GET", f"/v1/sessions/{out['session']}")
        assert closed["status"] == "closed" and closed["episodes_done"] == 2


def test_the_robot_loop_example_drives_a_ur5e_from_its_joint_trajectories(server, tmp_path):
    """Issue 41: the simulated UR5e runs each step's FollowJointTrajectory goal from the JSON
    alone (its base from GET /v1/domains) and posts the joints it reached; the session
    plans the next step from them and learns the size."""
    script = REPO / "docs" / "examples" / "robot_loop.py"
    proc = subprocess.run([sys.executable, str(script), "--url", server.base, "--token", TOKEN, "--robot", "ur5e",
                           "--episodes", "1", "--particles", "8", "--max-steps", "6", "--true-size", "0.045"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["robot"] == "ur5e" and len(out["utilities"]) == 1
    assert abs(out["posterior_size_mm"] - out["true_size_mm"]) < 3 * max(out["posterior_std_mm"], 0.5), out
    assert "FAILED" not in proc.stdout.split("episode 0 step 0")[1].splitlines()[0]   # the first pickup held
