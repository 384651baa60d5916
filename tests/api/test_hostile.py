"""Issue 25: hostile and careless clients against a real `tmoc serve` (the shared server of
tests/api/conftest.py). Each test reproduces a row of the issue's table."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from coordinator.loop.reality import SimulatedReality
from planner import stack_and_push_symbolic as sps
from planner import symbolic as sy

from .conftest import Server, act_and_observe, free_port, observation_body, stream_events, tmoc, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


@pytest.mark.parametrize("block", ["b5000000", f"b{10 ** 40}"])
def test_a_state_naming_a_huge_block_is_refused_at_once(client, block):
    """Row 1: the state check counted every missing block b1..bN before naming the first
    (5e6: 1.9 s and +355 MiB; an atom of 64 characters allows N ~ 1e52)."""
    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.045)})
    try:
        start = robot.start_episode(np.random.default_rng(0))
    finally:
        robot.close()
    state = ["is_in(c,init)", "hand_empty(r)", "is_in(b1,init)", f"is_in({block},init)"]
    obs = {"configuration": start.configuration.to_dict(), "state": state}
    t0 = time.perf_counter()
    r = client.post("/v1/sessions", json={"particles": 2, "observation": obs})
    elapsed = time.perf_counter() - t0
    assert 400 <= r.status_code < 500 and "b2" in r.text, r.text      # the first one missing
    assert block not in r.text and len(r.text) < 300, r.text           # and not the huge one (row 12)
    assert elapsed < 1.0, elapsed


def test_both_domains_name_the_first_missing_block_without_counting_to_the_last():
    huge = f"b{10 ** 40}"
    with pytest.raises(ValueError, match="block b2 has no location"):
        sy.parse_state(["is_in(c,init)", "hand_empty(r)", "is_in(b1,init)", f"is_in({huge},init)"])
    with pytest.raises(ValueError, match="block b2 is missing"):
        sps.parse_state(["hand_empty(r)", "is_in(b1,init)", f"is_in({huge},init)"])


@pytest.mark.parametrize("domain", ["container", "stack_and_push"])
def test_one_block_is_planned(client, domain):
    """Row 7: with n_blocks 1 every task failed (`stack: expected a list of 1
    probabilities`: T gives an action whose only context is 0 as a number)."""
    spec = {"agent": "tmoc", "domain": domain, "n_blocks": 1, "particles": 2, "episodes": 1,
            "max_steps": 10, "seed": 1}
    r = client.post("/v1/tasks", json=spec)
    assert r.status_code == 202, r.text
    events = stream_events(client, r.json()["id"])
    assert events[-1]["data"]["status"] == "succeeded", events[-1]
    episode = [e for e in events if e["event"] == "episode"][0]["data"]
    assert episode["delivered"] == 1


def test_a_ray_cluster_already_on_the_machine_is_not_joined(tmp_path):
    """Row 6: `ray.init()` without an address joins any cluster running on the machine
    and refuses `num_cpus` there: beside a `ray start`, `tmoc serve` answered every
    observation with a 500. The service starts its own Ray unless given --ray-address."""
    ray_cli = Path(sys.executable).with_name("ray")
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    head = subprocess.Popen([str(ray_cli), "start", "--head", f"--port={free_port()}", "--num-cpus=1",
                             "--include-dashboard=false", "--block", "--disable-usage-stats"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    try:
        time.sleep(8)                     # the head's GCS is up
        assert head.poll() is None
        out = subprocess.run([*tmoc(), "run", "--particles", "2", "--episodes", "1", "--max-steps", "2",
                              "--counterfactual", "0", "--no-progress", "--out", str(tmp_path)],
                             capture_output=True, text=True,
                             timeout=240, env=env)
        assert out.returncode == 0, out.stderr[-2000:]
        assert json.loads((tmp_path / "result.json").read_text())["episodes"][0]["actions"] >= 1
    finally:
        head.terminate()
        head.wait(timeout=60)


def test_without_a_token_a_foreign_host_gets_400(tmp_path):
    """Row 5: a server without a token answered `Host: evil.example:PORT` (a DNS-rebinding
    page) with the whole API. It answers its loopback names, --host and --allowed-host."""
    srv = Server(tmp_path / "open.sqlite", "--allowed-host", "robot.lan", token=None).start()
    try:
        port = srv.port
        for host, code in ((f"evil.example:{port}", 400), (f"127.0.0.1:{port}", 200),
                           (f"localhost:{port}", 200), ("robot.lan", 200),
                           (f"[::1]:{port}", 200), ("[::1]", 200), (f"[::2]:{port}", 400)):   # issue 38, row 12
            r = httpx.get(f"{srv.base}/v1/tasks", headers={"Host": host}, timeout=10)
            assert r.status_code == code, (host, r.status_code, r.text)
        r = httpx.post(f"{srv.base}/v1/tasks", json={"particles": 2}, headers={"Host": "evil.example"},
                       timeout=10)
        assert r.status_code == 400
    finally:
        srv.stop()


def test_event_streams_are_capped_per_task(tmp_path):
    """Row 9: 1500 open event streams on one task were all accepted (1500 descriptors:
    two clients could lock everyone out). 16 per task, 256 in all, then 429."""
    srv = Server(tmp_path / "streams.sqlite", token=None).start()
    try:
        limits = httpx.Limits(max_connections=40, max_keepalive_connections=0)
        with httpx.Client(base_url=srv.base, timeout=30, limits=limits) as c:
            r = c.post("/v1/tasks", json={"particles": 2, "episodes": 200, "max_steps": 60, "seed": 1})
            assert r.status_code == 202, r.text
            tid = r.json()["id"]
            streams = [c.stream("GET", f"/v1/tasks/{tid}/events") for _ in range(16)]
            opened = [s.__enter__() for s in streams]
            assert all(r.status_code == 200 for r in opened)
            extra = c.get(f"/v1/tasks/{tid}/events")
            assert extra.status_code == 429 and extra.headers["retry-after"] == "5", extra.text
            streams[0].__exit__(None, None, None)                 # one closed: room for one
            time.sleep(0.5)
            with c.stream("GET", f"/v1/tasks/{tid}/events") as again:
                assert again.status_code == 200
            assert c.delete(f"/v1/tasks/{tid}").status_code in (200, 202)
            for s in streams[1:]:
                s.__exit__(None, None, None)
    finally:
        srv.stop()


def test_wrong_sign_ins_are_throttled(tmp_path):
    """Row 12: 2000 wrong tokens at POST /ui/login went through at 736 a second. After 10
    failures a minute from one address it answers 429 with Retry-After, even to the token."""
    srv = Server(tmp_path / "login.sqlite").start()
    try:
        with httpx.Client(base_url=srv.base, timeout=10) as c:
            codes = [c.post("/ui/login", json={"token": f"wrong-{i}"}).status_code for i in range(10)]
            assert codes == [401] * 10
            r = c.post("/ui/login", json={"token": "wrong-again"})
            assert r.status_code == 429 and 1 <= int(r.headers["retry-after"]) <= 60, r.text
            assert c.post("/ui/login", json={"token": srv.token}).status_code == 429
            # The address is refused its bearer too (issue 38: else 429 against 200 tells a
            # guesser when it is right); another address is not locked out.
            assert c.get("/v1/tasks", headers=srv.headers).status_code == 429
        with httpx.Client(base_url=srv.base, timeout=10,
                          transport=httpx.HTTPTransport(local_address="127.0.0.9")) as other:
            assert other.get("/v1/tasks", headers=srv.headers).status_code == 200
    finally:
        srv.stop()


def test_a_busy_session_does_not_hold_the_thread_pool(tmp_path):
    """Row 2: one observation of many particles in flight and 45 concurrent GETs of /next
    on that session used up the 40 pool threads: /health, the task list and other sessions
    waited until the step ended. Now /next answers at once (409, Retry-After) while the
    step runs, and everything else stays fast."""
    from concurrent.futures import ThreadPoolExecutor

    # 256 particles as in the issue: a step of seconds, long enough to judge (64 made
    # steps of 0.6 s, shorter than the test's own set-up of the GETs)
    server = Server(tmp_path / "busy.sqlite", "--max-particles", "256").start()
    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.045)})
    try:
        start = robot.start_episode(np.random.default_rng(0))
        with server.client() as client:
            r = client.post("/v1/sessions", json={
                "particles": 256, "particle_budget": "fixed", "episodes": 1, "max_steps": 5,
                "observation": {"configuration": start.configuration.to_dict()}})
        assert r.status_code == 201, r.text
        sid, step = r.json()["id"], r.json()["next"]
        out = robot.execute(np.array(step["trajectory"]), step["action"])
        body = observation_body(out, step)
        headers = server.headers

        def get(path):
            r = httpx.get(server.base + path, headers=headers, timeout=60)
            return r.status_code, time.perf_counter()                  # when it was answered

        def step():
            r = httpx.post(f"{server.base}/v1/sessions/{sid}/observations", json=body, headers=headers,
                           timeout=300)
            return r.status_code, time.perf_counter()

        # Judged against the step itself, not a wall-clock bound (CI's 2 cores are busy with
        # the step's physics): before the fix every answer came after the step ended (/health
        # 6.2 s, the step's length); now they come while it runs.
        with ThreadPoolExecutor(max_workers=50) as pool:
            step_done = pool.submit(step)
            time.sleep(0.3)                                           # the step is under way
            nexts = [pool.submit(get, f"/v1/sessions/{sid}/next") for _ in range(45)]
            time.sleep(0.2)
            asked = time.perf_counter()
            health = get("/health")
            tasks = get("/v1/tasks")
            answered = [f.result() for f in nexts]
            code, step_end = step_done.result()
        assert code == 200
        assert asked < step_end, "the step ended before the test could judge it"
        assert health[0] == 200 and tasks[0] == 200
        assert health[1] < step_end and tasks[1] < step_end, (health[1] - step_end, tasks[1] - step_end)
        assert all(c in (200, 409) for c, _ in answered), answered
        busy = [t for c, t in answered if c == 409]
        assert busy and all(t < step_end for t in busy), len(busy)    # told at once, during the step
    finally:
        robot.close()
        server.stop()


def test_a_body_of_nested_containers_costs_the_loop_nothing(server, client):
    """Row 3: a 4 MiB body `[[{}],[{}],...]` to the open POST /ui/login stalled /health for
    2.8 s (the key counter parsed it on the event loop). Sign-in bodies are capped at 4 KiB
    and every JSON body's objects and arrays are counted in C before any parse."""
    from concurrent.futures import ThreadPoolExecutor

    bomb = b"[" + b",".join([b"[{}]"] * 800_000) + b"]"
    assert len(bomb) < 4 * 1024 * 1024

    def send(path, headers):
        t0 = time.perf_counter()
        r = httpx.post(server.base + path, content=bomb, timeout=60,
                       headers={"content-type": "application/json", **headers})
        return r.status_code, time.perf_counter() - t0

    with ThreadPoolExecutor(max_workers=5) as pool:
        sent = [pool.submit(send, "/ui/login", {}) for _ in range(3)]
        sent.append(pool.submit(send, "/v1/tasks", server.headers))
        time.sleep(0.2)
        t0 = time.perf_counter()
        assert httpx.get(server.base + "/health", timeout=10).status_code == 200
        health_s = time.perf_counter() - t0
        codes = [f.result() for f in sent]
    assert [c for c, _ in codes] == [413, 413, 413, 422], codes
    assert health_s < 0.5, health_s
    assert max(t for _, t in codes) < 3.0, codes


