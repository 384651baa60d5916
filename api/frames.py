"""Scene pictures and T per context of a task over HTTP (issue 16):
``GET /v1/tasks/{id}/frames``, ``/frames/{name}.png`` and ``/transition``.

The task worker's runs write frames through :class:`StoreFrameSink` into the store (at most
``--max-frames`` per task, the oldest deleted first); routes read SQLite only (in the
thread pool for the PNG blobs) and never render.
"""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
from typing import Annotated, Callable

from fastapi import APIRouter, HTTPException, Path
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool

from . import schemas as S
from .store import Store
from .worker import run_config

FRAME_NAME = r"^e[0-9]{3,6}-(end|s[0-9]{3,6})$"


class StoreFrameSink:
    """A run's frames into the store, bounded per task."""

    def __init__(self, store: Store, task_id: str, max_frames: int) -> None:
        self.store, self.task_id, self.max_frames = store, task_id, max_frames

    def add(self, name: str, png: bytes, meta: dict) -> None:
        self.store.add_frame(self.task_id, name, png, meta, self.max_frames)


def _prior_table(spec: dict) -> list[dict]:
    """T before the first episode (the optimistic prior: p 1, no counts)."""
    from coordinator.session import Session

    return Session(run_config(spec)).transition_table()


def add_routes(v1: APIRouter, store: Callable[[], Store], task_or_404: Callable, task_id_type,
               max_frames: int, errors: Callable) -> None:
    """The frames and transition routes on the /v1 router (its auth dependencies apply)."""
    TaskId = task_id_type
    FrameName = Annotated[str, Path(pattern=FRAME_NAME, max_length=16,
                                    description="a frame's name, as listed (e.g. e000-end, e001-s004)")]

    @v1.get("/tasks/{task_id}/frames", response_model=S.FrameList, tags=["tasks"], responses=errors(404))
    async def task_frames(task_id: TaskId):
        """Scene pictures of the task, oldest first: the real world at the end of every
        episode and, for every failed action, what happened beside what the heaviest
        particle, one that matched and one that did not predicted."""
        task_or_404(task_id)
        items = [{**m, "url": f"/v1/tasks/{task_id}/frames/{m['name']}.png"}
                 for m in store().frames(task_id)]
        for m in items:
            m["created_at"] = S.ts(m["created_at"])
        return {"run_id": task_id, "items": items, "total": len(items), "max_frames": max_frames}

    @v1.get("/tasks/{task_id}/frames/{name}.png", tags=["tasks"], response_class=Response,
            responses={200: {"content": {"image/png": {"schema": {"type": "string", "format": "binary"}}},
                             "description": "the frame (PNG)"}, **errors(404)})
    async def task_frame_png(task_id: TaskId, name: FrameName):
        """One scene picture as a PNG (320x240 per panel)."""
        task_or_404(task_id)
        png = await run_in_threadpool(store().frame_png, task_id, name)
        if png is None:
            raise HTTPException(404, f"task {task_id!r}: no frame {name!r}")
        return Response(png, media_type="image/png", headers={"Cache-Control": "private, max-age=3600"})

    @v1.get("/tasks/{task_id}/transition", response_model=S.TransitionView, tags=["tasks"],
            responses=errors(404))
    async def task_transition(task_id: TaskId):
        """T per context at the last episode boundary: the success probability and the
        weighted counts (all, and the real world's) it is estimated from."""
        row = await run_in_threadpool(task_or_404, task_id, transition=True)
        rows = row.get("transition")
        if rows is None:
            rows = await run_in_threadpool(_prior_table, row["spec"])
        return {"run_id": task_id, "episodes_done": row["episodes_done"], "rows": rows}


__all__ = ["StoreFrameSink", "add_routes", "FRAME_NAME"]
