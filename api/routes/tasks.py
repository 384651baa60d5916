"""The tasks resource: submit, list, read, cancel, and watch a task learn (episodes, Server-
Sent Events, belief, learning curve and its PNG).

Built per app (:func:`router`): POST /tasks takes this server's TaskSpec, whose limits are
part of the OpenAPI schema; the other routes are shared (``routes``).
"""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
import asyncio
import json
import weakref
from typing import Annotated, Any

from fastapi import APIRouter, Header, HTTPException, Query, Request
from fastapi.encoders import jsonable_encoder
from fastapi.responses import Response, StreamingResponse
from starlette.concurrency import run_in_threadpool

from .. import exports
from .. import schemas as S
from .. import views
from ..deps import (ExportsDep, NotifierDep, SettingsDep, ShuttingDownDep, StoreDep, TaskId, TaskWorkerDep,
                    task_or_404)
from ..errors import error_responses, refuse_invalid_config, refuse_unstorable, unprocessable
from ..store import TERMINAL, QueueFull, new_id
from ..task_worker import TaskWorker

KEEPALIVE_S = 15.0

# One Server-Sent Event (OpenAPI 3.1: the schema of a text/event-stream describes each event).
SSE_EVENT = {
    "type": "object",
    "properties": {
        "event": {"type": "string", "enum": ["episode", "status"],
                  "description": "`episode`: one per finished episode; `status`: the task's status "
                                 "changed (the last one ends the stream)"},
        "id": {"type": "string", "description": "the episode index (episode events only)"},
        "data": {"type": "string", "contentMediaType": "application/json",
                 "description": "episode: the episode record; status: the task (as GET /v1/tasks/{id})"},
        "retry": {"type": "integer"},
    },
}


def task_json(row: dict, worker: TaskWorker | None) -> dict:
    """A task as the API shows it (with the live node report while it runs)."""
    return views.task_view(row, worker.nodes_of(row["id"]) if worker is not None else None)


def router(task_spec: type) -> APIRouter:
    """The tasks routes of one app; `task_spec` is its TaskSpec model (api.schemas)."""
    r = APIRouter()

    async def submit_task(spec: task_spec, response: Response, settings: SettingsDep,
                          store: StoreDep, worker: TaskWorkerDep):
        """Queue a task (202). Limits: particles, episodes (422 naming the field) and the
        number of queued tasks (429)."""
        task_id = new_id("t")
        body = S.spec_body(spec)
        refuse_invalid_config(body)
        refuse_unstorable(body, settings.max_stored_steps)
        try:
            await run_in_threadpool(store.create_task, task_id, body, settings.max_queued)
        except QueueFull as exc:
            raise HTTPException(429, f"max_queued: {exc.queued} tasks are queued, this server's "
                                     f"limit is {exc.limit} (--max-queued); retry later",
                                headers={"Retry-After": "5"}) from None
        worker.submit(task_id)
        location = f"/v1/tasks/{task_id}"
        response.headers["Location"] = location
        return {"id": task_id, "status": "queued", "location": location,
                "links": views.task_links(task_id)}

    r.add_api_route("/tasks", submit_task, methods=["POST"], status_code=202,
                    response_model=S.TaskCreated, tags=["tasks"],
                    responses=error_responses(413, 429))
    r.include_router(routes)
    return r


routes = APIRouter()


@routes.get("/tasks", response_model=S.TaskList, tags=["tasks"])
async def list_tasks(store: StoreDep, worker: TaskWorkerDep,
                     limit: Annotated[int, Query(ge=1, le=200)] = 50,
                     offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
                     status: Annotated[S.TaskStatus | None, Query()] = None):
    """Tasks, newest first."""
    rows, total = store.list_tasks(limit, offset, status)
    items, skipped = views.shown(rows, lambda r: task_json(r, worker), S.TaskView)
    return views.page(items, total, limit, offset, skipped)


@routes.get("/tasks/{task_id}", response_model=S.TaskView, tags=["tasks"],
            responses=error_responses(404))
async def get_task(task_id: TaskId, store: StoreDep, worker: TaskWorkerDep):
    """Status, progress, the latest episode's metrics, and the result when done."""
    return task_json(task_or_404(store, task_id), worker)