def test_a_cancel_takes_effect_within_an_action(server, client):
    """Row 4: cancellation waited for the episode to end: 108.7 s at 16 blocks, while
    every queued task waited. It is now polled before every action."""
    spec = {"agent": "tmoc", "particles": 8, "episodes": 2, "n_blocks": 16, "max_steps": 60,
            "particle_budget": "fixed", "seed": 1}
    tid = client.post("/v1/tasks", json=spec).json()["id"]
    wait_for(lambda: client.get(f"/v1/tasks/{tid}").json()["status"] == "running", timeout=120,
             what="the task to start")
    time.sleep(3.0)                                             # a few actions in
    t0 = time.perf_counter()
    assert client.delete(f"/v1/tasks/{tid}").status_code in (200, 202)
    wait_for(lambda: client.get(f"/v1/tasks/{tid}").json()["status"] == "cancelled", timeout=60,
             every=0.1, what="the cancel")
    assert time.perf_counter() - t0 < 15.0
    assert client.get(f"/v1/tasks/{tid}").json()["progress"]["episodes_done"] == 0


def test_a_task_stops_at_its_budget_and_the_queue_goes_on(server, client):
    """Row 4: no per-task budget existed; at the accepted maxima one task held the worker for
    hours. `max_runtime_s` (capped by --max-task-runtime-s, its default) stops it within
    one action: it fails naming the budget, and the next queued task runs."""
    spec = {"agent": "tmoc", "particles": 8, "episodes": 2, "n_blocks": 16, "max_steps": 60,
            "particle_budget": "fixed", "seed": 1, "max_runtime_s": 3}
    long_id = client.post("/v1/tasks", json=spec).json()["id"]
    after = client.post("/v1/tasks", json={"particles": 2, "episodes": 1, "n_blocks": 2,
                                           "seed": 2, "frames": False})
    assert after.status_code == 202, after.text
    wait_for(lambda: client.get(f"/v1/tasks/{long_id}").json()["status"] == "running", timeout=120,
             every=0.1, what="the task to start")
    t0 = time.perf_counter()
    wait_for(lambda: client.get(f"/v1/tasks/{long_id}").json()["status"] == "failed", timeout=60,
             every=0.1, what="the budget")
    assert time.perf_counter() - t0 < 3.0 + 12.0                  # the budget plus one action
    task = client.get(f"/v1/tasks/{long_id}").json()
    assert task["error"].startswith("budget: the task ran past its max_runtime_s of 3 s"), task
    assert task["progress"]["episodes_done"] == 0
    wait_for(lambda: client.get(f"/v1/tasks/{after.json()['id']}").json()["status"] == "succeeded",
             timeout=120, what="the next task")


