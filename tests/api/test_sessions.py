"""External robot sessions: a test robot (a grounded world holding the hidden truth) drives
the service step by step; observations that do not fit get a 409 and change nothing."""
from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest
from mcap.reader import make_reader

from coordinator.cli import main
from coordinator.loop.reality import SimulatedReality

from .conftest import TOKEN, Server, drive_episode, observation_body, stream_events

# Slow: real tasks on a served Ray. Timeout: a task's event stream (180 s) after the shared server's start (90 s).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

TRUE_SIZE = 0.050
PRIOR_STD = (0.060 - 0.030) / np.sqrt(12)


@pytest.fixture()
def robot():
    world = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, TRUE_SIZE)})
    yield world
    world.close()


_observation = observation_body


def read_mcap(data: bytes) -> tuple[dict[str, list[dict]], dict]:
    """{topic: [decoded JSON messages]} and the ``tmoc`` metadata, by mcap's own reader."""
    reader = make_reader(io.BytesIO(data))
    topics: dict[str, list[dict]] = {}
    for _, channel, message in reader.iter_messages():
        topics.setdefault(channel.topic, []).append(json.loads(message.data))
    meta = next(m.metadata for m in reader.iter_metadata() if m.name == "tmoc")
    return topics, meta


def test_a_robot_driven_session_converges_like_a_simulated_task(client, robot, server, tmp_path):
    learning = {"agent": "tmoc", "particles": 24, "episodes": 1, "max_steps": 6, "seed": 3}
    start = robot.start_episode(np.random.default_rng(0))
    r = client.post("/v1/sessions", json={**learning, "observation": _observation(start)})
    assert r.status_code == 201, r.text
    created = r.json()
    sid, step = created["id"], created["next"]
    assert r.headers["location"] == f"/v1/sessions/{sid}"
    assert created["in_episode"] and step["episode"] == 0 and step["step"] == 0
    assert step["trajectory_columns"] == ["t", "x", "y", "z", "yaw", "opening"]

    reports, executed = [], []
    while step is not None:
        # GET next is idempotent: the same pending step until it is observed.
        pending = client.get(f"/v1/sessions/{sid}/next").json()["pending"]
        assert pending == step
        outcome = robot.execute(np.array(step["trajectory"]), step["action"])
        executed.append(step["trajectory"])
        r = client.post(f"/v1/sessions/{sid}/observations", json=_observation(outcome, step))
        assert r.status_code == 200, r.text
        body = r.json()
        reports.append(body["report"])
        assert body["report"]["state"] == sorted(outcome.state)
        step = body["next"]
    assert body["episode_done"] and body["episode"]["actions"] == len(reports) == 6

    post = client.get(f"/v1/sessions/{sid}/belief").json()
    assert abs(post["posterior"]["size_mean"] - TRUE_SIZE) < 0.003, post["posterior"]
    assert post["posterior"]["size_std"] < 0.5 * PRIOR_STD
    assert post["belief"]["n"] == 24
    view = client.get(f"/v1/sessions/{sid}").json()
    assert view["status"] == "finished" and view["episodes_done"] == 1 and not view["in_episode"]
    assert [p["episode"] for p in client.get(f"/v1/sessions/{sid}/curve").json()["points"]] == [0]
    assert client.get(f"/v1/sessions/{sid}/next").status_code == 409

    # Every step the robot took, exported as MCAP and read back with mcap's own reader.
    exported = client.get(f"/v1/sessions/{sid}/export")
    assert exported.status_code == 200 and exported.content[:8] == b"\x89MCAP0\r\n"
    topics, meta = read_mcap(exported.content)
    steps, trajs = topics["/tmoc/step"], topics["/tmoc/trajectory"]
    assert [m["action"] for m in steps] == [r["action"] for r in reports]
    assert [m["state_after"] for m in steps] == [r["state"] for r in reports]
    assert [m["success"] for m in steps] == [r["success"] for r in reports]
    assert [len(t["points"]) for t in trajs] == [len(t) for t in executed]
    assert trajs[0]["points"] == executed[0] and trajs[0]["columns"] == ["t", "x", "y", "z", "yaw", "opening"]
    assert steps[0]["configuration_before"] == pytest.approx(start.configuration.to_array().tolist())
    assert steps[-1]["belief"]["size_mean"] == pytest.approx(post["posterior"]["size_mean"])
    assert [e["episode"] for e in topics["/tmoc/episode"]] == [0]
    assert meta["source"] == "session" and meta["domain"] == "container"
    # ... and by `tmoc export` from the server, to a file.
    out = tmp_path / "robot.mcap"
    assert main(["export", "--server", server.base, "--session", sid, "--token", TOKEN, "-o", str(out)]) == 0
    assert read_mcap(out.read_bytes())[0]["/tmoc/step"] == steps

    # The same learner as a simulated task with the same truth gets there too.
    task = client.post("/v1/tasks", json={**learning, "true_size": TRUE_SIZE}).json()["id"]
    events = stream_events(client, task)
    assert events[-1]["data"]["status"] == "succeeded"
    sim = events[-2]["data"]["posterior"]
    assert abs(sim["size_mean"] - TRUE_SIZE) < 0.003, sim
    task_steps = read_mcap(client.get(f"/v1/tasks/{task}/export").content)[0]["/tmoc/step"]
    assert len(task_steps) == 6 and [m["step"] for m in task_steps] == list(range(6))


