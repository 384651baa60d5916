"""Bad input gets a 4xx whose body names the field; never a 500."""
from __future__ import annotations

import pytest

BAD_TASKS = [
    # (body, field that must be named, extra text that must appear)
    ({"particles": "many"}, "particles", "integer"),
    ({"particles": 3.5}, "particles", "integer"),
    ({"seed": True}, "seed", "integer"),
    ({"true_size": "big"}, "true_size", "number"),
    ({"sizes_variation": "yes"}, "sizes_variation", "boolean"),
    ({"costs": "cheap"}, "costs", ""),
    ({"costs": {"pickup": -1}}, "costs.pickup", "greater than or equal"),
    ({"domain": "kitchen"}, "domain", "container"),
    ({"agent": "ppo"}, "agent", "tmoc"),
    ({"likelihood": "exact"}, "likelihood", "replay"),
    ({"particles": 0}, "particles", "greater than or equal to 1"),
    ({"particles": 65}, "particles", "--max-particles 64"),
    ({"counterfactual_rows": 1}, "counterfactual_rows", "--max-counterfactual-rows 0"),
    ({"counterfactual_rows": -1}, "counterfactual_rows", "greater than or equal to 0"),
    ({"episodes": 7}, "episodes", "--max-episodes 6"),
    ({"max_steps": 61}, "max_steps", "--max-steps 60"),
    ({"true_size": 1.0}, "true_size", "less than or equal"),
    ({"error_rate": 0.7}, "error_rate", "less than"),
    ({"n_blocks": 17}, "n_blocks", "16"),
    ({"seed": -1}, "seed", "greater than or equal"),
    ({"seed": 2**53}, "seed", "less than or equal"),
    ({"partcles": 3}, "partcles", "Extra inputs"),
    ({"reality": "external"}, "reality", "/v1/sessions"),
]


@pytest.mark.parametrize("body,field,text", BAD_TASKS, ids=[f"{b}" for b, _, _ in BAD_TASKS])
def test_bad_task_specs_get_422_naming_the_field(client, body, field, text):
    r = client.post("/v1/tasks", json=body)
    assert r.status_code == 422, r.text
    data = r.json()
    assert data["message"].startswith(f"{field}:"), data["message"]
    assert text in data["message"], data["message"]
    assert any(".".join(map(str, d["loc"][1:])) == field for d in data["detail"]), data


@pytest.mark.parametrize("content", [b'{"particles": 3,', b"particles=3", b"[1, 2]", b"\xff\xfe",
                                     b'{"particles": NaN}', b"null"])
def test_malformed_bodies_get_422(client, content):
    r = client.post("/v1/tasks", content=content, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    assert r.json()["message"].split(":")[0] in ("body", "particles"), r.json()


@pytest.mark.parametrize("path", ["/v1/tasks", "/v1/sessions"])
def test_a_body_that_is_not_json_is_named_as_such(client, path):
    """Issue 25, row 14: under the per-domain union, `text/plain` got pydantic's generic
    "valid dictionary" message (the union's tag in `loc` defeated the check)."""
    r = client.post(path, content=b"hello", headers={"Content-Type": "text/plain"})
    assert r.status_code == 422
    assert r.json()["message"] == ("body: expected a JSON object sent with Content-Type: "
                                   "application/json (got text/plain)"), r.text


def test_oversized_bodies_get_413(client):
    r = client.post("/v1/tasks", content=b"[" + b"0," * (3 * 1024 * 1024) + b"0]",
                    headers={"content-type": "application/json"})
    assert r.status_code == 413


@pytest.mark.parametrize("path,params,field", [
    ("/v1/tasks", {"limit": 0}, "limit"),
    ("/v1/tasks", {"limit": "ten"}, "limit"),
    ("/v1/tasks", {"offset": -1}, "offset"),
    ("/v1/tasks", {"status": "sleeping"}, "status"),
    ("/v1/sessions", {"limit": 201}, "limit"),
    ("/v1/tasks/t_x/episodes", {"after": -2}, "after"),
    ("/v1/tasks/t_x/events", {"after": "x"}, "after"),
])
def test_bad_query_parameters_get_422_naming_them(client, path, params, field):
    r = client.get(path, params=params)
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith(f"query {field}:"), r.json()


def test_bad_last_event_id_gets_422(client):
    r = client.get("/v1/tasks/t_x/events", headers={"Last-Event-ID": "latest"})
    assert r.status_code == 422 and "Last-Event-ID" in r.json()["message"]


@pytest.mark.parametrize("suffix", ["", "/events", "/belief", "/curve", "/curve.png", "/episodes"])
def test_unknown_task_ids_get_404(client, suffix):
    r = client.get(f"/v1/tasks/t_0000{suffix}")
    assert r.status_code == 404 and "t_0000" in r.json()["detail"]


def test_bad_session_specs_get_4xx_naming_the_field(client):
    obs = {"configuration": {"robot": [0, 0, 0.2, 0], "objects": [[0, 0, 0, 0, 0, 0, 1]]}}
    r = client.post("/v1/sessions", json={"particles": 2, "observation": obs})
    assert r.status_code == 422 and r.json()["message"].startswith("observation.configuration.robot:")
    r = client.post("/v1/sessions", json={"particles": 2, "true_size": 0.05})
    assert r.status_code == 422 and r.json()["message"].startswith("true_size:")   # the robot is the truth
    r = client.post("/v1/sessions", json={"particles": 1000})
    assert r.status_code == 422 and "--max-particles 64" in r.json()["message"]
    obs = {"configuration": {"robot": [0, 0, 0.2, 0, 0.05], "objects": [[0, 0, 0, 0, 0, 0, 1]]}}
    r = client.post("/v1/sessions", json={"particles": 2, "observation": obs})
    assert r.status_code == 409 and "configuration.objects" in r.json()["detail"]   # not this scene


def test_domains_are_listed_over_http(client):
    r = client.get("/v1/domains")
    assert r.status_code == 200, r.text
    by_name = {d["name"]: d for d in r.json()["items"]}
    assert "container" in by_name and r.json()["total"] == len(by_name)
    one = client.get("/v1/domains/container").json()
    assert one == by_name["container"]
    assert one["contexts"][:2] == [["pickup", 0], ["stack", 0]] and one["utility"]["push"] == 30.0
    r = client.get("/v1/domains/kitchen")
    assert r.status_code == 404 and "kitchen" in r.json()["detail"]
