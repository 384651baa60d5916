"""The FastAPI application of the TMOC service: ``create_app(settings)`` assembles it.

Routes only read the SQLite store (fast, on the event loop) or hand blocking work to a
thread: tasks run on the :class:`~api.task_worker.TaskWorker` thread, session steps
(planning and particle simulations through the shared shard pools) run in the thread pool,
serialised per session. Nothing on the event loop waits for Ray or physics.

Where things are: routes in ``api.routes`` (one router per resource), what they depend on
in ``api.deps`` (read from ``app.state``), error shaping in ``api.errors``, middlewares in
``api.middleware``, views in ``api.views``.
"""
from __future__ import annotations

import asyncio
import logging
import signal
import threading
from contextlib import asynccontextmanager

from fastapi import APIRouter, Depends, FastAPI
from starlette.concurrency import run_in_threadpool

from coordinator.distributed.shard_pools import ShardPools

from . import schemas as S
from .auth import CookieSessions, LoginThrottle
from .deps import require_token
from .errors import add_exception_handlers, error_responses
from .exports import Exports
from .middleware import add_middlewares
from .notify import Notifier
from .routes import domains, frames, robots, service, sessions, tasks, ui
from .sessions import SessionManager
from .settings import Settings
from .store import Store
from .task_worker import TaskWorker

log = logging.getLogger("tmoc.api")

DESCRIPTION = ("Submit TMOC tasks, watch them learn (Server-Sent Events, belief, learning curve) "
               "and drive an external robot step by step. With TMOC_API_TOKEN set, every route "
               "but /health needs `Authorization: Bearer <token>`.")


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("tmoc-service")
    except Exception:  # pragma: no cover - not installed
        return "0+unknown"


def _signal_restorer():
    """Ray's core worker installs a C-level handler for SIGTERM/SIGINT when it starts (it
    dumps a stack and aborts): give the signals back to the server (graceful shutdown:
    running tasks stop at a boundary and resume after a restart) once Ray is up."""
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    def restore() -> None:
        for sig, handler in handlers.items():
            if callable(handler) or handler in (signal.SIG_DFL, signal.SIG_IGN):
                try:
                    signal.signal(sig, handler)
                except ValueError:   # not the main thread (an embedded server): leave them
                    pass

    return restore


PRUNE_EVERY_S = 3600.0       # how often `--retain-days` looks for runs past their time


def _prune_forever(store: Store, exports: Exports, retain_days: float, stopping: threading.Event) -> None:
    """`tmoc serve --retain-days`: at start-up and then hourly, purge the finished tasks
    and closed or finished sessions last changed more than `retain_days` ago (issue 38),
    their finished exports with them."""
    while not stopping.is_set():
        try:
            pruned = store.prune(retain_days * 86400.0)
            for run_id in pruned["tasks"] + pruned["sessions"]:
                exports.forget(run_id)
            if any(pruned.values()):
                log.info("retention: purged %d tasks and %d sessions older than %g days",
                         len(pruned["tasks"]), len(pruned["sessions"]), retain_days)
        except Exception:  # noqa: BLE001 - storage trouble: try again at the next round
            log.exception("retention: pruning failed")
        stopping.wait(PRUNE_EVERY_S)


@asynccontextmanager
async def lifespan(app: FastAPI):
    """Open the store, start the task worker; at the end stop it, close the pools and Ray."""
    st = app.state
    st.store = Store(st.settings.db)
    st.worker = TaskWorker(st.store, st.shard_pools, st.notifier, max_frames=st.settings.max_frames,
                           max_runtime_s=st.settings.max_task_runtime_s)
    stop_restore = threading.Event()
    st.sessions = SessionManager(st.store, st.shard_pools, st.settings.max_sessions,
                                 st.settings.session_idle_s, stopping=stop_restore)
    loop = asyncio.get_running_loop()
    st.notifier.bind(loop)
    st.shutting_down = asyncio.Event()
    # Called from uvicorn's signal handling before it waits for open connections: event
    # streams end at once instead of holding a graceful stop for seconds.
    st.begin_shutdown = lambda: loop.call_soon_threadsafe(st.shutting_down.set)
    restore_signals = _signal_restorer()
    st.shard_pools.on_ray_ready = lambda: loop.call_soon_threadsafe(restore_signals)
    st.worker.start()
    threading.Thread(target=st.sessions.restore, args=(stop_restore,), name="tmoc-session-restore",
                     daemon=True).start()
    if st.settings.session_idle_s != float("inf"):
        threading.Thread(target=st.sessions.evict_forever, args=(stop_restore,), name="tmoc-idle-eviction",
                         daemon=True).start()
    if st.settings.retain_days is not None:
        threading.Thread(target=_prune_forever, args=(st.store, st.exports, st.settings.retain_days, stop_restore),
                         name="tmoc-retention", daemon=True).start()
    try:
        yield
    finally:
        stop_restore.set()
        st.shutting_down.set()
        await run_in_threadpool(st.worker.stop, st.settings.shutdown_grace_s)
        await run_in_threadpool(st.shard_pools.close)
        st.store.close()


def create_app(settings: Settings | None = None) -> FastAPI:
    """The service's app: state, middlewares, exception handlers and routers."""
    settings = settings or Settings()
    app = FastAPI(title="TMOC service", version=_version(), description=DESCRIPTION,
                  lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    app.state.settings = settings
    app.state.notifier = Notifier()
    app.state.shard_pools = ShardPools(settings.ray_address, settings.n_shards)
    app.state.cookie_sessions = CookieSessions()
    app.state.login_throttle = LoginThrottle(per_address=settings.max_auth_failures,
                                             in_all=10 * settings.max_auth_failures)
    app.state.exports = Exports.beside(settings.db)
    add_middlewares(app, settings, app.state.cookie_sessions)
    if settings.allowed_hosts is not None:
        from starlette.middleware.trustedhost import TrustedHostMiddleware

        # Outermost: a foreign Host costs nothing beyond its headers.
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=list(settings.allowed_hosts))
    add_exception_handlers(app)

    gate = [Depends(require_token)] if settings.token else []
    app.include_router(service.health_router)
    app.include_router(service.docs_router, dependencies=gate)
    app.include_router(ui.router)
    v1 = APIRouter(prefix="/v1", dependencies=gate, responses=error_responses(401))
    limits = (settings.max_particles, settings.max_episodes, settings.max_steps)
    rows = settings.max_counterfactual_rows
    v1.include_router(tasks.router(S.task_spec_model(*limits, settings.max_task_runtime_s, rows)))
    v1.include_router(frames.router)
    v1.include_router(domains.router)
    v1.include_router(robots.router)
    v1.include_router(sessions.router(S.session_create_model(*limits, rows)))
    app.include_router(v1)
    return app


__all__ = ["Settings", "create_app", "lifespan"]
