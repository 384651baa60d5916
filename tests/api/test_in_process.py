"""The routes in-process (FastAPI's TestClient over ``create_app``), in the fast loop: what
needs no Ray (validation, lookups, the schema) gets feedback in seconds. The served
uvicorn + Ray tests (test_tasks.py, test_sessions.py, ...) stay the end-to-end truth."""
from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from api.app import create_app
from api.settings import Settings


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    db = tmp_path_factory.mktemp("inproc") / "tmoc.sqlite"
    with TestClient(create_app(Settings(db=str(db), max_particles=64))) as c:
        yield c


def test_health_and_the_domains_without_ray(client):
    assert client.get("/health").json()["status"] == "ok"
    names = {d["name"] for d in client.get("/v1/domains").json()["items"]}
    assert {"container", "stack_and_push"} <= names
    assert client.get("/v1/domains").json()["broken"] == {}
    d = client.get("/v1/domains/stack_and_push").json()
    assert d["name"] == "stack_and_push" and ["push", 1] in d["contexts"]
    assert client.get("/v1/domains/nowhere").status_code == 404


def test_the_robots_as_a_client_checks_trajectories_with_them(client):
    """Issue 41: GET /v1/robots describes each robot; from an arm's description alone a client's
    own forward kinematics reproduces the arm's tool pose."""
    import numpy as np

    from sim_workers.robots import robot
    from sim_workers.robots.kinematics import DH, forward

    items = client.get("/v1/robots").json()["items"]
    assert {r["name"] for r in items} >= {"gripper", "ur5e"}
    ur = client.get("/v1/robots/ur5e").json()
    assert ur["kind"] == "arm" and len(ur["joints"]) == 6 and ur["joints"][2]["high"] == pytest.approx(np.pi)
    q = np.array([0.3, -1.2, 1.4, -1.6, -1.5, 0.2])
    mine = np.array(ur["base"]) @ forward(DH(**ur["dh"]), q) @ np.array(ur["flange_to_tool"])
    assert np.abs(mine - robot("ur5e").tool(q)).max() < 1e-12
    gripper = client.get("/v1/robots/gripper").json()
    assert gripper["kind"] == "floating" and gripper["joints"][0]["low"] is None and gripper["dh"] is None
    missing = client.get("/v1/robots/ur10")
    assert missing.status_code == 404 and "ur5e" in missing.json()["detail"]


@pytest.mark.parametrize("body, field", [
    ({"particles": 65}, "particles"),                      # over this server's limit
    ({"domain": "nowhere"}, "domain"),
    ({"episodes": 0}, "episodes"),
    ({"truth": {"size": 0.5}}, "size"),
    ({"options": {"no_such_option": 1}}, "no_such_option"),
    ({"costs": {"push": -1}}, "push"),
    ({"reality_fail": "fly:2"}, "reality_fail"),
    ({"engine": "ode"}, "engine"),
    ({"reality_engine": "bullet"}, "reality_engine"),
    ({"robot": "ur6"}, "robot"),
])
def test_a_bad_task_is_a_422_naming_the_field_and_nothing_is_stored(client, body, field):
    before = client.get("/v1/tasks", params={"limit": 200}).json()["items"]
    r = client.post("/v1/tasks", json={"episodes": 1, **body})
    assert r.status_code == 422 and field in r.text, r.text
    assert client.get("/v1/tasks", params={"limit": 200}).json()["items"] == before


def test_unknown_ids_are_404s(client):
    for path in ("/v1/tasks/t_doesnotexist", "/v1/tasks/t_doesnotexist/belief",
                 "/v1/sessions/s_doesnotexist"):
        assert client.get(path).status_code == 404, path


def test_the_schema_has_one_task_model_per_domain(client):
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    assert {"TaskSpecContainer", "TaskSpecStackAndPush"} <= set(schemas)


