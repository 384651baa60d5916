"""The FastAPI application of the TMOC service: ``create_app(settings)``.

Routes only read the SQLite store (fast, on the event loop) or hand blocking work to a
thread: tasks run on the :class:`~api.worker.TaskWorker` thread, session steps (planning
and particle simulations through the shared shard pool) run in the thread pool, serialised
per session. Nothing on the event loop waits for Ray or physics.
"""
# No `from __future__ import annotations`: the request models are built per app (they carry
# the server's limits) and FastAPI must see the real classes in the signatures below.
import asyncio
import hmac
import io
import json
import logging
import re
import signal
import sqlite3
import threading
from contextlib import asynccontextmanager
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, Header, HTTPException, Path, Query, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import JSONResponse, Response, StreamingResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from . import dashboard
from . import frames as frame_routes
from . import schemas as S
from .auth import CookieSessions, TokenGate, authorised, bearer_ok, send_json as _send_json  # noqa: F401  (TokenGate, bearer_ok: public here too)
from .store import TERMINAL, QueueFull, Store
from .worker import (Notifier, PoolManager, SessionConflict, SessionGone, SessionManager,
                     TaskWorker, new_id, run_config)

log = logging.getLogger("tmoc.api")

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


@dataclass
class Settings:
    """What `tmoc serve` configures; `token` comes from TMOC_API_TOKEN."""

    db: str = "tmoc.sqlite"
    ray_address: str | None = None
    token: str | None = None
    max_particles: int = 512
    max_episodes: int = 1000
    max_steps: int = 1000
    max_queued: int = 64
    max_sessions: int = 16
    max_body_bytes: int = 4 * 1024 * 1024
    n_shards: int | None = None
    shutdown_grace_s: float = 5.0
    max_frames: int = 48          # scene pictures kept per task (0: none rendered)


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("tmoc-service")
    except Exception:  # pragma: no cover - not installed
        return "0+unknown"


def _page(items: list, total: int, limit: int, offset: int) -> dict:
    """A list endpoint's envelope; next_offset is None on the last page."""
    nxt = offset + len(items) if offset + len(items) < total else None
    return {"items": items, "total": total, "limit": limit, "offset": offset, "next_offset": nxt}


# ----------------------------------------------------------------------------- errors
def _err(*codes: int) -> dict:
    return {c: {"model": S.ErrorBody} for c in codes}


def _loc_text(loc) -> str:
    parts = [str(p) for p in loc]
    if parts and parts[0] in ("body", "query", "path", "header") and len(parts) > 1:
        where = parts[0]
        rest = ".".join(parts[1:])
        return rest if where == "body" else f"{where} {rest}"
    return ".".join(parts) or "body"


def _friendly(err: dict, settings: Settings) -> str:
    loc = tuple(err.get("loc", ()))
    msg = err.get("msg", "invalid")
    typ = err.get("type", "")
    if loc[-1:] == ("reality",) and err.get("input") == "external" and typ == "literal_error":
        return "an external robot is driven through POST /v1/sessions; tasks use reality 'simulated'"
    if loc[-1:] == ("domain",) and typ == "literal_error":
        from coordinator.domains import names
        return f"unknown domain {err.get('input')!r} (known: {', '.join(names())}; GET /v1/domains)"
    if typ == "less_than_equal" and loc[-1:] == ("particles",):
        return f"{msg} (this server's limit --max-particles {settings.max_particles})"
    if typ == "less_than_equal" and loc[-1:] == ("episodes",):
        return f"{msg} (this server's limit --max-episodes {settings.max_episodes})"
    if typ == "less_than_equal" and loc[-1:] == ("max_steps",):
        return f"{msg} (this server's limit --max-steps {settings.max_steps})"
    if loc == ("header", "Last-Event-ID"):
        return "expected an episode index (an integer >= -1)"
    if typ == "json_invalid":
        ctx = err.get("ctx") or {}
        return f"malformed JSON at character {loc[-1] if len(loc) > 1 else '?'}: {ctx.get('error', msg)}"
    return msg


MAX_ERRORS = 20     # a body with 300k unknown keys made a 27 MB 422 and stalled the loop 8 s