def test_observations_that_do_not_fit_get_409_and_change_nothing(client, robot):
    r = client.post("/v1/sessions", json={"particles": 2, "episodes": 1, "max_steps": 3, "seed": 1})
    assert r.status_code == 201 and r.json()["next"] is None and not r.json()["in_episode"]
    sid = r.json()["id"]
    start = robot.start_episode(np.random.default_rng(1))

    # No episode yet: nothing is pending.
    assert client.get(f"/v1/sessions/{sid}/next").status_code == 409
    r = client.post(f"/v1/sessions/{sid}/observations", json=_observation(start, "pickup(r,b1,init)"))
    assert r.status_code == 409 and "episode" in r.json()["detail"]

    r = client.post(f"/v1/sessions/{sid}/episodes", json=_observation(start))
    assert r.status_code == 201, r.text
    step = r.json()["next"]
    assert client.post(f"/v1/sessions/{sid}/episodes", json=_observation(start)).status_code == 409
    before = client.get(f"/v1/sessions/{sid}").json()

    outcome = robot.execute(np.array(step["trajectory"]), step["action"])
    good = _observation(outcome, step)
    conf = good["configuration"]
    bad = {
        "action": {**good, "action": "push(r,c,init,goal)"},
        "configuration.objects": {**good, "configuration": {**conf, "objects": conf["objects"][:3]}},
        "measurements": {**good, "measurements": [0.0, 1.0]},
        "state": {**good, "state": ["is_in(b1,init)", "hand_empty(r)", "flying(b2)"]},
        "quaternion": {**good, "configuration": {**conf, "objects": [row[:3] + [0, 0, 0, 0]
                                                                     for row in conf["objects"]]}},
    }
    for name, body in bad.items():
        r = client.post(f"/v1/sessions/{sid}/observations", json=body)
        assert r.status_code == 409, (name, r.text)
        assert name.split(".")[0] in r.json()["detail"] or name == "quaternion", (name, r.text)
    # Malformed arrays (not the schema's shapes or not numbers) are refused before anything.
    for body, field in (({**good, "configuration": {**conf, "robot": conf["robot"][:4]}}, "robot"),
                        ({**good, "configuration": {**conf, "robot": ["a"] * 5}}, "robot"),
                        ({**good, "configuration": {**conf, "objects": [[0.0] * 6]}}, "objects"),
                        ({k: v for k, v in good.items() if k != "action"}, "action")):
        r = client.post(f"/v1/sessions/{sid}/observations", json=body)
        assert r.status_code == 422 and field in r.json()["message"], r.text
    r = client.post(f"/v1/sessions/{sid}/observations", content=b'{"action": "x", "configuration": NaN}',
                    headers={"content-type": "application/json"})
    assert r.status_code == 422 and "configuration" in r.json()["message"]

    after = client.get(f"/v1/sessions/{sid}").json()
    assert after == before                                   # nothing changed
    assert client.get(f"/v1/sessions/{sid}/next").json()["pending"] == step

    r = client.post(f"/v1/sessions/{sid}/observations", json=good)
    assert r.status_code == 200, r.text
    assert client.get(f"/v1/sessions/{sid}").json()["step"] == 1
    reply = r.json()
    # The step is consumed: the same observation again is a replay (issue 12): the same
    # reply, and nothing changes; the same step id with another observation is a conflict.
    seen = client.get(f"/v1/sessions/{sid}").json()
    again = client.post(f"/v1/sessions/{sid}/observations", json=good)
    assert again.status_code == 200 and again.json() == reply
    assert client.get(f"/v1/sessions/{sid}").json() == seen
    other = {**good, "measurements": [0.01] + [0.0] * 16}
    r = client.post(f"/v1/sessions/{sid}/observations", json=other)
    assert r.status_code == 409 and "step_id" in r.json()["detail"], r.text
    assert client.get(f"/v1/sessions/{sid}").json() == seen

    assert client.delete(f"/v1/sessions/{sid}").json()["status"] == "closed"
    assert client.get(f"/v1/sessions/{sid}/next").status_code == 409
    for method, path in (("GET", "next"), ("POST", "observations"), ("POST", "episodes")):
        body = {"observations": good, "episodes": _observation(outcome)}.get(path)
        r = client.request(method, f"/v1/sessions/s_nope/{path}", json=body)
        assert r.status_code == 404, (path, r.text)


