"""The service itself: GET /health (open), and the API's docs (/openapi.json, /docs; gated
like /v1 when the server has a token)."""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
import sqlite3

from fastapi import APIRouter, Request, Response
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import JSONResponse

from .. import schemas as S
from ..auth import bearer_ok
from ..deps import SettingsDep, ShardPoolsDep, StoreDep, TaskWorkerDep

health_router = APIRouter()


@health_router.get("/health", response_model=S.Health, tags=["service"],
                   responses={503: {"model": S.Health, "description": "the task worker is dead, "
                                                                      "stalled or retrying"}})
async def health(request: Request, response: Response, settings: SettingsDep, store: StoreDep,
                 worker: TaskWorkerDep, shard_pools: ShardPoolsDep):
    """Liveness, the task worker's state and a glimpse of the queue; never needs a
    token (the running task's id is shown only with one). 503 when not ok."""
    state = worker.health()
    try:
        queued = store.count_tasks("queued")
    except sqlite3.Error as exc:
        queued, state = -1, {**state, "ok": False, "last_error": f"store: {exc}"}
    authorised = not settings.token or bearer_ok(
        request.headers.get("authorization", "").encode(), settings.token.encode())
    if not state["ok"]:
        response.status_code = 503
    return {"status": "ok" if state["ok"] else "degraded", "version": request.app.version,
            "ray": shard_pools.ray_status, "queued": queued,
            "running": worker.current if authorised else None,
            "auth": bool(settings.token), "worker": state}


docs_router = APIRouter(include_in_schema=False)


@docs_router.get("/openapi.json")
async def openapi_json(request: Request):
    return JSONResponse(request.app.openapi())


@docs_router.get("/docs")
async def swagger():
    return get_swagger_ui_html(openapi_url="/openapi.json", title="TMOC service")


__all__ = ["docs_router", "health_router"]
