"""A real `tmoc serve` (uvicorn on loopback, its own local two-CPU Ray) in a subprocess."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

TOKEN = "test-token-0123456789"
REPO = Path(__file__).resolve().parents[2]
# One TLS context for every test client: httpx builds one per client otherwise (17 ms of
# loading the CA store each, and the servers here are plain HTTP on loopback).
TLS = httpx.create_ssl_context()


def tmoc() -> list[str]:
    """The installed console script `tmoc`, as a user runs it (never the checkout's source)."""
    script = Path(sys.executable).with_name("tmoc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "coordinator.cli"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Server:
    """The installed `tmoc serve` on a free port with its own database, run from the
    database's folder (outside the checkout)."""

    def __init__(self, db: Path, *args: str, token: str | None = TOKEN, port: int | None = None) -> None:
        self.db = Path(db)
        # The paper's loop unless a test asks for counterfactual experience: these servers
        # test HTTP, storage and scheduling, and a snapshot before each episode's first plan
        # (the service's default, counterfactual_rows 4) would add seconds of physics to
        # every task and session they run (tests/api/test_sessions.py runs it over HTTP).
        if "--max-counterfactual-rows" not in args:
            args = ("--max-counterfactual-rows", "0", *args)
        self.args = list(args)
        self.token = token
        self.port = port or free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None
        # The first existing folder above the database: the server makes the rest itself.
        self.home = next(p for p in self.db.parents if p.exists())
        self.log_path = self.home / f"{self.db.stem}.log"

    @property
    def headers(self) -> dict:
        return {"Authorization": f"Bearer {self.token}"} if self.token else {}

    def start(self, timeout: float = 90.0) -> "Server":
        env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", PYTHONUNBUFFERED="1")
        env.pop("TMOC_API_TOKEN", None)
        if self.token:
            env["TMOC_API_TOKEN"] = self.token
        log = open(self.log_path, "a")
        self.proc = subprocess.Popen(
            [*tmoc(), "serve", "--port", str(self.port),
             "--db", str(self.db), "--no-access-log", "--log-level", "warning", *self.args],
            cwd=self.home, env=env, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True)          # its own process group: Ray's helpers included
        log.close()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log()}")
            try:
                if httpx.get(f"{self.base}/health", timeout=2, verify=TLS).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"server did not come up:\n{self.log()}")

    def log(self) -> str:
        try:
            return self.log_path.read_text()[-6000:]
        except OSError:
            return ""

    def _reap_group(self) -> None:
        # Ray's dashboard/runtime-env agents outlive a killed driver for a while: end the
        # server's whole process group (they are in it; nothing else is).
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass

    def kill(self) -> None:
        """SIGKILL the server process (a crash: no shutdown code runs)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(30)
        self._reap_group()

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(40)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._reap_group()

    def client(self, **kw) -> httpx.Client:
        kw.setdefault("verify", TLS)
        return httpx.Client(base_url=self.base, headers=self.headers, timeout=kw.pop("timeout", 60), **kw)


def parse_sse(lines) -> list[dict]:
    """SSE lines -> events {event, id, data (parsed JSON)}; stops after a final status."""
    events, cur = [], {}
    for line in lines:
        if line == "":
            if "data" in cur:
                cur["data"] = json.loads(cur["data"])
                events.append(cur)
                if cur.get("event") == "status" and cur["data"]["status"] in (
                        "succeeded", "failed", "cancelled"):
                    break
            cur = {}
            continue
        if line.startswith(":"):
            continue
        field, _, value = line.partition(":")
        value = value[1:] if value.startswith(" ") else value
        if field == "data":
            cur["data"] = cur.get("data", "") + value
        elif field in ("event", "id"):
            cur[field] = value
    return events


def stream_events(client: httpx.Client, task_id: str, last_event_id: str | None = None,
                  timeout: float = 180) -> list[dict]:
    headers = {"Last-Event-ID": last_event_id} if last_event_id is not None else {}
    with client.stream("GET", f"/v1/tasks/{task_id}/events", headers=headers,
                       timeout=httpx.Timeout(timeout)) as r:
        assert r.status_code == 200, r.read()
        assert r.headers["content-type"].startswith("text/event-stream")
        return parse_sse(r.iter_lines())


# -- the robot-session loop: a test robot (a SimulatedReality) answering a session --------
def observation_body(outcome, step=None, **extra) -> dict:
    """An observation body; with `step` (a pending step, or an action name) it answers it."""
    body = {"configuration": outcome.configuration.to_dict(), **extra}
    if isinstance(step, dict):
        body["action"] = step["action"]
        if "step_id" in step:        # (a server from before step ids sends none)
            body["step_id"] = step["step_id"]
    elif step is not None:
        body.update(action=step, step_id="s_none:0:0")
    return body


def act_and_observe(client: httpx.Client, sid: str, robot, step: dict, **extra):
    """Run the pending `step` on the test robot and post what it observed: (the response,
    the robot's outcome)."""
    outcome = robot.execute(np.array(step["trajectory"]), step["action"])
    return client.post(f"/v1/sessions/{sid}/observations", json=observation_body(outcome, step, **extra)), outcome


def drive_episode(client: httpx.Client, sid: str, robot, step: dict | None) -> list[dict]:
    """Act and observe from `step` until the episode ends; every reply, in order."""
    replies = []
    while step is not None:
        r, _ = act_and_observe(client, sid, robot, step)
        assert r.status_code == 200, r.text
        replies.append(r.json())
        step = replies[-1]["next"]
    return replies


def wait_for(predicate, timeout: float = 180, every: float = 0.2, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(every)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    """The shared server: token auth on, small limits so that tests stay small."""
    srv = Server(tmp_path_factory.mktemp("api") / "shared.sqlite",
                 "--max-particles", "64", "--max-episodes", "6", "--max-steps", "60",
                 "--max-queued", "8", "--max-sessions", "8").start()
    yield srv
    srv.stop()


@pytest.fixture()
def client(server):
    with server.client() as c:
        yield c
