"""Soak: a normal task and a robot session beside mixed hostile traffic (issue 25).

    python benchmarks/soak_hostile.py [--minutes 10] [--out FILE.json]

Starts one `tmoc serve` (a real uvicorn process with its own two-CPU Ray, a token set) on a
fresh database. First, alone: a normal task and a robot session (driven by the built-in
simulated reality through the Python client) are run and their results kept. Then, for
`--minutes`, hostile clients replay the reproductions of the issue's table, each at a
bounded rate, while the same task and session are run again, as often as the time allows,
and a prober reads `/health` every 0.1 s:

- row 1: sessions whose state names block b5000000 (and b10^40);
- row 2: 45 concurrent `GET /next` on the normal session while it steps;
- row 3: 4 MiB bodies of nested containers at `POST /ui/login` without credentials;
- row 4: 16-block tasks with a 3 s budget, and the same cancelled after 2 s;
- row 7: one-block tasks; row 9: 24 event streams on one task (16 allowed);
- row 12: wrong tokens at `POST /ui/login`; row 14: text/plain bodies, trailing periods;
- issue 38: five concurrent exports of the latest task and two opened and never read,
  wrong bearer tokens as fast as they are answered, a corrupt session row written
  into the database (the session list must stay 200, leaving it out), and the server
  started with three broken domain plugins installed (`GET /v1/domains` lists them).

The guessers (rows 12 and 38) connect from other loopback addresses (127.0.0.7, .8): the
throttle refuses a guessing address, and the normal clients' 127.0.0.1 must go on.

Prints `/health`'s p50/p99/max, what every hostile kind got (status codes), whether each
run of the normal task and session had the same results as alone (timings aside), and the
server process's resident memory before the hostile clients and 10 s after they left.
Exit status 1 if p99 >= 0.5 s, any result differs, or the memory grew by more than 20 %.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

import httpx
import numpy as np

from api.client import TMOCClient
from bench_api import free_port, pct   # benchmarks/ is on sys.path when run as a script
from coordinator.loop.reality import SimulatedReality

TOKEN = "soak-token-0123456789"
TASK = {"agent": "tmoc", "particles": 8, "episodes": 2, "n_blocks": 4, "max_steps": 30, "seed": 7,
        "frames": False}
SESSION = {"particles": 8, "episodes": 1, "n_blocks": 4, "max_steps": 30, "seed": 3}
TIMINGS = ("wall_s", "physics_s", "planning_s")


def _strip(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in TIMINGS} for r in records]


# ------------------------------------------------------------------------ normal work
def run_task(c: TMOCClient) -> list[dict]:
    """The normal task's stored episodes, timings left out."""
    tid = c.submit(**TASK)
    task = c.wait(tid, progress=False, timeout=1800)
    assert task["status"] == "succeeded", task
    return _strip(c.episodes(tid))


def run_session(c: TMOCClient, session_ids: list[str]) -> dict:
    """Drive the normal robot session to its end; its actions, posteriors and episodes."""
    robot = SimulatedReality("container", {"n_blocks": SESSION["n_blocks"]},
                             {"block_sizes": np.full(SESSION["n_blocks"], 0.041)})
    try:
        start = robot.start_episode(np.random.default_rng(SESSION["seed"]))
        s = c.session(**SESSION, observation={"configuration": start.configuration.to_dict()})
        session_ids.append(s.id)
        actions, posteriors, episodes = [], [], []
        while s.pending is not None:
            step = s.pending
            out = robot.execute(np.array(step["trajectory"]), step["action"])
            reply = s.observe(out.configuration.to_dict())
            actions.append(step["action"])
            posteriors.append(reply["posterior"])
            if reply["episode_done"]:
                episodes.append({k: v for k, v in reply["episode"].items() if k not in TIMINGS})
        s.close()
        return {"actions": actions, "posteriors": posteriors, "episodes": episodes}
    finally:
        robot.close()


