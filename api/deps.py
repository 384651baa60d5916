"""What routes depend on, read from ``request.app.state`` (set by ``create_app`` and its
lifespan): ``Annotated`` aliases to put in a route's signature, the 404 lookups, and the
bearer-token check of gated routes.
"""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
import asyncio
import hmac
from typing import Annotated

from fastapi import Depends, HTTPException, Path, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from coordinator.distributed.shard_pools import ShardPools

from .auth import CookieSessions, authorised
from .exports import Exports
from .notify import Notifier
from .sessions import SessionManager
from .settings import Settings
from .store import Store
from .task_worker import TaskWorker

TaskId = Annotated[str, Path(min_length=1, max_length=64, description="task id (t_...)")]
SessionId = Annotated[str, Path(min_length=1, max_length=64, description="session id (s_...)")]


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


def get_store(request: Request) -> Store:
    return request.app.state.store


def get_task_worker(request: Request) -> TaskWorker | None:
    """The task worker (None before the app's lifespan started it)."""
    return getattr(request.app.state, "worker", None)


def get_sessions(request: Request) -> SessionManager:
    return request.app.state.sessions


def get_notifier(request: Request) -> Notifier:
    return request.app.state.notifier


def get_exports(request: Request) -> Exports:
    return request.app.state.exports


def get_shard_pools(request: Request) -> ShardPools:
    return request.app.state.shard_pools


def get_cookie_sessions(request: Request) -> CookieSessions:
    """Browsers signed in at /ui (api.auth)."""
    return request.app.state.cookie_sessions


def get_shutting_down(request: Request) -> asyncio.Event:
    """Set when the server begins to stop: event streams end at once."""
    return request.app.state.shutting_down


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
TaskWorkerDep = Annotated[TaskWorker | None, Depends(get_task_worker)]
SessionsDep = Annotated[SessionManager, Depends(get_sessions)]
NotifierDep = Annotated[Notifier, Depends(get_notifier)]
ExportsDep = Annotated[Exports, Depends(get_exports)]
ShardPoolsDep = Annotated[ShardPools, Depends(get_shard_pools)]
ShuttingDownDep = Annotated[asyncio.Event, Depends(get_shutting_down)]
CookieSessionsDep = Annotated[CookieSessions, Depends(get_cookie_sessions)]


def task_or_404(store: Store, task_id: str, **kw) -> dict:
    row = store.get_task(task_id, **kw)
    if row is None:
        raise HTTPException(404, f"task {task_id!r}: no such task")
    return row


def session_or_404(store: Store, session_id: str, **kw) -> dict:
    row = store.get_session(session_id, **kw)
    if row is None:
        raise HTTPException(404, f"session {session_id!r}: no such session")
    return row


_bearer = HTTPBearer(auto_error=False, description="the server's TMOC_API_TOKEN")


async def require_token(request: Request,
                        creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]):
    """The gate of /v1 and the docs when the server has a token (see create_app)."""
    # `creds` declares the bearer scheme in the OpenAPI schema; a browser signed in at
    # /ui sends the session cookie instead (api.auth).
    expected = request.app.state.settings.token.encode()
    if creds is not None and hmac.compare_digest(creds.credentials.encode(), expected):
        return
    if not authorised(dict(request.scope.get("headers", ())), expected, request.app.state.cookie_sessions):
        raise HTTPException(401, "missing or invalid token: send Authorization: Bearer <token>",
                            headers={"WWW-Authenticate": "Bearer"})


__all__ = ["CookieSessionsDep", "ExportsDep", "NotifierDep", "SessionId", "SessionsDep", "SettingsDep",
           "ShardPoolsDep", "ShuttingDownDep", "StoreDep", "TaskId", "TaskWorkerDep",
           "get_cookie_sessions", "get_notifier", "get_sessions", "get_settings", "get_shard_pools",
           "get_shutting_down", "get_store", "get_task_worker", "require_token", "session_or_404",
           "task_or_404"]