def test_a_budget_over_the_server_s_cap_is_refused_by_name(client):
    r = client.post("/v1/tasks", json={"particles": 2, "episodes": 1, "max_runtime_s": 1e9})
    assert r.status_code == 422
    assert "max_runtime_s" in r.json()["message"] and "--max-task-runtime-s 3600" in r.json()["message"]
    r = client.post("/v1/tasks", json={"particles": 2, "episodes": 1, "max_runtime_s": 0})
    assert r.status_code == 422 and "max_runtime_s" in r.json()["message"]


def _session_mid_episode(srv: Server, robot: SimulatedReality, particles: int, steps: int) -> tuple[str, dict]:
    """A robot session of `particles` with `steps` observed steps of its first episode:
    (its id, the pending step), so a restart must replay those steps."""
    with srv.client() as c:
        obs = robot.start_episode(np.random.default_rng(0))
        r = c.post("/v1/sessions", json={"particles": particles, "episodes": 1, "max_steps": 20, "seed": 4,
                                         "observation": {"configuration": obs.configuration.to_dict()}})
        assert r.status_code == 201, r.text
        sid, step = r.json()["id"], r.json()["next"]
        for _ in range(steps):
            out = robot.execute(np.array(step["trajectory"]), step["action"])
            r = c.post(f"/v1/sessions/{sid}/observations",
                       json={"action": step["action"], "step_id": step["step_id"],
                             "configuration": out.configuration.to_dict()})
            assert r.status_code == 200, r.text
            step = r.json()["next"]
    return sid, step


