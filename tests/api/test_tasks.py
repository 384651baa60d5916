"""Tasks over HTTP against a real uvicorn server with its own two-CPU Ray (issue 5)."""
from __future__ import annotations

import asyncio
import math

import httpx
import pytest

from .conftest import stream_events, wait_for

# Slow: real tasks on a served Ray. Timeout: the accepted tasks' wait (240 s) after the shared server's start (90 s).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(360)]

TINY = {"agent": "tmoc", "particles": 3, "episodes": 2, "max_steps": 3, "seed": 1}


def test_submit_stream_and_complete_a_task(server, client):
    r = client.post("/v1/tasks", json=TINY)
    assert r.status_code == 202, r.text
    task = r.json()
    assert r.headers["location"] == f"/v1/tasks/{task['id']}" == task["location"]
    assert task["status"] == "queued"

    events = stream_events(client, task["id"])
    episodes = [e for e in events if e["event"] == "episode"]
    assert [e["id"] for e in episodes] == ["0", "1"]
    assert [e["data"]["episode"] for e in episodes] == [0, 1]
    assert all({"utility", "actions", "posterior", "loads"} <= set(e["data"]) for e in episodes)
    final = events[-1]
    assert final["event"] == "status" and final["data"]["status"] == "succeeded", events[-1]

    view = client.get(f"/v1/tasks/{task['id']}").json()
    assert view["status"] == "succeeded"
    assert view["progress"] == {"episodes_done": 2, "episodes": 2}
    assert view["latest"]["episode"] == 1
    assert view["latest"]["utility"] == episodes[1]["data"]["utility"]
    assert view["result"]["summary"]["final_size_mean"] == episodes[1]["data"]["posterior"]["size_mean"]
    assert view["spec"]["particles"] == 3 and view["spec"]["reality"] == "simulated"

    # Resuming the stream after episode 0 replays only what came after it.
    again = stream_events(client, task["id"], last_event_id="0")
    assert [e.get("id") for e in again if e["event"] == "episode"] == ["1"]
    assert again[-1]["data"]["status"] == "succeeded"

    belief = client.get(f"/v1/tasks/{task['id']}/belief").json()
    assert belief["learns_belief"] and belief["episodes_done"] == 2
    hist = belief["belief"]["histogram"][0]
    assert len(hist["edges"]) == len(hist["weights"]) + 1
    assert math.isclose(sum(hist["weights"]), 1.0, rel_tol=1e-9)
    assert belief["posterior"]["size_mean"] == view["latest"]["posterior"]["size_mean"]

    curve = client.get(f"/v1/tasks/{task['id']}/curve").json()
    assert [p["episode"] for p in curve["points"]] == [0, 1]
    assert curve["points"][1]["utility"] == episodes[1]["data"]["utility"]
    png = client.get(f"/v1/tasks/{task['id']}/curve.png")
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    assert png.content.startswith(b"\x89PNG\r\n\x1a\n")

    stored = client.get(f"/v1/tasks/{task['id']}/episodes").json()
    assert [e["episode"] for e in stored] == [0, 1]
    listing = client.get("/v1/tasks", params={"limit": 200}).json()
    assert task["id"] in [t["id"] for t in listing["items"]]
    assert client.get("/v1/tasks/t_doesnotexist").status_code == 404
    assert client.get("/v1/tasks/t_doesnotexist/events").status_code == 404


def test_cancel_a_queued_and_a_running_task(client):
    running = client.post("/v1/tasks", json={**TINY, "episodes": 6, "max_steps": 4, "particles": 2}).json()
    queued = client.post("/v1/tasks", json=TINY).json()

    # A queued task is cancelled at once and never runs.
    r = client.delete(f"/v1/tasks/{queued['id']}")
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "cancelled"
    view = client.get(f"/v1/tasks/{queued['id']}").json()
    assert view["status"] == "cancelled" and view["attempts"] == 0 and view["started_at"] is None

    # A running one stops at its next episode boundary.
    with client.stream("GET", f"/v1/tasks/{running['id']}/events") as s:
        for line in s.iter_lines():
            if line.startswith("id:"):
                break                                       # its first episode is stored
    r = client.delete(f"/v1/tasks/{running['id']}")
    assert r.status_code == 202, r.text
    assert r.json()["cancel_requested"] is True and "boundary" in r.json()["detail"]
    events = stream_events(client, running["id"])
    assert events[-1]["event"] == "status" and events[-1]["data"]["status"] == "cancelled"
    view = client.get(f"/v1/tasks/{running['id']}").json()
    done = view["progress"]["episodes_done"]
    assert 1 <= done < 6
    stored = client.get(f"/v1/tasks/{running['id']}/episodes").json()
    assert [e["episode"] for e in stored] == list(range(done))

    r = client.delete(f"/v1/tasks/{running['id']}")         # finished: a conflict (issue 12)
    assert r.status_code == 409 and "already cancelled" in r.json()["detail"], r.text
    assert client.delete("/v1/tasks/t_nope").status_code == 404


def test_a_finished_task_cannot_be_cancelled(client):
    task = client.post("/v1/tasks", json={"agent": "tmp_rl", "episodes": 1, "max_steps": 1,
                                          "n_blocks": 2}).json()
    stream_events(client, task["id"])
    r = client.delete(f"/v1/tasks/{task['id']}")
    assert r.status_code == 409 and "succeeded" in r.json()["detail"]


def test_fifty_concurrent_submissions_queue_or_are_refused_at_the_limit(server, client):
    spec = {"agent": "tmp_rl", "episodes": 1, "max_steps": 1, "n_blocks": 2, "seed": 3}

    async def submit_all():
        async with httpx.AsyncClient(base_url=server.base, headers=server.headers, timeout=60,
                                     limits=httpx.Limits(max_connections=50)) as c:
            return await asyncio.gather(*(c.post("/v1/tasks", json={**spec, "seed": i})
                                          for i in range(50)))

    responses = asyncio.run(submit_all())
    codes = [r.status_code for r in responses]
    assert set(codes) <= {202, 429}, codes
    accepted = [r.json()["id"] for r in responses if r.status_code == 202]
    refused = [r for r in responses if r.status_code == 429]
    assert len(accepted) >= 8 and refused, codes          # --max-queued 8
    assert all("max_queued" in r.json()["detail"] and "8" in r.json()["detail"] for r in refused)

    def all_done():
        views = [client.get(f"/v1/tasks/{i}").json() for i in accepted]
        return views if all(v["status"] == "succeeded" for v in views) else None

    views = wait_for(all_done, timeout=240, every=0.5, what="the accepted tasks to succeed")
    # One at a time, in the order queued (the listing is newest first).
    listing = client.get("/v1/tasks", params={"limit": 200}).json()["items"]
    order = [t["id"] for t in reversed(listing) if t["id"] in set(accepted)]
    starts = {v["id"]: v["started_at"] for v in views}
    ends = {v["id"]: v["finished_at"] for v in views}
    assert [starts[i] for i in order] == sorted(starts.values())
    assert all(ends[a] <= starts[b] for a, b in zip(order, order[1:]))
    assert all(v["progress"]["episodes_done"] == 1 for v in views)