def validation_body(errors: list[dict], settings: Settings) -> dict:
    """The 422 body: the first MAX_ERRORS errors (`errors_total` says how many there were)."""
    detail = []
    for e in errors[:MAX_ERRORS]:
        loc = [p for p in e.get("loc", ()) if not str(p).startswith(S.TAG_PREFIX)]   # the domain union's tag
        detail.append({"loc": loc, "msg": _friendly(e, settings), "type": e.get("type", "value_error")})
    message = "; ".join(f"{'body' if d['type'] == 'json_invalid' else _loc_text(d['loc'])}: {d['msg']}"
                        for d in detail[:5])
    body = {"detail": detail, "message": message}
    if len(errors) > MAX_ERRORS:
        body["errors_total"] = len(errors)
        body["message"] += f" (and {len(errors) - len(detail)} more errors)"
    return jsonable_encoder(body)


def refuse_invalid_config(spec: dict) -> None:
    """A 422 naming the field when a schema-valid spec is still not a valid run (a
    constraint across fields that no JSON schema states); never a 500 later."""
    from pydantic import ValidationError

    from .worker import run_config

    try:
        run_config(spec)
    except ValidationError as exc:
        err = exc.errors()[0]
        msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        field = [str(p) for p in err.get("loc", ())] or [msg.split(":", 1)[0].split(".")[0]]
        raise RequestValidationError([{"loc": ["body", *field], "msg": msg, "type": err.get("type", "value_error")}]) from None


def unprocessable(settings: Settings, loc: list, msg: str, typ: str = "value_error") -> JSONResponse:
    return JSONResponse(validation_body([{"loc": loc, "msg": msg, "type": typ}], settings), 422)


class BodyLimit:
    """Read the whole request body first (at most `limit` bytes: 413 over it, declared or
    streamed in chunks), refuse a JSON body with more than `max_keys` object keys (422:
    validating 300k unknown keys stalled the event loop for seconds), then hand the
    buffered body to the app."""

    def __init__(self, app, limit: int, max_keys: int = 2000) -> None:
        self.app, self.limit, self.max_keys = app, limit, max_keys

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers", ()))
        try:
            if int(headers.get(b"content-length", b"0")) > self.limit:
                return await self._refuse(send)
        except ValueError:
            pass
        chunks, seen, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] != "http.request":        # the client went away
                return
            body = message.get("body", b"")
            seen += len(body)
            if seen > self.limit:
                return await self._refuse(send)
            chunks.append(body)
            more = message.get("more_body", False)
        body = b"".join(chunks)
        if body and b"json" in headers.get(b"content-type", b"").lower():
            keys = _count_keys(body, self.max_keys)
            if keys > self.max_keys:
                return await _send_json(send, 422, {
                    "detail": [{"loc": ["body"], "type": "too_many_keys",
                                "msg": f"over {self.max_keys} object keys in one body"}],
                    "message": f"body: over {self.max_keys} object keys in one body"})
        replayed = False

        async def replay():
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()                       # e.g. http.disconnect for SSE

        await self.app(scope, replay, send)

    async def _refuse(self, send) -> None:
        await _send_json(send, 413, {"detail": f"request body over {self.limit} bytes"})


class _TooManyKeys(Exception):
    pass


def _count_keys(body: bytes, limit: int) -> int:
    """Object keys in a JSON body, counting stops past `limit`; 0 if it is not JSON (the
    app's own parser reports that)."""
    seen = 0

    def hook(pairs):
        nonlocal seen
        seen += len(pairs)
        if seen > limit:
            raise _TooManyKeys
        return dict(pairs)

    try:
        json.loads(body, object_pairs_hook=hook)
    except _TooManyKeys:
        return seen
    except (ValueError, RecursionError):
        return 0
    return seen