def test_after_a_restart_a_session_is_restored_in_the_background(tmp_path):
    """Row 8: the first request after a restart replayed the episode itself (22.4 s at 128
    particles, past the client's timeout). Sessions are replayed on a thread at start-up;
    a request meanwhile gets 409 "being restored" with Retry-After at once, which the Python
    client waits out; the step is the one before the restart."""
    from api.client import TMOCClient

    db = tmp_path / "restore.sqlite"
    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.050)})
    srv = Server(db, token=None).start()
    try:
        sid, step = _session_mid_episode(srv, robot, particles=32, steps=3)   # a replay of ~5 s on 2 cores
        srv.stop()
        srv = Server(db, token=None).start()
        with srv.client() as c:
            t0 = time.perf_counter()
            first = c.get(f"/v1/sessions/{sid}/next")
            answered = time.perf_counter() - t0
            assert answered < 2.0, answered                     # never the replay's seconds
            if first.status_code == 409:                          # a fast machine may be done
                assert "being restored" in first.json()["detail"], first.text
                assert first.headers["retry-after"]
            else:
                assert first.status_code == 200, first.text
        with TMOCClient(srv.base) as client:
            nxt = client._call("GET", f"/v1/sessions/{sid}/next")["pending"]
        assert nxt["step_id"] == step["step_id"] and nxt["action"] == step["action"]
        np.testing.assert_array_equal(nxt["trajectory"], step["trajectory"])
    finally:
        srv.stop()
        robot.close()


