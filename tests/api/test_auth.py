"""Access: a bearer token on every route but /health; loopback only without a token."""
from __future__ import annotations

import argparse
import os
import subprocess

import httpx
import pytest

from coordinator.cli import UsageError
from coordinator.commands import serve

from .conftest import TLS, TOKEN, free_port, tmoc

PROTECTED = [("GET", "/v1/tasks"), ("POST", "/v1/tasks"), ("GET", "/v1/tasks/t_1"),
             ("DELETE", "/v1/tasks/t_1"), ("GET", "/v1/tasks/t_1/events"), ("GET", "/v1/tasks/t_1/belief"),
             ("GET", "/v1/tasks/t_1/curve.png"), ("POST", "/v1/sessions"), ("GET", "/v1/sessions/s_1/next"),
             ("POST", "/v1/sessions/s_1/observations"), ("GET", "/openapi.json"), ("GET", "/docs")]


@pytest.mark.parametrize("method,path", PROTECTED)
def test_every_route_but_health_needs_the_token(server, method, path):
    # Each route from its own loopback address: a wrong credential counts against its
    # address (issue 38), and 36 of them from the suite's 127.0.0.1 would throttle it.
    address = f"127.0.0.{20 + PROTECTED.index((method, path))}"
    with httpx.Client(transport=httpx.HTTPTransport(local_address=address, verify=TLS), timeout=30) as c:
        for headers in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": f"Basic {TOKEN}"},
                        {"Authorization": TOKEN}):
            r = c.request(method, server.base + path, headers=headers, json={} if method == "POST" else None)
            assert r.status_code == 401, (headers, r.text)
            assert r.headers.get("www-authenticate") == "Bearer"
        r = c.request(method, server.base + path, headers=server.headers,
                      json={"particles": 0} if method == "POST" else None)
        assert r.status_code != 401, r.text


def test_health_needs_no_token(server):
    r = httpx.get(server.base + "/health")
    assert r.status_code == 200 and r.json()["status"] == "ok" and r.json()["auth"] is True


def _args(host: str, insecure: bool = False) -> argparse.Namespace:
    return argparse.Namespace(host=host, port=8000, insecure=insecure, max_particles=10, max_episodes=10,
                              max_steps=10, max_queued=10, max_sessions=10, shards=None)


def test_without_a_token_only_loopback_unless_insecure(monkeypatch):
    monkeypatch.delenv("TMOC_API_TOKEN", raising=False)
    assert serve.check_args(_args("127.0.0.1")) is None
    assert serve.check_args(_args("::1")) is None
    assert serve.check_args(_args("localhost")) is None
    with pytest.raises(UsageError, match="TMOC_API_TOKEN"):
        serve.check_args(_args("0.0.0.0"))
    assert serve.check_args(_args("0.0.0.0", insecure=True)) is None
    monkeypatch.setenv("TMOC_API_TOKEN", "s3cret")
    assert serve.check_args(_args("0.0.0.0")) == "s3cret"
    monkeypatch.setenv("TMOC_API_TOKEN", " ")
    with pytest.raises(UsageError, match="empty"):
        serve.check_args(_args("127.0.0.1"))


@pytest.mark.parametrize("argv,needle", [
    (["--host", "0.0.0.0"], "--host 0.0.0.0"),
    (["--max-particles", "0"], "--max-particles"),
    (["--max-counterfactual-rows", "257"], "--max-counterfactual-rows"),
    (["--port", "70000"], "--port"),
])
@pytest.mark.slow          # a `tmoc serve` process per case
def test_serve_refuses_bad_flags_with_exit_code_2(tmp_path, argv, needle):
    env = {k: v for k, v in os.environ.items() if k != "TMOC_API_TOKEN"}
    out = subprocess.run([*tmoc(), "serve", "--db",
                          str(tmp_path / "x.sqlite"), "--port", str(free_port()), *argv],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out
    assert needle in out.stderr and "Traceback" not in out.stderr, out.stderr


@pytest.mark.slow          # a second `tmoc serve` process
def test_a_second_server_on_the_same_database_is_refused(server):
    env = {k: v for k, v in os.environ.items() if k != "TMOC_API_TOKEN"}
    out = subprocess.run([*tmoc(), "serve", "--db", str(server.db),
                          "--port", str(free_port())],
                         cwd=server.db.parent, env=env, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "in use" in out.stderr, out
