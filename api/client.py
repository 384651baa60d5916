"""A Python client of the TMOC service's HTTP API (httpx).

    from api.client import TMOCClient

    tmoc = TMOCClient("http://127.0.0.1:8000", token=os.environ.get("TMOC_API_TOKEN"))
    task = tmoc.submit(agent="tmoc", particles=24, episodes=4, seed=1)
    result = tmoc.wait(task)                       # a progress bar over episodes
    for event in tmoc.events(task): ...            # SSE, resumed after a dropped connection

A robot integrator drives a session with :class:`RobotSession`::

    session = tmoc.session(particles=24, episodes=2, observation={"configuration": conf})
    while (step := session.pending) is not None:
        conf = robot.execute(step["trajectory"])   # columns t, x, y, z, yaw, opening
        reply = session.observe(conf)              # echoes action and step_id; safe to retry

Errors from the server raise :class:`TMOCError` with the status and the server's message.
"""
from __future__ import annotations

import json
import time
from typing import Any, Iterator

import httpx

TERMINAL = ("succeeded", "failed", "cancelled")


class TMOCError(RuntimeError):
    """A 4xx/5xx answer: `status` and the server's message (which names the field)."""

    def __init__(self, status: int, message: str, body: Any = None) -> None:
        super().__init__(f"{status}: {message}")
        self.status, self.message, self.body = status, message, body


class TMOCClient:
    """One service endpoint; thread-safe like httpx.Client."""

    def __init__(self, base_url: str, token: str | None = None, timeout: float = 60.0) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.base_url = base_url.rstrip("/")
        self._http = httpx.Client(base_url=self.base_url, headers=headers, timeout=timeout)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> "TMOCClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- plumbing ------------------------------------------------------------------------
    # How long a call waits out "a step is in progress" (409 with Retry-After: the server
    # answers at once instead of parking a thread behind the step).
    busy_wait_s: float = 600.0

    def _send(self, method: str, path: str, **kw) -> httpx.Response:
        """One request; an idempotent one (GET, DELETE) is sent again after a transport
        error, such as a keep-alive connection the server closed while idle."""
        for attempt in range(4):
            try:
                return self._http.request(method, path, **kw)
            except httpx.TransportError:
                if method not in ("GET", "DELETE") or attempt == 3:
                    raise
                time.sleep(0.2 * (attempt + 1))
        raise AssertionError("unreachable")

    def _call(self, method: str, path: str, **kw) -> Any:
        deadline = time.monotonic() + self.busy_wait_s
        r = self._send(method, path, **kw)
        while r.status_code == 409 and "retry-after" in r.headers and time.monotonic() < deadline:
            time.sleep(min(float(r.headers["retry-after"]), 5.0))
            r = self._send(method, path, **kw)
        if r.status_code >= 400:
            try:
                body = r.json()
            except ValueError:
                body = r.text
            message = body.get("message") or body.get("detail") if isinstance(body, dict) else body
            raise TMOCError(r.status_code, str(message), body)
        return r.json() if r.headers.get("content-type", "").startswith("application/json") else r.content

    # -- service -------------------------------------------------------------------------
    def health(self) -> dict:
        return self._call("GET", "/health")

    def domains(self) -> list[dict]:
        return self._call("GET", "/v1/domains")["items"]

    def robots(self) -> list[dict]:
        """Every registered robot: joints and limits, and for an arm its kinematics (DH
        parameters, base pose, flange-to-tool transform), to check trajectories with."""
        return self._call("GET", "/v1/robots")["items"]

    # -- tasks ---------------------------------------------------------------------------
    def submit(self, **spec) -> str:
        """Queue a task (RunConfig fields: agent, particles, episodes, seed, domain, ...);
        returns its id."""
        return self._call("POST", "/v1/tasks", json=spec)["id"]

    def get(self, task_id: str) -> dict:
        return self._call("GET", f"/v1/tasks/{task_id}")

    def cancel(self, task_id: str) -> dict:
        return self._call("DELETE", f"/v1/tasks/{task_id}")

    def belief(self, task_id: str) -> dict:
        return self._call("GET", f"/v1/tasks/{task_id}/belief")

    def curve(self, task_id: str) -> dict:
        return self._call("GET", f"/v1/tasks/{task_id}/curve")

    def episodes(self, task_id: str, after: int = -1) -> list[dict]:
        return self._call("GET", f"/v1/tasks/{task_id}/episodes", params={"after": after})

    def events(self, task_id: str, *, last_event_id: int | None = None, reconnect: bool = True,
               retries: int = 20, timeout: float = 600.0) -> Iterator[dict]:
        """The task's Server-Sent Events as dicts {event, id, data}, until its final status.

        A dropped connection (or a server restart) is resumed with Last-Event-ID = the last
        episode seen, so no episode is delivered twice or lost; `retries` bounds the
        reconnections in a row.
        """
        last, failures = last_event_id, 0
        while True:
            headers = {} if last is None else {"Last-Event-ID": str(last)}
            try:
                with self._http.stream("GET", f"/v1/tasks/{task_id}/events", headers=headers,
                                       timeout=httpx.Timeout(timeout, connect=10.0)) as r:
                    if r.status_code >= 400:
                        r.read()
                        raise TMOCError(r.status_code, r.text)
                    for event in _parse_sse(r.iter_lines()):
                        failures = 0
                        if event.get("event") == "episode" and event.get("id") is not None:
                            last = int(event["id"])
                        yield event
                        if event.get("event") == "status" and event["data"].get("status") in TERMINAL:
                            return
            except (httpx.TransportError, httpx.RemoteProtocolError):
                if not reconnect or failures >= retries:
                    raise
            failures += 1
            time.sleep(min(5.0, 0.2 * 2 ** min(failures, 5)))

    def wait(self, task_id: str, *, progress: bool = True, timeout: float = 600.0) -> dict:
        """Follow the task's events to the end (a tqdm bar over episodes); the final task."""
        from tqdm import tqdm

        task = self.get(task_id)
        bar = tqdm(total=task["progress"]["episodes"], desc=task_id, unit="ep", disable=not progress)
        bar.update(task["progress"]["episodes_done"])
        seen = task["progress"]["episodes_done"] - 1
        try:
            for event in self.events(task_id, last_event_id=seen, timeout=timeout):
                if event["event"] == "episode":
                    rec = event["data"]
                    bar.set_postfix(utility=f"{rec['utility']:.0f}",
                                    size=f"{rec['posterior']['size_mean'] * 1000:.1f}mm")
                    bar.update(1)
                elif event["data"].get("status") in TERMINAL:
                    task = event["data"]
        finally:
            bar.close()
        return task

    # -- sessions ------------------------------------------------------------------------
    def session(self, **spec) -> "RobotSession":
        """Create a robot session (RunConfig fields; `observation` starts episode 0)."""
        created = self._call("POST", "/v1/sessions", json=spec)
        return RobotSession(self, created["id"], created.get("next"))


