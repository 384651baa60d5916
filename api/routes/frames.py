"""Scene pictures and T per context of a task over HTTP (issue 16):
``GET /v1/tasks/{id}/frames``, ``/frames/{name}.png`` and ``/transition``.

The task worker's runs write frames into the store (api.frames.StoreFrameSink); these routes
read SQLite only (in the thread pool for the PNG blobs) and never render.
"""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
from typing import Annotated

from fastapi import APIRouter, HTTPException, Path
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from .. import schemas as S
from ..deps import SettingsDep, StoreDep, TaskId, task_or_404
from ..errors import error_responses

FRAME_NAME = r"^e[0-9]{3,6}-(end|s[0-9]{3,6})$"
FrameName = Annotated[str, Path(pattern=FRAME_NAME, max_length=16,
                                description="a frame's name, as listed (e.g. e000-end, e001-s004)")]

router = APIRouter()


def _prior_table(spec: dict) -> list[dict]:
    """T before the first episode (the optimistic prior: p 1, no counts)."""
    from coordinator.loop.session import Session

    return Session(S.run_config(spec)).transition_table()


@router.get("/tasks/{task_id}/frames", response_model=S.FrameList, tags=["tasks"],
            responses=error_responses(404))
async def task_frames(task_id: TaskId, store: StoreDep, settings: SettingsDep):
    """Scene pictures of the task, oldest first: the real world at the end of every
    episode and, for every failed action, what happened beside what the heaviest
    particle, one that matched and one that did not predicted."""
    task_or_404(store, task_id)
    items = [{**m, "url": f"/v1/tasks/{task_id}/frames/{m['name']}.png"}
             for m in store.frames(task_id)]
    for m in items:
        m["created_at"] = S.ts(m["created_at"])
    return {"run_id": task_id, "items": items, "total": len(items), "max_frames": settings.max_frames}


@router.get("/tasks/{task_id}/frames/{name}.png", tags=["tasks"], response_class=Response,
            responses={200: {"content": {"image/png": {"schema": {"type": "string", "format": "binary"}}},
                             "description": "the frame (PNG)"}, **error_responses(404)})
async def task_frame_png(task_id: TaskId, name: FrameName, store: StoreDep):
    """One scene picture as a PNG (320x240 per panel)."""
    task_or_404(store, task_id)
    png = await run_in_threadpool(store.frame_png, task_id, name)
    if png is None:
        raise HTTPException(404, f"task {task_id!r}: no frame {name!r}")
    return Response(png, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})


@router.get("/tasks/{task_id}/transition", response_model=S.TransitionView, tags=["tasks"],
            responses=error_responses(404))
async def task_transition(task_id: TaskId, store: StoreDep):
    """T per context at the last episode boundary: the success probability and the
    weighted counts (all, and the real world's) it is estimated from."""
    row = await run_in_threadpool(task_or_404, store, task_id, transition=True)
    rows = row.get("transition")
    if rows is None:
        rows = await run_in_threadpool(_prior_table, row["spec"])
    return {"run_id": task_id, "episodes_done": row["episodes_done"], "rows": rows}


__all__ = ["FRAME_NAME", "router"]