def test_a_stack_and_push_robot_session_and_task_over_http(client):
    """The second domain end to end over HTTP: a robot session whose scene is a rail and a
    tower (its atoms and actions are stack-and-push's), and a simulated task."""
    world = SimulatedReality("stack_and_push", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.040)})
    try:
        learning = {"domain": "stack_and_push", "agent": "tmoc", "particles": 8, "episodes": 1,
                    "max_steps": 4, "seed": 2}
        start = world.start_episode(np.random.default_rng(0))
        r = client.post("/v1/sessions", json={**learning, "observation": _observation(start)})
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        replies = drive_episode(client, sid, world, r.json()["next"])
        actions, body = [b["report"]["action"] for b in replies], replies[-1]
        assert len(actions) == 4 and actions[0] == "pickup(r,b1,init)"
        assert all(re.fullmatch(r"pickup\(r,b\d,(init|table|rail)\)|stack\(r,b\d,tower\)", a)
                   for a in actions), actions
        state = body["report"]["state"]
        assert "hand_empty(r)" in state or any(a.startswith("is_holding(r,") for a in state)
        assert not any(a.startswith("at_container(") for a in state)
        post = client.get(f"/v1/sessions/{sid}/belief").json()["posterior"]
        assert post["size_std"] < 0.5 * PRIOR_STD, post      # the grasps taught it the size
        # a container configuration is not this scene: 409 naming the objects
        bad = {"configuration": {"robot": [0, 0, 0.2, 0, 0.05], "objects": [[0, 0, 0, 0, 0, 0, 1]] * 9}}
        r = client.post("/v1/sessions", json={**learning, "observation": bad})
        assert r.status_code == 409 and "configuration.objects" in r.json()["detail"]
    finally:
        world.close()
    task = client.post("/v1/tasks", json={**learning, "true_size": 0.040}).json()["id"]
    events = stream_events(client, task)
    assert events[-1]["data"]["status"] == "succeeded", events[-1]
    assert events[-2]["data"]["actions"] == 4


def test_a_robot_session_asks_its_worlds_before_its_first_plan(tmp_path):
    # counterfactual_rows (issue 40): the episode's first plan is made with the worlds lent,
    # so the snapshot's trials are in the episode's record; a server with the default limit
    # gives a session that names no rows the service's default, 4.
    world = SimulatedReality("container", {"n_blocks": 3}, {"block_sizes": np.full(3, TRUE_SIZE)})
    srv = Server(tmp_path / "counterfactual.sqlite", "--max-counterfactual-rows", "32").start()
    try:
        spec = {"agent": "tmoc", "particles": 4, "episodes": 1, "max_steps": 2, "seed": 1, "n_objects": 3}
        start = world.start_episode(np.random.default_rng(0))
        client = srv.client()
        r = client.post("/v1/sessions", json={**spec, "observation": _observation(start)})
        assert r.status_code == 201, r.text
        sid, step = r.json()["id"], r.json()["next"]
        while step is not None:
            outcome = world.execute(np.array(step["trajectory"]), step["action"])
            body = client.post(f"/v1/sessions/{sid}/observations", json=_observation(outcome, step)).json()
            step = body["next"]
        jobs = 1 + 3 + 3                        # the container's pickup, stacks of 1..3, pushes of 1..3
        assert body["episode"]["counterfactual_trials"] == 4 * jobs, body["episode"]
        assert body["episode"]["counterfactual_s"] > 0
        assert client.get(f"/v1/sessions/{sid}").json()["spec"]["counterfactual_rows"] == 4
        client.close()
    finally:
        world.close()
        srv.stop()