class AllowHeader:
    """A 405 lists every method the path supports (Starlette lists only the first route's)."""

    def __init__(self, app, fastapi_app) -> None:
        self.app, self.fastapi_app = app, fastapi_app
        self._table: list[tuple[re.Pattern, set[str]]] | None = None

    def table(self) -> list[tuple[re.Pattern, set[str]]]:
        if self._table is None:
            paths = {p: {m.upper() for m in ops} for p, ops in self.fastapi_app.openapi()["paths"].items()}
            paths.update({"/openapi.json": {"GET"}, "/docs": {"GET"}})
            self._table = [(re.compile("^" + re.sub(r"\\{[^}]+\\}", "[^/]+", re.escape(p)) + "$"), m)
                           for p, m in paths.items()]
        return self._table

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)

        async def patched(message):
            if message["type"] == "http.response.start" and message["status"] == 405:
                methods = set()
                for pattern, allowed in self.table():
                    if pattern.match(scope["path"]):
                        methods |= allowed
                headers = [(k, v) for k, v in message.get("headers", []) if k.lower() != b"allow"]
                headers.append((b"allow", ", ".join(sorted(methods)).encode()))
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, patched)


# ----------------------------------------------------------------------------- views
def _task_links(task_id: str) -> dict[str, str]:
    base = f"/v1/tasks/{task_id}"
    return {"self": base, "events": f"{base}/events", "episodes": f"{base}/episodes",
            "belief": f"{base}/belief", "curve": f"{base}/curve", "curve_png": f"{base}/curve.png",
            "frames": f"{base}/frames", "transition": f"{base}/transition"}


def task_nodes(row: dict, live: list[dict] | None = None) -> list[dict] | None:
    """The Ray nodes that ran a task's particles: the result's when it succeeded, else what
    the worker reported at the running task's last episode boundary."""
    runtime = (row.get("result") or {}).get("runtime") or {}
    nodes = runtime.get("nodes", live)
    if nodes is None:
        return None
    # Results stored by earlier versions list bare node ids.
    return [n if isinstance(n, dict) else {"node_id": str(n), "hostname": "", "shards": 0,
                                           "particle_actions": 0} for n in nodes]


def task_view(row: dict, live_nodes: list[dict] | None = None) -> dict:
    return {
        "id": row["id"], "status": row["status"], "spec": row["spec"],
        "progress": {"episodes_done": row["episodes_done"], "episodes": row["episodes"]},
        "latest": row.get("latest"), "cancel_requested": bool(row["cancel_requested"]),
        "attempts": row["attempts"], "error": row.get("error"), "result": row.get("result"),
        "nodes": task_nodes(row, live_nodes),
        "created_at": S.ts(row["created_at"]), "started_at": S.ts(row.get("started_at")),
        "finished_at": S.ts(row.get("finished_at")), "links": _task_links(row["id"]),
    }


def _session_links(session_id: str) -> dict[str, str]:
    base = f"/v1/sessions/{session_id}"
    return {"self": base, "next": f"{base}/next", "observations": f"{base}/observations",
            "episodes": f"{base}/episodes", "belief": f"{base}/belief", "curve": f"{base}/curve"}


def session_view(row: dict) -> dict:
    return {
        "id": row["id"], "status": row["status"], "spec": row["spec"],
        "episodes": row["spec"]["episodes"], "episodes_done": row["episodes_done"],
        "in_episode": bool(row["in_episode"]), "step": row["step"], "pending": row.get("pending"),
        "posterior": row.get("posterior"), "latest": row.get("latest"),
        "last_observation": _last_observation(row.get("last_reply")),
        "created_at": S.ts(row["created_at"]), "updated_at": S.ts(row["updated_at"]),
        "links": _session_links(row["id"]),
    }


def _last_observation(last_reply: dict | None) -> dict | None:
    """The last accepted observation (as stored: configuration, state, measurements), the
    action and step it answered and whether that action succeeded."""
    if not last_reply:
        return None
    report = (last_reply.get("reply") or {}).get("report") or {}
    return {"step_id": last_reply.get("step_id"), "action": last_reply.get("action"),
            "success": report.get("success"), **(last_reply.get("observation") or {})}


def _curve_points(records: list[dict]) -> list[dict]:
    return [{"episode": r["episode"], "utility": r["utility"],
             "size_mean": r["posterior"]["size_mean"], "size_std": r["posterior"]["size_std"],
             "actions": r["actions"], "delivered": r["delivered"], "loads": r["loads"],
             "properties": r["posterior"].get("properties")}
            for r in records]


_plot_lock = threading.Lock()


