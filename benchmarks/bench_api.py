"""Latency of the HTTP service while a task keeps both cores busy.

    python benchmarks/bench_api.py [--requests 400] [--streams 60] [--particles 24]

Starts `tmoc serve` (a real uvicorn process with its own local two-CPU Ray) on a fresh
database, submits a TMOC task big enough to keep both cores busy (two shard actors
simulating particles, plus the server's worker thread executing the simulated reality and
planning), and while it runs measures, from a separate client process:

- `GET /v1/tasks/{id}`: request -> full JSON response, sequential, keep-alive;
- the event stream: connect to `GET /v1/tasks/{id}/events` with `Last-Event-ID: -1` -> the
  first stored episode event received (a client resuming and catching up); a second
  client keeps a live stream open all along (episode events pushed as they are stored).

Prints p50/p99 of each and the CPU load seen during the measurement (the aim: p99 < 50 ms).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import httpx


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))]


def cpu_times() -> tuple[float, float]:
    with open("/proc/stat") as f:
        parts = [float(x) for x in f.readline().split()[1:]]
    idle = parts[3] + parts[4]
    return sum(parts), idle


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--requests", type=int, default=400)
    ap.add_argument("--streams", type=int, default=60)
    ap.add_argument("--particles", type=int, default=24)
    args = ap.parse_args()

    port = free_port()
    tmp = tempfile.mkdtemp(prefix="bench_api_")
    log = open(os.path.join(tmp, "server.log"), "w")
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    env.pop("TMOC_API_TOKEN", None)
    proc = subprocess.Popen([sys.executable, "-m", "coordinator.cli", "serve", "--port", str(port),
                             "--db", os.path.join(tmp, "bench.sqlite"), "--no-access-log",
                             "--log-level", "warning"],
                            stdout=log, stderr=subprocess.STDOUT, env=env, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    client = httpx.Client(base_url=base, timeout=30)
    try:
        for _ in range(300):
            try:
                if client.get("/health").status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
        # A first tiny task starts Ray and the shard pool, so the measurement sees a steady state.
        warm = client.post("/v1/tasks", json={"particles": 2, "episodes": 1, "max_steps": 1}).json()["id"]
        while client.get(f"/v1/tasks/{warm}").json()["status"] not in ("succeeded", "failed"):
            time.sleep(0.2)
        spec = {"agent": "tmoc", "particles": args.particles, "episodes": 50, "max_steps": 8, "seed": 1}
        task = client.post("/v1/tasks", json=spec).json()["id"]

        # Live events on an open stream, in the background.
        live: list[float] = []

        def listen() -> None:
            with httpx.Client(base_url=base, timeout=None) as c, c.stream("GET", f"/v1/tasks/{task}/events") as r:
                event = None
                for line in r.iter_lines():
                    if line.startswith("event:"):
                        event = line.split(":", 1)[1].strip()
                    elif line.startswith("data:") and event == "episode":
                        live.append(time.time())
                    elif line.startswith("data:") and event == "status" and '"status":"running"' not in line \
                            and '"status":"queued"' not in line:
                        return

        t_listen = threading.Thread(target=listen, daemon=True)
        t_listen.start()
        while client.get(f"/v1/tasks/{task}").json()["progress"]["episodes_done"] < 1:
            time.sleep(0.2)

        total0, idle0 = cpu_times()
        get_ms = []
        for _ in range(args.requests):
            t0 = time.perf_counter()
            r = client.get(f"/v1/tasks/{task}")
            r.json()
            get_ms.append((time.perf_counter() - t0) * 1000)
            assert r.status_code == 200, r.text
            time.sleep(0.005)
        stream_ms = []
        for _ in range(args.streams):
            t0 = time.perf_counter()
            with client.stream("GET", f"/v1/tasks/{task}/events", headers={"Last-Event-ID": "-1"}) as r:
                for line in r.iter_lines():
                    if line.startswith("id:"):
                        break
            stream_ms.append((time.perf_counter() - t0) * 1000)
            time.sleep(0.01)
        total1, idle1 = cpu_times()
        busy = 1 - (idle1 - idle0) / max(1e-9, total1 - total0)
        status = client.get(f"/v1/tasks/{task}").json()
        client.delete(f"/v1/tasks/{task}")
        print(json.dumps({
            "device": f"{os.cpu_count()} cores; task: tmoc {args.particles} particles, max_steps 8, "
                      f"{status['progress']['episodes_done']} episodes done during the run",
            "cpu_busy_during_measurement": round(busy, 3),
            "GET /v1/tasks/{id}": {"n": len(get_ms), "p50_ms": round(statistics.median(get_ms), 2),
                                   "p99_ms": round(pct(get_ms, 99), 2), "max_ms": round(max(get_ms), 2)},
            "events: connect -> first episode event": {
                "n": len(stream_ms), "p50_ms": round(statistics.median(stream_ms), 2),
                "p99_ms": round(pct(stream_ms, 99), 2), "max_ms": round(max(stream_ms), 2)},
            "live episode events received": len(live),
            "aim": "p99 < 50 ms",
        }, indent=2))
        return 0
    finally:
        client.close()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
        try:
            os.killpg(proc.pid, signal.SIGKILL)      # Ray helpers the server left behind
        except ProcessLookupError:
            pass
        log.close()


if __name__ == "__main__":
    sys.exit(main())