def _group_members(pgid: int) -> list[int]:
    """The live processes of process group `pgid` (a zombie has ended: reaping it is its
    new parent's business, and an init that does not reap would keep it forever)."""
    if not os.path.isdir("/proc"):                 # no /proc: the group as kill() sees it
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return []
        return [pgid]
    members = []
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                text = open(f"/proc/{entry.name}/stat").read()
            except OSError:
                continue
            fields = text[text.rindex(")") + 2:].split()
            if int(fields[2]) == pgid and fields[0] not in "ZX":
                members.append(int(entry.name))
    return members


def _group_gone(pgid: int, timeout: float) -> bool:
    """Whether every process of the server's group (Ray's included) has ended."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not _group_members(pgid):
            return True
        time.sleep(0.1)
    return False


def _group_listing(pgid: int) -> str:
    """`ps`'s lines for the processes left in the group (what outlived the server)."""
    import subprocess

    out = subprocess.run(["ps", "-o", "pid,ppid,stat,etime,args", "-g", str(pgid)],
                         capture_output=True, text=True, check=False)
    return out.stdout


def test_a_sigterm_during_the_start_up_restore_ends_the_server_at_once(tmp_path):
    """Row 11: a SIGTERM during the start-up restore waited 7-11 s (8.5 s measured) for
    Ray's start and the replay, past Docker's 10 s stop timeout, and the replay thread then
    started a second Ray cluster through Ray's auto-init. Now the replay stops at its next
    step, nothing waits for a Ray still starting, and the next start restores the session
    to the same step: tried while Ray starts, then while the replay simulates."""
    db = tmp_path / "sigterm.sqlite"
    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.050)})
    srv = Server(db, token=None).start()
    try:
        sid, step = _session_mid_episode(srv, robot, particles=96, steps=4)   # ~8 s once Ray is up
        srv.stop()
        for ray_up in (False, True):
            srv = Server(db, token=None).start()
            with srv.client() as c:
                # Ray starting (ray.init takes 3-5 s on 2 cores), or up with the replay
                # simulating (~5 s more here; a faster machine may be done: not asserted)
                want = "ready" if ray_up else "starting"
                wait_for(lambda c=c, want=want: c.get("/health").json()["ray"] == want,
                         timeout=120, every=0.05, what="Ray")
                time.sleep(1.0 if ray_up else 0.3)
                if not ray_up:
                    assert c.get(f"/v1/sessions/{sid}/next").status_code == 409   # being restored
            t0 = time.perf_counter()
            srv.proc.send_signal(signal.SIGTERM)
            srv.proc.wait(30)
            took = time.perf_counter() - t0
            # was 5.9 s while Ray started; with Ray up, Ray's own shutdown (~2.3 s) is most of it
            assert took < (8.0 if ray_up else 3.0), (ray_up, took, srv.log())
            assert _group_gone(srv.proc.pid, 15.0), ("Ray's processes outlived the server", ray_up,
                                                     _group_listing(srv.proc.pid))
            assert "Traceback" not in srv.log(), srv.log()
        srv = Server(db, token=None).start()
        from api.client import TMOCClient

        with TMOCClient(srv.base) as client:
            nxt = client._call("GET", f"/v1/sessions/{sid}/next")["pending"]
        assert nxt["step_id"] == step["step_id"] and nxt["action"] == step["action"]
        np.testing.assert_array_equal(nxt["trajectory"], step["trajectory"])
    finally:
        srv.stop()
        robot.close()


def test_an_abandoned_session_stops_holding_a_slot(tmp_path):
    """Row 14: abandoned sessions (a create retried after a lost reply leaks one) held
    --max-sessions slots forever. One idle for --session-idle-s no longer counts; it
    still answers when its robot comes back."""
    srv = Server(tmp_path / "idle.sqlite", "--max-sessions", "1", "--session-idle-s", "3",
                 token=None).start()
    try:
        with srv.client() as c:
            spec = {"particles": 2, "episodes": 1, "n_blocks": 2}
            first = c.post("/v1/sessions", json=spec)
            assert first.status_code == 201, first.text
            full = c.post("/v1/sessions", json=spec)
            assert full.status_code == 429
            assert "idle for 3 s (--session-idle-s) stops counting" in full.json()["detail"]
            time.sleep(3.5)
            assert c.post("/v1/sessions", json=spec).status_code == 201
            back = c.get(f"/v1/sessions/{first.json()['id']}")
            assert back.status_code == 200 and back.json()["status"] == "active"
    finally:
        srv.stop()