@routes.delete("/tasks/{task_id}", response_model=S.CancelView, tags=["tasks"],
               responses={**error_responses(404, 409), 202: {"model": S.CancelView}})
async def cancel_task(task_id: TaskId, response: Response, store: StoreDep, worker: TaskWorkerDep):
    """Cancel: a queued task is cancelled at once (200); a running one stops at its next
    episode boundary (202, `cancel_requested`); a finished one cannot be (409)."""
    outcome = await run_in_threadpool(store.cancel_task, task_id)
    if outcome is None:
        raise HTTPException(404, f"task {task_id!r}: no such task")
    status, changed = outcome
    if not changed:
        raise HTTPException(409, f"task {task_id!r} already {status}")
    if status == "running":
        worker.cancel(task_id)
        response.status_code = 202
        detail = "cancel requested: the task stops at its next episode boundary"
    else:
        detail = "cancelled"
    return {**task_json(task_or_404(store, task_id), worker), "detail": detail}


@routes.post("/tasks/{task_id}/purge", response_model=S.PurgeView, tags=["tasks"],
             responses=error_responses(404, 409))
async def purge_task(task_id: TaskId, store: StoreDep, built: ExportsDep):
    """Delete a finished task's stored rows (the task, its episodes, step records and
    pictures); 409 while it is queued or running (cancel it first). Issue 38: nothing was
    ever reclaimed. `tmoc serve --retain-days N` does this for every run older than N days."""
    return await exports.purged(store.purge_task, built, "task", task_id, "cancel")


@routes.get("/tasks/{task_id}/episodes", tags=["tasks"], responses=error_responses(404),
            response_model=list[dict[str, Any]])
async def task_episodes(task_id: TaskId, store: StoreDep,
                        after: Annotated[int, Query(ge=-1, le=10**9)] = -1,
                        limit: Annotated[int, Query(ge=1, le=1000)] = 1000):
    """Stored episode records with index > `after`, in order."""
    task_or_404(store, task_id)
    rows = store.episodes(task_id, after, limit)
    return Response("[" + ",".join(r for _, r in rows) + "]", media_type="application/json")


@routes.get("/tasks/{task_id}/events", tags=["tasks"],
            responses={200: {"content": {"text/event-stream": {"schema": SSE_EVENT}},
                             "description": "`episode` events (id = episode index, data = the "
                                            "episode record) and `status` events; the stream "
                                            "ends after the final status"}, **error_responses(404, 429)},
            response_class=StreamingResponse)