def test_an_arm_s_session_steps_carry_a_joint_trajectory_a_client_can_check(client, robot):
    """Issue 41: with robot ur5e each step carries a FollowJointTrajectory-shaped goal whose
    positions put the tool (by GET /v1/robots' kinematics) on the step's rows; the simulated
    UR5e reality runs it over HTTP as a real arm would and reports its joints."""
    from sim_workers.robots.kinematics import DH, forward
    from sim_workers.robots.motion import ArmMotion

    start = robot.start_episode(np.random.default_rng(0))
    r = client.post("/v1/sessions", json={"agent": "tmoc", "particles": 4, "episodes": 1, "max_steps": 2,
                                          "seed": 1, "robot": "ur5e", "observation": _observation(start)})
    assert r.status_code == 201, r.text
    sid, step = r.json()["id"], r.json()["next"]
    ur5e = client.get("/v1/robots/ur5e").json()
    assert ur5e["links"] and ur5e["trajectory_acceleration"] == 1.4
    assert ur5e["link_masses"] == [3.761, 8.058, 2.846, 1.37, 1.3, 0.365] and ur5e["joint_torques"][0] == 150.0
    dh = DH(**ur5e["dh"])
    # the arm stands where the domain declares (GET /v1/domains: robot_base x, y, z, yaw)
    domains = client.get("/v1/domains").json()
    domains = domains.get("items", domains) if isinstance(domains, dict) else domains
    x, y, z, yaw = next(d for d in domains if d["name"] == "container")["robot_base"]
    base = np.array([[np.cos(yaw), -np.sin(yaw), 0, x], [np.sin(yaw), np.cos(yaw), 0, y], [0, 0, 1, z], [0, 0, 0, 1]])
    tool = np.array(ur5e["flange_to_tool"])
    n = 0
    while step is not None:
        goal = step["joint_trajectory"]
        assert goal["joint_names"] == [j["name"] for j in ur5e["joints"]]
        assert len(goal["points"]) == len(step["trajectory"])
        for point, row in zip(goal["points"], step["trajectory"]):
            pose = base @ forward(dh, np.array(point["positions"])) @ tool
            assert np.abs(pose[:3, 3] - row[1:4]).max() < 1e-6
            assert abs(point["time_from_start"] - (row[0] - step["trajectory"][0][0])) < 1e-9
            assert max(abs(v) for v in point["velocities"]) <= 1.02 * ur5e["joints"][0]["max_velocity"]
        # the simulated UR5e runs the goal as a real arm would (from the JSON alone: the
        # robot's name, the domain's base, the goal; the rows for the fingers) and reports
        # the joints it measured, which put the tool on the step's last row
        rows = np.array(step["trajectory"])
        outcome = robot.execute(rows, step["action"], arm=ArmMotion.from_goal("ur5e", (x, y, z, yaw), goal, rows[0, 0]))
        measured = outcome.joint_positions.tolist()
        assert np.abs((base @ forward(dh, outcome.joint_positions) @ tool)[:3, 3] - rows[-1, 1:4]).max() < 1e-4
        assert measured != goal["points"][-1]["positions"]          # tracked, not copied
        bad = client.post(f"/v1/sessions/{sid}/observations",
                          json=_observation(outcome, step, joint_positions=measured[:5]))
        assert bad.status_code == 409 and "joint_positions" in bad.text and "6 joints" in bad.text
        r = client.post(f"/v1/sessions/{sid}/observations",
                        json=_observation(outcome, step, joint_positions=measured))
        assert r.status_code == 200, r.text
        step, n = r.json()["next"], n + 1
        if step is not None:
            assert step["joint_trajectory"]["points"][0]["positions"] == measured
    assert n == 2
    bad = client.post("/v1/sessions", json={"robot": "ur6", "observation": _observation(start)})
    assert bad.status_code == 422 and "robot" in bad.text
