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
    d = client.get("/v1/domains/stack_and_push").json()
    assert d["name"] == "stack_and_push" and ["push", 1] in d["contexts"]
    assert client.get("/v1/domains/nowhere").status_code == 404


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


def test_the_schema_offers_the_installed_engines_and_a_session_has_no_reality_engine(client):
    schemas = client.get("/openapi.json").json()["components"]["schemas"]
    task = schemas["TaskSpecContainer"]["properties"]
    engines = [e for alt in task["engine"]["anyOf"] for e in alt.get("enum", [])]
    assert engines == ["pybullet", "mujoco"] and "reality_engine" in task
    session = schemas["SessionCreateContainer"]["properties"]
    assert "engine" in session and "reality_engine" not in session