async def task_events(request: Request, task_id: TaskId, settings: SettingsDep, store: StoreDep,
                      worker: TaskWorkerDep, notifier: NotifierDep, shutting_down: ShuttingDownDep,
                      last_event_id: Annotated[str, Header(
                          alias="Last-Event-ID", pattern=r"^\s*(-1|[0-9]{1,12})\s*$",
                          description="resume after this episode index")] = None,
                      after: Annotated[int | None, Query(ge=-1, le=10**9, description=(
                          "resume after this episode index (for clients that cannot set "
                          "Last-Event-ID)"))] = None):
    """Server-Sent Events: one `episode` event per episode, `status` events when the
    status changes, a final `status` event when the task ends. Resumable with
    Last-Event-ID."""
    start = -1 if after is None else after
    if last_event_id is not None and last_event_id.strip():
        try:
            start = int(last_event_id.strip())
            if start < -1:
                raise ValueError
        except ValueError:
            return unprocessable(settings, ["header", "Last-Event-ID"],
                                 "expected an episode index (integer >= -1)", "int_parsing")
    if store.task_status(task_id) is None:
        raise HTTPException(404, f"task {task_id!r}: no such task")
    # Each open stream holds a descriptor: capped per task and in all (issue 25: 1500
    # streams on one task were all accepted). Counted when subscribed, here on the loop,
    # so a burst cannot pass the check together.
    if (notifier.count(task_id) >= settings.max_streams_per_task
            or notifier.count() >= settings.max_streams):
        raise HTTPException(429, f"too many open event streams (at most {settings.max_streams_per_task} "
                                 f"per task, {settings.max_streams} in all): close one and retry",
                            headers={"Retry-After": "5"})
    ev = notifier.subscribe(task_id)

    async def stream():
        try:
            yield "retry: 2000\n\n"
            last, last_status = start, None
            while True:
                status, _ = store.task_status(task_id)
                for episode, record in store.episodes(task_id, last):
                    yield f"id: {episode}\nevent: episode\ndata: {record}\n\n"
                    last = episode
                if status != last_status:
                    view = json.dumps(jsonable_encoder(task_json(store.get_task(task_id), worker)),
                                      separators=(",", ":"))
                    yield f"event: status\ndata: {view}\n\n"
                    last_status = status
                if status in TERMINAL:
                    return
                woke = await _wait_any(ev, shutting_down, KEEPALIVE_S)
                if woke == "shutdown":
                    return                 # the client reconnects with Last-Event-ID
                if woke == "timeout":
                    yield ": keep-alive\n\n"
                ev.clear()
        finally:
            notifier.unsubscribe(task_id, ev)

    body = stream()
    # A stream that never starts (the client left first) never runs its finally.
    weakref.finalize(body, notifier.unsubscribe, task_id, ev)
    return StreamingResponse(body, media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


async def _wait_any(event: asyncio.Event, shutdown: asyncio.Event, timeout: float) -> str:
    """'event', 'shutdown' or 'timeout', whichever comes first."""
    if shutdown.is_set():
        return "shutdown"
    waits = {asyncio.ensure_future(event.wait()): "event",
             asyncio.ensure_future(shutdown.wait()): "shutdown"}
    try:
        done, _ = await asyncio.wait(waits, timeout=timeout, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for w in waits:
            w.cancel()
    if not done:
        return "timeout"
    return "shutdown" if shutdown.is_set() else "event"


@routes.get("/tasks/{task_id}/belief", response_model=S.BeliefView, tags=["tasks"],
            responses=error_responses(404))
async def task_belief(task_id: TaskId, store: StoreDep):
    """The posterior over the block size at the last episode boundary (the prior before
    the first): mean, std, effective sample size and a weighted histogram."""
    row = task_or_404(store, task_id, belief=True)
    spec, belief, latest = row["spec"], row.get("belief"), row.get("latest")
    if latest is not None:
        posterior = latest["posterior"]
    else:
        prior, posterior = await run_in_threadpool(views.prior, spec)
        belief = belief or prior
    return views.belief_view(task_id, spec, belief, posterior, row["episodes_done"],
                             spec.get("true_size"))


@routes.get("/tasks/{task_id}/curve", response_model=S.CurveView, tags=["tasks"],
            responses=error_responses(404))
async def task_curve(task_id: TaskId, store: StoreDep):
    """The learning curve: utility and posterior size (mean, std) per episode."""
    row = task_or_404(store, task_id)
    records = [json.loads(r) for _, r in store.episodes(task_id)]
    return {"run_id": task_id, "agent": row["spec"]["agent"],
            "true_size": row["spec"].get("true_size"), "points": views.curve_points(records)}


@routes.get("/tasks/{task_id}/export", tags=["tasks"], response_class=Response,
            responses={**exports.RESPONSES, **error_responses(404, 429)})
async def export_task(task_id: TaskId, store: StoreDep, built: ExportsDep):
    """Every step of the task's finished episodes as MCAP (``tmoc export``), streamed as it
    is written; 429 while too many exports are being built (``api.exports``)."""
    row = task_or_404(store, task_id)
    return await exports.serve(built, store, task_id, "task", row["spec"])


@routes.get("/tasks/{task_id}/curve.png", tags=["tasks"], response_class=Response,
            responses={200: {"content": {"image/png": {"schema": {"type": "string", "format": "binary"}}},
                             "description": "the learning curve as a PNG"}, **error_responses(404)})
async def task_curve_png(task_id: TaskId, store: StoreDep):
    """The learning curve as a PNG (`tmoc run`'s curve.png of the episodes so far)."""
    row = task_or_404(store, task_id)
    records = [json.loads(r) for _, r in store.episodes(task_id)]
    png = await run_in_threadpool(views.render_png, row["spec"], records)
    return Response(png, media_type="image/png")


__all__ = ["KEEPALIVE_S", "SSE_EVENT", "router", "routes"]
