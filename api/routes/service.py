"""The service itself: GET /health (open), and the API's docs (/openapi.json, /docs; gated
like /v1 when the server has a token)."""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
import functools
import sqlite3
from pathlib import Path

from fastapi import APIRouter, HTTPException, Request, Response
from fastapi.responses import JSONResponse

from .. import schemas as S
from ..auth import authorised
from ..deps import SettingsDep, ShardPoolsDep, StoreDep, TaskWorkerDep

health_router = APIRouter()


@health_router.get("/health", response_model=S.Health, tags=["service"],
                   responses={503: {"model": S.Health, "description": "the task worker is dead, "
                                                                      "stalled or retrying"}})
async def health(request: Request, response: Response, settings: SettingsDep, store: StoreDep,
                 worker: TaskWorkerDep, shard_pools: ShardPoolsDep):
    """Liveness, the task worker's state and a glimpse of the queue; never needs a
    token (the running task's id is shown only with one, or to a browser signed in at
    /ui). 503 when not ok."""
    state = worker.health()
    try:
        queued = store.count_tasks("queued")
    except sqlite3.Error as exc:
        queued, state = -1, {**state, "ok": False, "last_error": f"store: {exc}"}
    # a bearer or a browser signed in at /ui (issue 25: the dashboard saw no running task)
    signed_in = not settings.token or authorised(
        dict(request.scope.get("headers", ())), settings.token.encode(), request.app.state.cookie_sessions)
    if not state["ok"]:
        response.status_code = 503
    return {"status": "ok" if state["ok"] else "degraded", "version": request.app.version,
            "ray": shard_pools.ray_status, "queued": queued,
            "running": worker.current if signed_in else None,
            "auth": bool(settings.token), "worker": state}


docs_router = APIRouter(include_in_schema=False)


@docs_router.get("/openapi.json")
async def openapi_json(request: Request):
    return JSONResponse(request.app.openapi())


# Swagger UI from the installed `fastapi-offline` (a pinned release), never a CDN: the
# page runs with the session cookie's rights, so only our own scripts may run there
# (issue 25: a floating CDN version, no SRI, no CSP).
DOCS_CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; "
            "script-src 'self'; connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; "
            "form-action 'none'")
DOCS_PAGE = b"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>TMOC service: API</title>
<link rel="stylesheet" href="/docs/swagger-ui.css"></head>
<body><div id="swagger-ui"></div>
<script src="/docs/swagger-ui-bundle.js"></script><script src="/docs/init.js"></script>
</body></html>"""
DOCS_INIT = (b'window.ui = SwaggerUIBundle({url: "/openapi.json", dom_id: "#swagger-ui", '
             b'presets: [SwaggerUIBundle.presets.apis], layout: "BaseLayout", deepLinking: true});')


@functools.cache                  # read once (1.2 MB), on first use
def _swagger_assets() -> dict[str, tuple[bytes, str]]:
    from importlib import resources

    # fastapi-offline ships Swagger UI 5 (OpenAPI 3.1, what FastAPI writes); only its
    # static files are used.
    root = Path(str(resources.files("fastapi_offline") / "static"))
    return {"swagger-ui-bundle.js": ((root / "swagger-ui-bundle.js").read_bytes(), "text/javascript; charset=utf-8"),
            "swagger-ui.css": ((root / "swagger-ui.css").read_bytes(), "text/css; charset=utf-8"),
            "init.js": (DOCS_INIT, "text/javascript; charset=utf-8")}


@docs_router.get("/docs")
async def swagger():
    return Response(DOCS_PAGE, media_type="text/html; charset=utf-8",
                    headers={"Content-Security-Policy": DOCS_CSP, "X-Content-Type-Options": "nosniff"})


@docs_router.get("/docs/{name}")
async def swagger_asset(name: str):
    assets = _swagger_assets()
    if name not in assets:
        raise HTTPException(404, f"{name!r}: not a file of the docs page")
    body, ctype = assets[name]
    return Response(body, media_type=ctype, headers={"Cache-Control": "max-age=86400",
                                                     "X-Content-Type-Options": "nosniff"})


__all__ = ["docs_router", "health_router"]