class RobotSession:
    """The next/observe loop of one robot session."""

    def __init__(self, client: TMOCClient, session_id: str, pending: dict | None) -> None:
        self.client, self.id, self.pending = client, session_id, pending
        self.last_reply: dict | None = None

    def start_episode(self, configuration: dict, **extra) -> dict | None:
        """Start the next episode from the robot's observed configuration; the first step."""
        body = {"configuration": configuration, **extra}
        self.pending = self.client._call("POST", f"/v1/sessions/{self.id}/episodes", json=body)["next"]
        return self.pending

    def next(self) -> dict | None:
        """The pending step as the server has it (also after a restart of either side)."""
        self.pending = self.client._call("GET", f"/v1/sessions/{self.id}/next")["pending"]
        return self.pending

    def observe(self, configuration: dict, *, state: list[str] | None = None,
                measurements: list[float] | None = None, joint_positions: list[float] | None = None,
                retries: int = 3) -> dict:
        """Report what the robot observed after executing the pending step (an arm: with the
        joints it measured, from which the next step is planned). The body echoes the step's
        action and step_id, so a retry after a lost reply gets the same reply and changes
        nothing."""
        if self.pending is None:
            raise TMOCError(409, "no pending step: start an episode first")
        body: dict = {"action": self.pending["action"], "step_id": self.pending["step_id"],
                      "configuration": configuration}
        if state is not None:
            body["state"] = state
        if measurements is not None:
            body["measurements"] = measurements
        if joint_positions is not None:
            body["joint_positions"] = [float(q) for q in joint_positions]
        for attempt in range(retries + 1):
            try:
                reply = self.client._call("POST", f"/v1/sessions/{self.id}/observations", json=body)
                break
            except httpx.TransportError:
                if attempt == retries:
                    raise
                time.sleep(0.5 * (attempt + 1))
        self.last_reply, self.pending = reply, reply["next"]
        return reply

    def get(self) -> dict:
        return self.client._call("GET", f"/v1/sessions/{self.id}")

    def belief(self) -> dict:
        return self.client._call("GET", f"/v1/sessions/{self.id}/belief")

    def close(self) -> dict:
        return self.client._call("DELETE", f"/v1/sessions/{self.id}")


def _parse_sse(lines) -> Iterator[dict]:
    """SSE lines -> {event, id, data (parsed JSON)} per event."""
    cur: dict = {}
    for line in lines:
        if line == "":
            if "data" in cur:
                cur["data"] = json.loads(cur["data"])
                yield cur
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