def test_each_domain_s_schema_offers_the_robots_that_can_stand_in_it(client):
    """An arm stands where the domain declares (robot_base): a domain without one offers the
    floating gripper alone, so a schema-valid request is never refused for its robot."""
    from types import SimpleNamespace

    from coordinator.domains import load, names
    from coordinator.robots import names_for

    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    for d in names():
        label = "".join(w.title() for w in d.split("_"))
        for model in (f"TaskSpec{label}", f"SessionCreate{label}"):
            prop = schemas[model]["properties"]["robot"]
            offered = prop["enum"] if "enum" in prop else [prop["const"]]       # one robot: a const
            assert offered == names_for(load(d).physics), (model, offered)
    assert "ur5e" in names_for(load("container").physics)
    assert names_for(SimpleNamespace(robot_base=None)) == ["gripper"]


def test_the_schema_offers_the_installed_engines_and_a_session_has_no_reality_engine(client):
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    task = schemas["TaskSpecContainer"]["properties"]
    engines = [e for alt in task["engine"]["anyOf"] for e in alt.get("enum", [])]
    assert engines == ["pybullet", "mujoco"] and "reality_engine" in task
    session = schemas["SessionCreateContainer"]["properties"]
    assert "engine" in session and "reality_engine" not in session


def test_a_robot_sessions_steps_export_as_mcap_without_ray(client):
    """A session whose agent keeps no belief (tmp_rl: no particle worlds, no Ray) driven by
    a test robot for two steps: its export reads back with mcap's own reader, step for step."""
    import io
    import json

    import numpy as np
    from mcap.reader import make_reader

    from coordinator.loop.reality import SimulatedReality

    from .conftest import drive_episode

    robot = SimulatedReality("container", {"n_blocks": 3}, {"block_sizes": np.full(3, 0.045)})
    try:
        start = robot.start_episode(np.random.default_rng(0))
        r = client.post("/v1/sessions", json={"agent": "tmp_rl", "episodes": 1, "max_steps": 2, "n_blocks": 3,
                                              "observation": {"configuration": start.configuration.to_dict()}})
        assert r.status_code == 201, r.text
        sid = r.json()["id"]
        replies = drive_episode(client, sid, robot, r.json()["next"])
    finally:
        robot.close()
    link = client.get(f"/v1/sessions/{sid}").json()["links"]["export"]     # issue 38, row 12
    assert link == f"/v1/sessions/{sid}/export"
    from api.views import task_links

    assert task_links("t_x")["export"] == "/v1/tasks/t_x/export"
    exported = client.get(link)
    assert exported.status_code == 200 and exported.headers["content-type"] == "application/octet-stream"
    reader = make_reader(io.BytesIO(exported.content))
    steps = [json.loads(m.data) for _, ch, m in reader.iter_messages(topics=["/tmoc/step"])]
    assert [s["action"] for s in steps] == [b["report"]["action"] for b in replies]
    assert [s["state_after"] for s in steps] == [b["report"]["state"] for b in replies]
    assert len(steps) == 2 and steps[1]["configuration_before"] == steps[0]["configuration_after"]
    assert client.get("/v1/sessions/s_doesnotexist/export").status_code == 404
    assert client.get("/v1/tasks/t_doesnotexist/export").status_code == 404


def test_a_domains_versioned_id_is_taken_over_http(client):
    """Issue 38, row 12: `container-v1` is the registry's and the CLI's name for the
    container at version 1; over HTTP it got 422. It is read back as the name."""
    import numpy as np

    from coordinator.loop.reality import SimulatedReality

    robot = SimulatedReality("container", {"n_blocks": 3}, {"block_sizes": np.full(3, 0.045)})
    try:
        start = robot.start_episode(np.random.default_rng(0))
    finally:
        robot.close()
    body = {"agent": "tmp_rl", "episodes": 1, "max_steps": 2, "n_blocks": 3,
            "observation": {"configuration": start.configuration.to_dict()}}
    r = client.post("/v1/sessions", json={**body, "domain": "container-v1"})
    assert r.status_code == 201, r.text
    assert r.json()["spec"]["domain"] == "container"
    r = client.post("/v1/sessions", json={**body, "domain": "container-v9"})
    assert r.status_code == 422 and "domain" in r.text


