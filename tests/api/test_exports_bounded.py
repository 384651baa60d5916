"""Exports that stream and are bounded (issue 38, findings 1-3), on a real `tmoc serve`: a
task of 20000 stored steps starts sending at once, its finished export is kept so that a
retry does not rebuild it, concurrent exports of one task follow one build, more distinct
builds than allowed get 429 with Retry-After, `/health` stays fast throughout, and a client
that stops reading is dropped after the send timeout."""
from __future__ import annotations

import asyncio
import io
import json
import sqlite3
import threading
import time

import httpx
import pytest

from api.exports import BoundedStream
from api.store import _INSERT_STEP, Store, _step_row

from .conftest import Server

STEPS = 20_000
TRAJ = {"columns": ["t", "x", "y", "z", "yaw", "opening"], "points": [[0.1 * k, 0.0, 0.0, 0.2, 0.0, 0.08] for k in range(8)]}


def _stored_task(store: Store, task_id: str, steps: int) -> None:
    """A finished task whose steps are stored as the task worker stores them."""
    store.create_task(task_id, {"episodes": 1, "domain": "container"})
    rows = [_step_row(task_id, {"episode": k // 50, "step": k % 50, "action": "pickup(r,b1,init)",
                                "time": float(k), "trajectory": TRAJ, "measurements": [0.045] * 17,
                                "belief": {"size": {"mean": 0.045, "std": 0.001}}}) for k in range(steps)]
    with sqlite3.connect(store.path) as raw:
        raw.executemany(_INSERT_STEP, rows)
        raw.execute("UPDATE tasks SET status = 'succeeded' WHERE id = ?", (task_id,))


@pytest.fixture(scope="module")
def export_server(tmp_path_factory):
    db = tmp_path_factory.mktemp("exports") / "exports.sqlite"
    store = Store(str(db))
    try:
        for tid in ("t_big", "t_other", "t_third"):
            _stored_task(store, tid, STEPS)
    finally:
        store.close()
    srv = Server(db).start()
    yield srv
    srv.stop()


@pytest.mark.timeout(300)
@pytest.mark.slow
def test_an_export_starts_at_once_and_is_kept(export_server):
    srv = export_server
    t0 = time.perf_counter()
    with httpx.stream("GET", f"{srv.base}/v1/tasks/t_big/export", headers=srv.headers, timeout=120) as r:
        assert r.status_code == 200
        chunks = r.iter_bytes()
        first = next(chunks)
        first_s = time.perf_counter() - t0
        body = first + b"".join(chunks)
    whole_s = time.perf_counter() - t0
    assert body[:8] == b"\x89MCAP0\r\n" and body[-8:] == b"\x89MCAP0\r\n"
    assert first_s < 0.5 * whole_s, (first_s, whole_s)        # sent while it was built
    from mcap.reader import make_reader

    steps = sum(1 for _, ch, _ in make_reader(io.BytesIO(body)).iter_messages(topics=["/tmoc/step"]))
    assert steps == STEPS
    # Kept: the retry streams the finished file, the same bytes, without a build.
    t1 = time.perf_counter()
    again = httpx.get(f"{srv.base}/v1/tasks/t_big/export", headers=srv.headers, timeout=120)
    assert again.content == body and time.perf_counter() - t1 < whole_s
    kept = list((srv.db.parent / f"{srv.db.name}.exports").glob("t_big-*.mcap"))
    assert [p.name for p in kept] == [f"t_big-{STEPS}-0.mcap"]


@pytest.mark.timeout(300)
@pytest.mark.slow
def test_many_exports_do_not_stall_the_service(export_server):
    srv = export_server
    health: list[float] = []
    codes: list[int] = []
    stop = threading.Event()

    def probe() -> None:
        with httpx.Client(base_url=srv.base, timeout=30) as c:
            while not stop.is_set():
                t = time.perf_counter()
                c.get("/health")
                health.append(time.perf_counter() - t)
                time.sleep(0.05)

    def export(tid: str) -> None:
        with httpx.stream("GET", f"{srv.base}/v1/tasks/{tid}/export", headers=srv.headers, timeout=120) as r:
            codes.append(r.status_code)
            if r.status_code == 429:
                assert int(r.headers["retry-after"]) > 0
            for _ in r.iter_bytes():
                pass

    prober = threading.Thread(target=probe)
    prober.start()
    # 20 of one task (one build, followed by all), then two more distinct ones at once:
    # at most two builds run, the third waits for a 429.
    threads = [threading.Thread(target=export, args=("t_other",)) for _ in range(20)]
    threads += [threading.Thread(target=export, args=(tid,)) for tid in ("t_third", "t_fourth_missing")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stop.set()
    prober.join()
    assert codes.count(200) >= 21 and set(codes) <= {200, 404, 429}, codes
    health.sort()
    assert health[int(0.99 * (len(health) - 1))] < 0.5, health[-5:]


def test_a_client_that_stops_reading_is_dropped():
    """The response's every send must be taken within its timeout: a stalled one raises
    (the server then closes the connection) instead of holding the file and memory."""
    async def body():
        for _ in range(4):
            yield b"x" * 65536

    response = BoundedStream(body(), media_type="application/octet-stream")
    response.send_timeout_s = 0.2
    sent: list[dict] = []

    async def send(message: dict) -> None:
        sent.append(message)
        if message["type"] == "http.response.body":
            await asyncio.sleep(3600)                    # the client reads nothing

    t0 = time.perf_counter()
    with pytest.raises(asyncio.TimeoutError):
        asyncio.run(response.stream_response(send))
    assert time.perf_counter() - t0 < 2.0 and len(sent) == 2
    assert json.dumps(sent[0]["status"]) == "200"


def test_followers_of_a_build_that_just_finished_get_the_file(tmp_path):
    """The soak found it: an export of a few steps finishes between a follower finding its
    build and opening the file being written (renamed by then): a 500. The follower now
    reads the finished file."""
    from concurrent.futures import ThreadPoolExecutor

    from api.exports import Exports, ExportBusy

    store = Store(str(tmp_path / "tiny.sqlite"))
    try:
        _stored_task(store, "t_tiny", 3)
        exports = Exports(tmp_path / "exports", max_builds=64)

        def read() -> bytes | str:
            try:
                source = exports.open(store, "t_tiny", "task", {"domain": "container"})
            except ExportBusy:
                return "busy"
            with source.file as f:
                if source.build is not None:
                    source.build.done.wait(30)
                return f.read()

        with ThreadPoolExecutor(16) as pool:
            got = list(pool.map(lambda _: read(), range(200)))
        whole = [g for g in got if isinstance(g, bytes)]
        assert len(whole) == 200 and len(set(whole)) == 1 and whole[0][-8:] == b"\x89MCAP0\r\n"
    finally:
        store.close()