@pytest.mark.timeout(300)
def test_a_returning_idle_session_is_replayed_in_the_background(tmp_path):
    """Issue 38, row 10: a robot returning after --session-idle-s waited for its whole
    episode's replay inside its first request, and idle sessions left memory only when
    someone created a session. Now eviction runs on a timer and the first request gets 409
    "being restored" with Retry-After at once; the Python client waits it out and gets the
    step it left at."""
    from api.client import TMOCClient

    robot = SimulatedReality("container", {"n_blocks": 4}, {"block_sizes": np.full(4, 0.045)})
    # Idle after 6 s: the robot's own step between two requests (its world acting, in this
    # process) took over 2 s on a loaded 2-core CI machine, and a 2 s limit then evicted the
    # session mid-episode, before the test's idle wait (a 409 on the second step).
    srv = Server(tmp_path / "idle-replay.sqlite", "--session-idle-s", "6", token=None).start()
    try:
        with srv.client() as c:
            obs = robot.start_episode(np.random.default_rng(0))
            r = c.post("/v1/sessions", json={"particles": 16, "episodes": 1, "n_blocks": 4, "max_steps": 20,
                                             "seed": 4, "observation": {"configuration": obs.configuration.to_dict()}})
            assert r.status_code == 201, r.text
            sid, step = r.json()["id"], r.json()["next"]
            for _ in range(2):
                r, _ = act_and_observe(c, sid, robot, step)
                assert r.status_code == 200, r.text
                step = r.json()["next"]
            time.sleep(10.0)                     # idle past 6 s, and the timer (every 3 s) ran
            t0 = time.perf_counter()
            first = c.get(f"/v1/sessions/{sid}/next")
            assert time.perf_counter() - t0 < 1.0
            assert first.status_code == 409 and "being restored" in first.json()["detail"], first.text
            assert int(first.headers["retry-after"]) > 0
        with TMOCClient(srv.base) as client:
            nxt = client._call("GET", f"/v1/sessions/{sid}/next")["pending"]
        assert nxt["step_id"] == step["step_id"] and nxt["action"] == step["action"]
    finally:
        srv.stop()
        robot.close()


def test_after_kill_9_ray_goes_within_seconds(tmp_path):
    """Row 14: after `kill -9` of the server two of Ray's agents lived 60-120 s (they wait
    a fixed 60 s for a GCS that is gone). The server's reaper takes them down."""
    import signal

    from coordinator.distributed.reaper import alive, descendants

    srv = Server(tmp_path / "k9.sqlite", token=None).start()
    try:
        with srv.client() as c:
            tid = c.post("/v1/tasks", json={"particles": 2, "episodes": 1, "n_blocks": 2,
                                            "frames": False}).json()["id"]
            wait_for(lambda: c.get(f"/v1/tasks/{tid}").json()["status"] == "succeeded", timeout=180,
                     what="a task (Ray started)")
        started = descendants(srv.proc.pid)
        assert len(started) >= 4, started                # GCS, raylet, agents, workers, reaper
        srv.proc.send_signal(signal.SIGKILL)
        srv.proc.wait(30)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 20 and any(alive(p, s) for p, s in started.items()):
            time.sleep(0.25)
        left = [Path(f"/proc/{p}/cmdline").read_bytes()[:60] for p, s in started.items() if alive(p, s)]
        assert not left, (time.monotonic() - t0, left)
    finally:
        srv.stop()


def test_the_docs_page_runs_only_the_service_s_own_scripts(server, client):
    """Row 13: /docs loaded Swagger's script from a CDN (floating version, no SRI, no CSP)
    into a page with the session cookie's rights. It is served from the installed
    fastapi-offline's Swagger UI files, under a CSP that lets only the service's own scripts run."""
    import re

    page = client.get("/docs")
    assert page.status_code == 200
    csp = page.headers["content-security-policy"]
    assert "script-src 'self'" in csp and "unsafe-inline" not in csp.split("script-src")[1].split(";")[0]
    scripts = re.findall(r'<script[^>]*src="([^"]+)"', page.text)
    assert scripts and all(src.startswith("/docs/") for src in scripts), scripts
    assert "<script>" not in page.text                             # no inline script
    js = client.get("/docs/swagger-ui-bundle.js")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    assert len(js.content) > 500_000
    assert client.get("/docs/init.js").status_code == 200
    assert client.get("/docs/../openapi.json").status_code in (200, 404)   # no path games past the table
    assert client.get("/docs/passwd").status_code == 404
    assert httpx.get(server.base + "/docs/swagger-ui-bundle.js", timeout=10).status_code == 401   # gated
