"""Issue 14, item 4 over HTTP: `truth` and `options` in task and session requests, each
domain with its own request model (the published schema is their union by `domain`), the
posterior per property, the joint belief, and trajectories that carry the efforts."""
from __future__ import annotations

import math

import pytest

from .conftest import stream_events

# Slow: real tasks on a served Ray. Timeout: a task's event stream (180 s) after the shared server's start (90 s).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

HEAVY_TASK = {"domain": "stack_and_push", "agent": "tmoc", "particles": 4, "episodes": 1, "max_steps": 4,
              "seed": 2, "true_size": 0.045, "truth": {"density": 2400.0},
              "options": {"unknown_density": True, "force_sigma": 0.1}}


def test_a_task_learns_the_density_it_was_given_as_truth(client):
    r = client.post("/v1/tasks", json=HEAVY_TASK)
    assert r.status_code == 202, r.text
    task_id = r.json()["id"]
    events = stream_events(client, task_id)
    assert events[-1]["data"]["status"] == "succeeded", events[-1]
    view = client.get(f"/v1/tasks/{task_id}").json()
    assert view["spec"]["options"] == {"unknown_density": True, "force_sigma": 0.1}
    assert view["spec"]["truth"] == {"density": 2400.0}
    summary = view["result"]["summary"]
    assert summary["truth"] == {"size": 0.045, "density": 2400.0}
    post = summary["posterior"]
    assert set(post) == {"size", "density"} and post["density"]["unit"] == "kg/m^3"
    assert 300.0 <= post["density"]["mean"] <= 3000.0
    belief = client.get(f"/v1/tasks/{task_id}/belief").json()["belief"]
    assert len(belief["histogram"]) == 2
    joint = belief["joint"]
    assert len(joint["x_edges"]) == 21 and len(joint["y_edges"]) == 21
    assert joint["x_edges"][0] == 0.03 and joint["y_edges"][-1] == 3000.0
    assert math.isclose(sum(map(sum, joint["weights"])), 1.0, rel_tol=1e-9)


def test_options_and_truth_are_the_domains_and_refused_by_name(client):
    cases = [
        ({**HEAVY_TASK, "options": {"unknown_density": True, "foo": 1}}, "options.foo"),
        ({**HEAVY_TASK, "options": {"force_sigma": -1.0}}, "options.force_sigma"),
        ({**HEAVY_TASK, "options": {"unknown_density": "yes"}}, "options.unknown_density"),
        ({**HEAVY_TASK, "truth": {"mass": 1.0}}, "truth.mass"),
        ({**HEAVY_TASK, "truth": {"density": 0.5}}, "truth.density"),
        ({"agent": "tmoc", "options": {"unknown_density": True}}, "options.unknown_density"),
        ({**HEAVY_TASK, "domain": "stack_and_push", "n_blocks": 9}, "n_blocks"),
        ({**HEAVY_TASK, "domain": "nope"}, "domain"),
    ]
    for body, field in cases:
        r = client.post("/v1/tasks", json=body)
        assert r.status_code == 422, (body, r.text)
        data = r.json()
        assert data["message"].startswith(f"{field}:"), (field, data["message"])
        assert "Traceback" not in r.text
    # The container takes the truth's density as a known one: it reaches the physics.
    ok = client.post("/v1/tasks", json={"agent": "tmp_rl", "particles": 1, "episodes": 1, "max_steps": 1,
                                        "truth": {"density": 7800.0}})
    assert ok.status_code == 202, ok.text
    spec = client.get(ok.json()["location"]).json()["spec"]
    assert spec["truth"] == {"density": 7800.0}


def test_the_schema_publishes_one_request_model_per_domain(client):
    schema = client.get("/openapi.json").json()
    body = schema["paths"]["/v1/tasks"]["post"]["requestBody"]["content"]["application/json"]["schema"]
    branches = body.get("oneOf") or body.get("anyOf")
    refs = sorted(b["$ref"].rsplit("/", 1)[-1] for b in branches)
    from coordinator.domains import names

    label = lambda d: "TaskSpec" + "".join(w.title() for w in d.split("_"))  # noqa: E731
    assert refs == sorted(label(d) for d in names())          # built-ins, and any plugin installed
    assert {"TaskSpecContainer", "TaskSpecStackAndPush"} <= set(refs)
    sp = schema["components"]["schemas"]["StackAndPushOptions"]["properties"]
    assert {"unknown_density", "force_sigma", "force_from_mass"} <= set(sp)
    assert schema["components"]["schemas"]["ContainerOptions"].get("properties", {}) == {}


def test_a_session_with_mass_in_y_sends_the_efforts_with_the_trajectory(client):
    body = {"domain": "stack_and_push", "agent": "tmoc", "particles": 2, "episodes": 1, "max_steps": 2,
            "options": {"unknown_density": True}}
    r = client.post("/v1/sessions", json=body)
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    from sim_workers.stack_and_push import StackAndPushDomain

    d = StackAndPushDomain()
    props = {"block_sizes": [0.045] * 8}
    conf = d.initial_configuration(props)
    first = client.post(f"/v1/sessions/{sid}/episodes", json={"configuration": conf.to_dict()})
    assert first.status_code in (200, 201), first.text
    step = first.json()["next"]
    assert step["trajectory_columns"] == ["t", "x", "y", "z", "yaw", "opening", "grip_force", "force_limit"]
    assert all(len(row) == 8 for row in step["trajectory"]) and len(step["pose"]) == 6
    # A client that sends the measurements without the sensed channels (held weight, grasp
    # width) is still understood: they count as not measured.
    meas = [0.0] + [v for xy in conf.objects[:, :2] for v in xy]
    obs = client.post(f"/v1/sessions/{sid}/observations",
                      json={"action": step["action"], "step_id": step["step_id"],
                            "configuration": conf.to_dict(), "measurements": meas})
    assert obs.status_code == 200, obs.text
    client.delete(f"/v1/sessions/{sid}")