def _render_png(spec: dict, records: list[dict]) -> bytes:
    from coordinator.runner import plot_curve

    config = dict(spec)
    config.setdefault("true_size", float("nan"))
    buf = io.BytesIO()
    with _plot_lock:                     # pyplot keeps global state
        plot_curve({"config": config, "episodes": records}, buf)
    return buf.getvalue()


def _prior(spec: dict) -> tuple[dict | None, dict]:
    """The belief a run starts from (exactly: the same seeded draw as the run)."""
    from coordinator.session import Session

    s = Session(run_config(spec))
    return (s.belief.summary() if s.belief is not None else None), s.posterior()


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


# ----------------------------------------------------------------------------- the app
def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    TaskSpec = S.task_spec_model(settings.max_particles, settings.max_episodes, settings.max_steps)
    SessionCreate = S.session_create_model(settings.max_particles, settings.max_episodes,
                                           settings.max_steps)

    store_box: dict[str, Any] = {}
    notifier = Notifier()
    pools = PoolManager(settings.ray_address, settings.n_shards)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        store = Store(settings.db)
        worker = TaskWorker(store, pools, notifier, max_frames=settings.max_frames)
        sessions = SessionManager(store, pools, settings.max_sessions)
        store_box.update(store=store, worker=worker, sessions=sessions)
        app.state.store, app.state.worker, app.state.sessions = store, worker, sessions
        loop = asyncio.get_running_loop()
        notifier.bind(loop)
        shutting_down = asyncio.Event()
        store_box["shutting_down"] = shutting_down
        # Called from uvicorn's signal handling before it waits for open connections: event
        # streams end at once instead of holding a graceful stop for seconds.
        app.state.begin_shutdown = lambda: loop.call_soon_threadsafe(shutting_down.set)
        # Ray's core worker installs a C-level handler for SIGTERM/SIGINT when it starts (it
        # dumps a stack and aborts). Give the signals back to the server (graceful shutdown:
        # running tasks stop at a boundary and resume after a restart) once Ray is up.
        handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

        def restore_signals() -> None:
            for sig, handler in handlers.items():
                if callable(handler) or handler in (signal.SIG_DFL, signal.SIG_IGN):
                    try:
                        signal.signal(sig, handler)
                    except ValueError:   # not the main thread (an embedded server): leave them
                        pass

        pools.on_ray_ready = lambda: loop.call_soon_threadsafe(restore_signals)
        worker.start()
        try:
            yield
        finally:
            shutting_down.set()
            await run_in_threadpool(worker.stop, settings.shutdown_grace_s)
            await run_in_threadpool(pools.close)
            store.close()

    app = FastAPI(
        title="TMOC service",
        version=_version(),
        description=("Submit TMOC tasks, watch them learn (Server-Sent Events, belief, learning "
                     "curve) and drive an external robot step by step. With TMOC_API_TOKEN set, "
                     "every route but /health needs `Authorization: Bearer <token>`."),
        lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    # Starlette runs the last added outermost: the token first, then the body.
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)
    app.add_middleware(AllowHeader, fastapi_app=app)
    cookie_sessions = CookieSessions()
    if settings.token:
        app.add_middleware(TokenGate, token=settings.token, sessions=cookie_sessions)

    def store() -> Store:
        return store_box["store"]

    # -- access --------------------------------------------------------------------------
    deps = []
    if settings.token:
        bearer = HTTPBearer(auto_error=False, description="the server's TMOC_API_TOKEN")
        expected = settings.token.encode()

        async def require_token(request: Request,
                                creds: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)]):
            # `creds` declares the bearer scheme in the OpenAPI schema; a browser signed in at
            # /ui sends the session cookie instead (api.auth).
            if creds is not None and hmac.compare_digest(creds.credentials.encode(), expected):
                return
            if not authorised(dict(request.scope.get("headers", ())), expected, cookie_sessions):
                raise HTTPException(401, "missing or invalid token: send Authorization: Bearer <token>",
                                    headers={"WWW-Authenticate": "Bearer"})

        deps = [Depends(require_token)]

    # -- error handlers ------------------------------------------------------------------
    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError):
        errors = list(exc.errors())
        ctype = request.headers.get("content-type", "")
        if request.method in ("POST", "PUT", "PATCH") and "json" not in ctype.lower():
            for e in errors:
                if tuple(e.get("loc", ())) == ("body",):
                    e["msg"] = (f"expected a JSON object sent with Content-Type: application/json "
                                f"(got {ctype or 'no Content-Type'})")
        return JSONResponse(validation_body(errors, settings), 422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException):
        if exc.status_code == 400:       # FastAPI: a body that is not even text (bad UTF-8, ...)
            return JSONResponse(validation_body([{"loc": ["body"], "type": "json_invalid",
                                                  "msg": f"could not parse the body: {exc.detail}"}],
                                                settings), 422)
        return JSONResponse({"detail": exc.detail}, exc.status_code, headers=exc.headers)

    @app.exception_handler(sqlite3.Error)
    async def _storage(request: Request, exc: sqlite3.Error):
        log.error("storage error on %s %s: %s", request.method, request.url.path, exc)
        return JSONResponse({"detail": f"storage unavailable ({exc}); nothing was changed, "
                                       "retry later"}, 503, headers={"Retry-After": "5"})

    @app.exception_handler(Exception)
    async def _internal(request: Request, exc: Exception):  # pragma: no cover - a bug
        log.exception("internal error on %s %s", request.method, request.url.path)
        return JSONResponse({"detail": f"internal error: {type(exc).__name__}"}, 500)

    # -- health & docs -------------------------------------------------------------------
    @app.get("/health", response_model=S.Health, tags=["service"],
             responses={503: {"model": S.Health, "description": "the task worker is dead, "
                                                                "stalled or retrying"}})
    async def health(request: Request, response: Response):
        """Liveness, the task worker's state and a glimpse of the queue; never needs a
        token (the running task's id is shown only with one). 503 when not ok."""
        worker = store_box["worker"]
        state = worker.health()
        try:
            queued = store().count_tasks("queued")
        except sqlite3.Error as exc:
            queued, state = -1, {**state, "ok": False, "last_error": f"store: {exc}"}
        authorised = not settings.token or bearer_ok(
            request.headers.get("authorization", "").encode(), settings.token.encode())
        if not state["ok"]:
            response.status_code = 503
        return {"status": "ok" if state["ok"] else "degraded", "version": app.version,
                "ray": pools.ray_status, "queued": queued,
                "running": worker.current if authorised else None,
                "auth": bool(settings.token), "worker": state}

    docs = APIRouter(dependencies=deps, include_in_schema=False)

    @docs.get("/openapi.json")
    async def openapi_json():
        return JSONResponse(app.openapi())

    @docs.get("/docs")
    async def swagger():
        return get_swagger_ui_html(openapi_url="/openapi.json", title="TMOC service")

    app.include_router(docs)
    app.include_router(dashboard.router(settings.token, cookie_sessions))

    v1 = APIRouter(prefix="/v1", dependencies=deps, responses=_err(401))
    TaskId = Annotated[str, Path(min_length=1, max_length=64, description="task id (t_...)")]
    SessionId = Annotated[str, Path(min_length=1, max_length=64, description="session id (s_...)")]

    def task_json(row: dict) -> dict:
        """A task as the API shows it (with the live node report while it runs)."""
        worker = store_box.get("worker")
        return task_view(row, worker.nodes_of(row["id"]) if worker is not None else None)

    def task_or_404(task_id: str, **kw) -> dict:
        row = store().get_task(task_id, **kw)
        if row is None:
            raise HTTPException(404, f"task {task_id!r}: no such task")
        return row

    def session_or_404(session_id: str, **kw) -> dict:
        row = store().get_session(session_id, **kw)
        if row is None:
            raise HTTPException(404, f"session {session_id!r}: no such session")
        return row

    # -- tasks -----------------------------------------------------------------------------
    @v1.post("/tasks", status_code=202, response_model=S.TaskCreated, tags=["tasks"],
             responses=_err(413, 429))
    async def submit_task(spec: TaskSpec, response: Response):
        """Queue a task (202). Limits: particles, episodes (422 naming the field) and the
        number of queued tasks (429)."""
        task_id = new_id("t")
        body = S.spec_body(spec)
        refuse_invalid_config(body)
        try:
            await run_in_threadpool(store().create_task, task_id, body, settings.max_queued)
        except QueueFull as exc:
            raise HTTPException(429, f"max_queued: {exc.queued} tasks are queued, this server's "
                                     f"limit is {exc.limit} (--max-queued); retry later",
                                headers={"Retry-After": "5"}) from None
        store_box["worker"].submit(task_id)
        location = f"/v1/tasks/{task_id}"
        response.headers["Location"] = location
        return {"id": task_id, "status": "queued", "location": location, "links": _task_links(task_id)}

    @v1.get("/tasks", response_model=S.TaskList, tags=["tasks"])
    async def list_tasks(limit: Annotated[int, Query(ge=1, le=200)] = 50,
                         offset: Annotated[int, Query(ge=0, le=10**9)] = 0,
                         status: Annotated[S.TaskStatus | None, Query()] = None):
        """Tasks, newest first."""
        rows, total = store().list_tasks(limit, offset, status)
        return _page([task_json(r) for r in rows], total, limit, offset)

    @v1.get("/tasks/{task_id}", response_model=S.TaskView, tags=["tasks"], responses=_err(404))
    async def get_task(task_id: TaskId):
        """Status, progress, the latest episode's metrics, and the result when done."""
        return task_json(task_or_404(task_id))

    @v1.delete("/tasks/{task_id}", response_model=S.CancelView, tags=["tasks"],
               responses={**_err(404, 409), 202: {"model": S.CancelView}})
    async def cancel_task(task_id: TaskId, response: Response):
        """Cancel: a queued task is cancelled at once (200); a running one stops at its next
        episode boundary (202, `cancel_requested`); a finished one cannot be (409)."""
        outcome = await run_in_threadpool(store().cancel_task, task_id)
        if outcome is None:
            raise HTTPException(404, f"task {task_id!r}: no such task")
        status, changed = outcome
        if not changed:
            raise HTTPException(409, f"task {task_id!r} already {status}")
        if status == "running":
            store_box["worker"].cancel(task_id)
            response.status_code = 202
            detail = "cancel requested: the task stops at its next episode boundary"
        else:
            detail = "cancelled"
        return {**task_json(task_or_404(task_id)), "detail": detail}

    @v1.get("/tasks/{task_id}/episodes", tags=["tasks"], responses=_err(404),
            response_model=list[dict[str, Any]])
    async def task_episodes(task_id: TaskId,
                            after: Annotated[int, Query(ge=-1, le=10**9)] = -1,
                            limit: Annotated[int, Query(ge=1, le=1000)] = 1000):
        """Stored episode records with index > `after`, in order."""
        task_or_404(task_id)
        rows = store().episodes(task_id, after, limit)
        return Response("[" + ",".join(r for _, r in rows) + "]", media_type="application/json")

    @v1.get("/tasks/{task_id}/events", tags=["tasks"],
            responses={200: {"content": {"text/event-stream": {"schema": SSE_EVENT}},
                             "description": "`episode` events (id = episode index, data = the "
                                            "episode record) and `status` events; the stream "
                                            "ends after the final status"}, **_err(404)},
            response_class=StreamingResponse)
    async def task_events(request: Request, task_id: TaskId,
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
        st = store()
        if st.task_status(task_id) is None:
            raise HTTPException(404, f"task {task_id!r}: no such task")

        async def stream():
            ev = notifier.subscribe(task_id)
            try:
                yield "retry: 2000\n\n"
                last, last_status = start, None
                while True:
                    status, _ = st.task_status(task_id)
                    for episode, record in st.episodes(task_id, last):
                        yield f"id: {episode}\nevent: episode\ndata: {record}\n\n"
                        last = episode
                    if status != last_status:
                        view = json.dumps(jsonable_encoder(task_json(st.get_task(task_id))),
                                          separators=(",", ":"))
                        yield f"event: status\ndata: {view}\n\n"
                        last_status = status
                    if status in TERMINAL:
                        return
                    woke = await _wait_any(ev, store_box["shutting_down"], KEEPALIVE_S)
                    if woke == "shutdown":
                        return                 # the client reconnects with Last-Event-ID
                    if woke == "timeout":
                        yield ": keep-alive\n\n"
                    ev.clear()
            finally:
                notifier.unsubscribe(task_id, ev)

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    async def _belief_view(run_id: str, spec: dict, belief: dict | None, latest: dict | None,
                           done: int, true_size: float | None) -> dict:
        from coordinator.agents import agent as agent_spec

        learns = agent_spec(spec["agent"]).learn_belief
        if latest is not None:
            posterior = latest["posterior"]
        else:
            prior, posterior = await run_in_threadpool(_prior, spec)
            belief = belief or prior
        return {"run_id": run_id, "agent": spec["agent"], "episodes_done": done,
                "learns_belief": learns, "posterior": posterior,
                "belief": belief if learns else None, "true_size": true_size}

    @v1.get("/tasks/{task_id}/belief", response_model=S.BeliefView, tags=["tasks"], responses=_err(404))
    async def task_belief(task_id: TaskId):
        """The posterior over the block size at the last episode boundary (the prior before
        the first): mean, std, effective sample size and a weighted histogram."""
        row = task_or_404(task_id, belief=True)
        return await _belief_view(task_id, row["spec"], row.get("belief"), row.get("latest"),
                                  row["episodes_done"], row["spec"].get("true_size"))

    @v1.get("/tasks/{task_id}/curve", response_model=S.CurveView, tags=["tasks"], responses=_err(404))
    async def task_curve(task_id: TaskId):
        """The learning curve: utility and posterior size (mean, std) per episode."""
        row = task_or_404(task_id)
        records = [json.loads(r) for _, r in store().episodes(task_id)]
        return {"run_id": task_id, "agent": row["spec"]["agent"],
                "true_size": row["spec"].get("true_size"), "points": _curve_points(records)}

    @v1.get("/tasks/{task_id}/curve.png", tags=["tasks"], response_class=Response,
            responses={200: {"content": {"image/png": {"schema": {"type": "string", "format": "binary"}}},
                             "description": "the learning curve as a PNG"}, **_err(404)})
    async def task_curve_png(task_id: TaskId):
        """The learning curve as a PNG (`tmoc run`'s curve.png of the episodes so far)."""
        row = task_or_404(task_id)
        records = [json.loads(r) for _, r in store().episodes(task_id)]
        png = await run_in_threadpool(_render_png, row["spec"], records)
        return Response(png, media_type="image/png")

    frame_routes.add_routes(v1, store, task_or_404, TaskId, settings.max_frames, _err)

    # -- domains ---------------------------------------------------------------------------
    @v1.get("/domains", response_model=S.DomainList, tags=["domains"])
    async def list_domains():
        """Every registered domain (built-in and installed plugins), as `tmoc domains`."""
        from coordinator.domains import describe, names

        items = [await run_in_threadpool(describe, n) for n in names()]
        return {"items": items, "total": len(items)}

    @v1.get("/domains/{name}", response_model=S.DomainView, tags=["domains"], responses=_err(404))
    async def get_domain(name: Annotated[str, Path(min_length=1, max_length=64)]):
        """One domain: objects, L (names, units, prior), measurement channels, actions, T
        contexts and utility terms."""
        from coordinator.domains import describe, names

        if name not in names():
            raise HTTPException(404, f"domain {name!r}: no such domain (known: {', '.join(names())})")
        return await run_in_threadpool(describe, name)

    # -- sessions --------------------------------------------------------------------------
    def conflict(exc: SessionConflict) -> HTTPException:
        return HTTPException(409, str(exc))

    @v1.post("/sessions", status_code=201, response_model=S.SessionCreated, tags=["sessions"],
             responses=_err(409, 413, 429))
    async def create_session(body: SessionCreate, response: Response):
        """A TMOC session whose real world is an external robot. With `observation`, its
        first episode starts at once and `next` is the first action to execute."""
        spec = S.spec_body(body, exclude={"observation"})
        refuse_invalid_config(spec)
        initial = body.observation.model_dump(mode="json") if body.observation is not None else None
        try:
            session_id, nxt = await run_in_threadpool(store_box["sessions"].create, spec, initial)
        except QueueFull as exc:
            raise HTTPException(429, f"max_sessions: {exc.queued} sessions are active, this "
                                     f"server's limit is {exc.limit} (--max-sessions)",
                                headers={"Retry-After": "30"}) from None
        except SessionConflict as exc:
            raise conflict(exc) from None
        response.headers["Location"] = f"/v1/sessions/{session_id}"
        return {**session_view(session_or_404(session_id)), "next": nxt}

    @v1.get("/sessions", response_model=S.SessionList, tags=["sessions"])
    async def list_sessions(limit: Annotated[int, Query(ge=1, le=200)] = 50,
                            offset: Annotated[int, Query(ge=0, le=10**9)] = 0):
        rows, total = store().list_sessions(limit, offset)
        return _page([session_view(r) for r in rows], total, limit, offset)

    @v1.get("/sessions/{session_id}", response_model=S.SessionView, tags=["sessions"], responses=_err(404))
    async def get_session(session_id: SessionId):
        return session_view(session_or_404(session_id))

    @v1.delete("/sessions/{session_id}", response_model=S.SessionView, tags=["sessions"],
               responses=_err(404))
    async def close_session(session_id: SessionId):
        """Close the session: it frees its memory; its stored episodes stay readable."""
        status = await run_in_threadpool(store_box["sessions"].close, session_id)
        if status is None:
            raise HTTPException(404, f"session {session_id!r}: no such session")
        return session_view(session_or_404(session_id))

    async def _session_call(fn, *args):
        try:
            return await run_in_threadpool(fn, *args)
        except SessionGone:
            raise HTTPException(404, f"session {args[0]!r}: no such session") from None
        except SessionConflict as exc:
            raise conflict(exc) from None

    @v1.post("/sessions/{session_id}/episodes", status_code=201, response_model=S.EpisodeStarted,
             tags=["sessions"], responses=_err(404, 409, 413))
    async def start_episode(session_id: SessionId, observation: S.InitialObservation):
        """Start the next episode from the robot's initial observation; returns the first step."""
        episode, nxt = await _session_call(store_box["sessions"].start_episode, session_id,
                                           observation.model_dump(mode="json"))
        return {"session_id": session_id, "episode": episode, "next": nxt}

    @v1.get("/sessions/{session_id}/next", response_model=S.NextView, tags=["sessions"],
            responses=_err(404, 409))
    async def next_step(session_id: SessionId):
        """The pending action: its key pose, the trajectory to execute (columns t, x, y, z,
        yaw, opening) and the expected symbolic state after it. 409 when no episode is in
        progress."""
        episode, nxt = await _session_call(store_box["sessions"].next, session_id)
        return {"session_id": session_id, "episode": episode, "in_episode": True, "pending": nxt}

    @v1.post("/sessions/{session_id}/observations", response_model=S.ObservationResult,
             tags=["sessions"], responses=_err(404, 409, 413))
    async def observe(session_id: SessionId, observation: S.StepObservation):
        """What the robot observed after executing the pending action: updates the belief
        and T, and returns the step's report and the next step. An observation that does not
        fit the pending action (none pending, another action, a configuration of another
        scene) gets a 409 and changes nothing."""
        return await _session_call(store_box["sessions"].observe, session_id,
                                   observation.model_dump(mode="json"))

    @v1.get("/sessions/{session_id}/belief", response_model=S.BeliefView, tags=["sessions"],
            responses=_err(404))
    async def session_belief(session_id: SessionId):
        """The session's posterior over the block size, now (updated at every observation)."""
        from coordinator.agents import agent as agent_spec

        row = session_or_404(session_id, belief=True)
        learns = agent_spec(row["spec"]["agent"]).learn_belief
        return {"run_id": session_id, "agent": row["spec"]["agent"],
                "episodes_done": row["episodes_done"], "learns_belief": learns,
                "posterior": row.get("posterior") or {}, "belief": row.get("belief") if learns else None,
                "true_size": None}

    @v1.get("/sessions/{session_id}/curve", response_model=S.CurveView, tags=["sessions"],
            responses=_err(404))
    async def session_curve(session_id: SessionId):
        row = session_or_404(session_id)
        records = [json.loads(r) for _, r in store().episodes(session_id)]
        return {"run_id": session_id, "agent": row["spec"]["agent"], "true_size": None,
                "points": _curve_points(records)}

    app.include_router(v1)
    return app