# -------------------------------------------------------------------------- hostility
class Hostile:
    """The hostile clients: one thread per kind, each at a bounded rate."""

    def __init__(self, base: str, stop: threading.Event, session_ids: list[str], db: str) -> None:
        self.base, self.stop, self.session_ids, self.db = base, stop, session_ids, db
        self.codes: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        self.auth = {"Authorization": f"Bearer {TOKEN}"}
        robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, 0.045)})
        try:           # a real scene's configuration: the state check is what is attacked
            self.configuration = robot.start_episode(np.random.default_rng(0)).configuration.to_dict()
        finally:
            robot.close()

    def _loop(self, kind: str, every_s: float, fn, address: str | None = None) -> None:
        transport = httpx.HTTPTransport(local_address=address) if address else None
        with httpx.Client(base_url=self.base, timeout=60, transport=transport) as c:
            while not self.stop.is_set():
                try:
                    for code in fn(c):
                        self.codes[kind][code] += 1
                except httpx.HTTPError as exc:
                    self.codes[kind][type(exc).__name__] += 1
                self.stop.wait(every_s)

    def huge_block(self, c):
        for block in ("b5000000", f"b{10 ** 40}"):
            state = ["is_in(c,init)", "hand_empty(r)", "is_in(b1,init)", f"is_in({block},init)"]
            body = {"particles": 2, "episodes": 1,
                    "observation": {"configuration": self.configuration, "state": state}}
            yield c.post("/v1/sessions", json=body, headers=self.auth).status_code

    def busy_session(self, c):
        if not self.session_ids:
            return
        sid = self.session_ids[-1]
        with httpx.Client(base_url=self.base, timeout=60,
                          limits=httpx.Limits(max_connections=45)) as many:
            results: list[int] = []
            threads = [threading.Thread(target=lambda: results.append(
                many.get(f"/v1/sessions/{sid}/next", headers=self.auth).status_code)) for _ in range(45)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
        yield from results

    def nested_body(self, c):
        body = b"[" + b",".join([b"[{}]"] * (4 * 1024 * 1024 // 5)) + b"]"
        yield c.post("/ui/login", content=body[:4 * 1024 * 1024 - 1] + b"]",
                     headers={"content-type": "application/json"}).status_code

    def long_tasks(self, c):
        spec = {"agent": "tmoc", "particles": 8, "episodes": 2, "n_blocks": 16, "max_steps": 200,
                "particle_budget": "fixed", "max_runtime_s": 3, "frames": False}
        r = c.post("/v1/tasks", json=spec, headers=self.auth)
        yield r.status_code
        r2 = c.post("/v1/tasks", json={**spec, "max_runtime_s": 60}, headers=self.auth)
        yield r2.status_code
        if r2.status_code == 202:
            time.sleep(2.0)
            yield c.delete(f"/v1/tasks/{r2.json()['id']}", headers=self.auth).status_code

    def one_block(self, c):
        yield c.post("/v1/tasks", json={"particles": 2, "episodes": 1, "n_blocks": 1, "max_steps": 4,
                                        "frames": False}, headers=self.auth).status_code

    def streams(self, c):
        tasks = c.get("/v1/tasks", headers=self.auth, params={"limit": 1}).json().get("items", [])
        if not tasks:
            return
        tid = tasks[0]["id"]
        opened = []
        try:
            for _ in range(24):
                s = c.stream("GET", f"/v1/tasks/{tid}/events", headers=self.auth)
                r = s.__enter__()
                opened.append(s)
                yield r.status_code
            time.sleep(1.0)
        finally:
            for s in opened:
                s.__exit__(None, None, None)

    def wrong_tokens(self, c):
        for _ in range(5):
            yield c.post("/ui/login", json={"token": "wrong"}).status_code

    def bearer_guess(self, c):
        for k in range(20):
            yield c.get("/v1/tasks", headers={"Authorization": f"Bearer guess-{k}"}).status_code

    def corrupt_row(self, c):
        import sqlite3

        sid = f"s_corrupt{time.monotonic_ns()}"
        with sqlite3.connect(self.db, timeout=30) as raw:
            raw.execute("INSERT INTO sessions (id, spec, status, created_at, updated_at, checkpoint, pending) "
                        "VALUES (?, '{}', 'closed', ?, ?, '{}', '{')", (sid, time.time(), time.time()))
        r = c.get("/v1/sessions", headers=self.auth, params={"limit": 200})
        yield r.status_code
        yield "skipped" if r.status_code == 200 and r.json().get("skipped") else "not skipped"

    def broken_plugins(self, c):
        r = c.get("/v1/domains", headers=self.auth)
        yield r.status_code
        yield "listed" if r.status_code == 200 and len(r.json().get("broken", {})) == 3 else "not listed"

    def exports(self, c):
        """Issue 38, rows 1-3: five exports of the latest task at once, and two that are
        opened and never read (each the server must bound, then drop)."""
        tasks = c.get("/v1/tasks", headers=self.auth, params={"limit": 1}).json().get("items", [])
        if not tasks:
            return
        url = f"/v1/tasks/{tasks[0]['id']}/export"
        codes: list = []

        def read_all() -> None:
            with httpx.stream("GET", self.base + url, headers=self.auth, timeout=120) as r:
                codes.append(r.status_code)
                for _ in r.iter_bytes():
                    pass

        unread = [httpx.Client(base_url=self.base, timeout=120) for _ in range(2)]
        streams = [u.stream("GET", url, headers=self.auth) for u in unread]
        for st in streams:
            codes.append(st.__enter__().status_code)       # headers only: the body is not read
        threads = [threading.Thread(target=read_all) for _ in range(5)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        time.sleep(5.0)
        for st, u in zip(streams, unread):
            st.__exit__(None, None, None)
            u.close()
        yield from codes

    def careless(self, c):
        yield c.post("/v1/tasks", content=b"hello", headers={**self.auth, "content-type": "text/plain"}).status_code
        yield c.post("/v1/tasks", content=b"{not json", headers={**self.auth,
                                                                  "content-type": "application/json"}).status_code
        yield c.get("/v1/tasks/t-nope", headers=self.auth).status_code
        yield c.get("/v1/tasks", headers={"Host": "evil.example"}).status_code

    def start(self) -> list[threading.Thread]:
        kinds = [("row 1 huge block", 1.0, self.huge_block), ("row 2 busy session", 2.0, self.busy_session),
                 ("row 3 nested body", 2.0, self.nested_body), ("row 4 long task", 10.0, self.long_tasks),
                 ("row 7 one block", 20.0, self.one_block), ("row 9 streams", 5.0, self.streams),
                 ("row 12 wrong token", 1.0, self.wrong_tokens, "127.0.0.7"),
                 ("row 14 careless", 0.5, self.careless),
                 ("38 bearer guess", 0.05, self.bearer_guess, "127.0.0.8"),
                 ("38 corrupt row", 30.0, self.corrupt_row), ("38 broken plugins", 10.0, self.broken_plugins),
                 ("38 exports", 5.0, self.exports)]
        threads = [threading.Thread(target=self._loop, args=k, daemon=True, name=k[0]) for k in kinds]
        for t in threads:
            t.start()
        return threads


def broken_plugins(tmp: str) -> str:
    """A folder holding three installed domain plugins that do not work (as pip installs
    them: a .dist-info with entry points): a module that is not installed, version 0, a
    physics half that does not import. The server must start and serve the rest."""
    root = os.path.join(tmp, "plugins")
    info = os.path.join(root, "tmoc_soak_broken-0.1.dist-info")
    os.makedirs(info)
    with open(os.path.join(info, "METADATA"), "w") as f:
        f.write("Metadata-Version: 2.1\nName: tmoc-soak-broken\nVersion: 0.1\n")
    with open(os.path.join(info, "entry_points.txt"), "w") as f:
        f.write("[tmoc.domains]\nghost = tmoc_soak_not_installed:DOMAIN\nzero = tmoc_soak_broken:ZERO\n"
                "hollow = tmoc_soak_broken:HOLLOW\n")
    with open(os.path.join(root, "tmoc_soak_broken.py"), "w") as f:
        f.write('ZERO = {"physics": "sim_workers.container:ContainerDomain", '
                '"task": "planner.container:ContainerTask", "version": 0}\n'
                'HOLLOW = {"physics": "tmoc_soak_gone:Physics", "task": "planner.container:ContainerTask"}\n')
    return root


def rss_mib(pid: int) -> float:
    """The server process's resident memory (MiB; its own, not Ray's processes)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return round(int(line.split()[1]) / 1024, 1)
    return float("nan")


def probe_health(base: str, stop: threading.Event, out: list[float]) -> None:
    with httpx.Client(base_url=base, timeout=30) as c:
        while not stop.is_set():
            t0 = time.perf_counter()
            try:
                c.get("/health")
                out.append(time.perf_counter() - t0)
            except httpx.HTTPError:
                out.append(float("inf"))
            stop.wait(0.1)


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--out", default=None, help="also write the figures as JSON here")
    args = ap.parse_args()

    port = free_port()
    tmp = tempfile.mkdtemp(prefix="soak_hostile_")
    log = open(os.path.join(tmp, "server.log"), "w")
    plugins = broken_plugins(tmp)
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", TMOC_API_TOKEN=TOKEN,
               PYTHONPATH=os.pathsep.join(filter(None, [plugins, os.environ.get("PYTHONPATH")])))
    proc = subprocess.Popen([sys.executable, "-m", "coordinator.cli", "serve", "--port", str(port),
                             "--db", os.path.join(tmp, "soak.sqlite"), "--no-access-log",
                             "--log-level", "warning", "--max-queued", "64"],
                            stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        client = TMOCClient(base, token=TOKEN, timeout=120)
        for _ in range(600):
            try:
                client.health()
                break
            except (httpx.TransportError, Exception):
                time.sleep(0.1)
        t0 = time.perf_counter()
        alone_task = run_task(client)
        alone_session = run_session(client, [])
        alone_s = time.perf_counter() - t0
        print(f"alone: task {len(alone_task)} episodes, session {len(alone_session['actions'])} steps, "
              f"{alone_s:.0f} s", flush=True)

        rss_start = rss_mib(proc.pid)
        stop = threading.Event()
        health: list[float] = []
        session_ids: list[str] = []
        prober = threading.Thread(target=probe_health, args=(base, stop, health), daemon=True)
        prober.start()
        hostile = Hostile(base, stop, session_ids, os.path.join(tmp, "soak.sqlite"))
        threads = hostile.start()
        end = time.monotonic() + args.minutes * 60
        same_task, same_session, rounds = [], [], 0
        while time.monotonic() < end:
            holder: dict = {}
            t = threading.Thread(target=lambda: holder.update(s=run_session(client, session_ids)))  # noqa: B023 (joined below)
            t.start()
            same_task.append(run_task(client) == alone_task)
            t.join()
            same_session.append(holder.get("s") == alone_session)
            rounds += 1
            print(f"round {rounds}: task same {same_task[-1]}, session same {same_session[-1]}, "
                  f"/health p99 so far {pct(health, 99) * 1000:.0f} ms", flush=True)
        stop.set()
        for th in threads + [prober]:
            th.join(timeout=120)
        time.sleep(10.0)                     # the clients have left: what the server keeps
        rss_end = rss_mib(proc.pid)
        figures = {
            "server_rss_mib_start": rss_start, "server_rss_mib_after": rss_end,
            "minutes": args.minutes, "rounds": rounds, "health_requests": len(health),
            "health_p50_ms": round(pct(health, 50) * 1000, 1),
            "health_p99_ms": round(pct(health, 99) * 1000, 1),
            "health_max_ms": round(max(health) * 1000, 1),
            "task_same_as_alone": f"{sum(same_task)}/{len(same_task)}",
            "session_same_as_alone": f"{sum(same_session)}/{len(same_session)}",
            "hostile": {k: dict(v) for k, v in sorted(hostile.codes.items())},
        }
        print(json.dumps(figures, indent=1))
        if args.out:
            with open(args.out, "w") as f:
                json.dump(figures, f, indent=1)
        ok = (figures["health_p99_ms"] < 500 and all(same_task) and all(same_session) and rounds > 0
              and rss_end <= 1.2 * rss_start)
        return 0 if ok else 1
    finally:
        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(60)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            os.killpg(proc.pid, signal.SIGKILL)


if __name__ == "__main__":
    raise SystemExit(main())