def test_a_server_error_closes_its_connection(tmp_path):
    """Issue 38, row 8: after a 500 uvicorn closes the connection; without `Connection:
    close` a keep-alive client sent its next request down it and got "connection reset"."""
    app = create_app(Settings(db=str(tmp_path / "boom.sqlite")))

    def boom():
        raise RuntimeError("a bug")

    app.add_api_route("/boom", boom)
    with TestClient(app, raise_server_exceptions=False) as c:
        r = c.get("/boom")
        assert r.status_code == 500 and r.headers["connection"] == "close"
        assert r.json() == {"detail": "internal error: RuntimeError"}
        assert c.get("/health").status_code == 200


def test_a_corrupt_row_fails_alone(tmp_path):
    """Issue 38, row 9: a bad `sessions.pending` made `GET /v1/sessions` a 500 for the whole
    list; a bad episode row gave `GET .../episodes` a 200 with invalid JSON. Now the list
    leaves the bad row out (`skipped`) and the episode reads as a valid stand-in."""
    import json
    import sqlite3

    import numpy as np

    from coordinator.loop.reality import SimulatedReality

    from .conftest import drive_episode

    db = tmp_path / "corrupt.sqlite"
    with TestClient(create_app(Settings(db=str(db))), raise_server_exceptions=False) as c:
        robot = SimulatedReality("container", {"n_blocks": 3}, {"block_sizes": np.full(3, 0.045)})
        try:
            ids = []
            for _ in range(2):
                start = robot.start_episode(np.random.default_rng(0))
                r = c.post("/v1/sessions", json={"agent": "tmp_rl", "episodes": 2, "max_steps": 2, "n_blocks": 3,
                                                 "observation": {"configuration": start.configuration.to_dict()}})
                assert r.status_code == 201, r.text
                ids.append(r.json()["id"])
            drive_episode(c, ids[0], robot, c.get(f"/v1/sessions/{ids[0]}").json()["pending"])
        finally:
            robot.close()
        with sqlite3.connect(db) as raw:
            raw.execute("UPDATE sessions SET pending = '{' WHERE id = ?", (ids[1],))
            raw.execute("UPDATE episodes SET record = '{' WHERE run_id = ?", (ids[0],))
        listed = c.get("/v1/sessions")
        assert listed.status_code == 200, listed.text
        body = listed.json()
        assert [s["id"] for s in body["items"]] == [ids[0]] and body["skipped"] == 1 and body["total"] == 2
        assert c.get(f"/v1/sessions/{ids[0]}").status_code == 200
        curve = c.get(f"/v1/sessions/{ids[0]}/curve")
        assert curve.status_code == 200 and curve.json()["points"] == [], curve.text
        from api.store import Store

        store = Store(str(db))
        try:
            (episode, text), = store.episodes(ids[0])
            assert episode == 0 and json.loads(text) == {"episode": 0, "corrupt": "the stored record is not valid JSON"}
        finally:
            store.close()


def test_a_curve_of_a_domain_without_a_size_is_served():
    """A chute run's episode record (L is a friction): its curve points say the size is
    null and give L's properties; the response model accepts them (a stored chute episode
    made GET /v1/tasks/{id}/curve answer 500, a KeyError on `size_mean`)."""
    from api import views
    from api.schemas.responses import CurveView

    record = {"episode": 0, "utility": -100.0, "actions": 2, "delivered": 0, "loads": [8, 7],
              "posterior": {"mean": [0.65], "std": [0.066],
                            "properties": {"friction": {"mean": 0.65, "std": 0.066, "unit": "1"}}}}
    points = views.curve_points([record])
    assert points[0]["size_mean"] is None and points[0]["properties"]["friction"]["mean"] == 0.65
    view = CurveView(run_id="t_1", agent="tmoc", true_size=None, points=points)
    assert view.points[0].size_std is None and view.points[0].loads == [8, 7]
