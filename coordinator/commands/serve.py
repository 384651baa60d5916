"""`tmoc serve`: the HTTP service (FastAPI on uvicorn) on this machine.

One uvicorn process with one event loop (never ``--workers N``: every worker would be its
own Ray driver with its own shard pools), one Ray driver and the shard pools shared by every
task and session. With TMOC_API_TOKEN set every route but /health needs
``Authorization: Bearer <token>``; without it the server binds only to loopback unless
``--insecure``.
"""
from __future__ import annotations

import argparse
import contextlib
import ipaddress
import logging
import os
import socket
import sqlite3

from ..distributed.reaper import clean, start_reaper, sweep
from ..run_config import field_bounds
from . import UsageError


def register(sub) -> None:
    p = sub.add_parser("serve", help="run the HTTP service (tasks, event streams, robot sessions)",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--host", default="127.0.0.1", help="interface to bind")
    p.add_argument("--port", type=int, default=8000)
    p.add_argument("--db", default="tmoc.sqlite", help="SQLite file (created if missing; WAL mode)")
    p.add_argument("--ray-address", default=None, help="join a running Ray cluster (default: local Ray)")
    p.add_argument("--insecure", action="store_true",
                   help="allow a non-loopback --host without TMOC_API_TOKEN")
    p.add_argument("--max-particles", type=int, default=512, help="largest `particles` a task may ask for")
    p.add_argument("--max-episodes", type=int, default=1000, help="largest `episodes` a task may ask for")
    p.add_argument("--max-steps", type=int, default=1000, help="largest `max_steps` a task may ask for")
    p.add_argument("--max-counterfactual-rows", type=int, default=32, metavar="M",
                   help="largest `counterfactual_rows` a task or session may ask for (its snapshot "
                        "simulates M x the domain's contexts before a plan); one that names none "
                        "gets min(4, M); 0: the paper's loop only")
    p.add_argument("--max-queued", type=int, default=64, help="queued tasks before submissions get 429")
    p.add_argument("--max-sessions", type=int, default=16, help="active robot sessions before 429")
    p.add_argument("--shards", type=int, default=None,
                   help="shard actors per pool (default: one per CPU of the Ray cluster)")
    p.add_argument("--max-frames", type=int, default=48,
                   help="scene pictures kept per task (the oldest go first; 0: none rendered)")
    p.add_argument("--log-level", default="info", choices=["critical", "error", "warning", "info", "debug"])
    p.add_argument("--no-access-log", action="store_true", help="do not log every request")
    p.add_argument("--session-idle-s", type=float, default=3600.0,
                   help="a robot session nothing was stored for this long stops counting against "
                        "--max-sessions and leaves memory (it still works when its robot returns)")
    p.add_argument("--max-task-runtime-s", type=float, default=3600.0,
                   help="a task's running time at most, and the budget of one that sets no "
                        "max_runtime_s: past it the task stops within one action and fails")
    p.add_argument("--max-connections", type=int, default=1024,
                   help="open connections before new ones get 503 (uvicorn's limit_concurrency)")
    p.add_argument("--allowed-host", action="append", default=[], metavar="NAME",
                   help="without TMOC_API_TOKEN, a Host name to answer besides localhost, "
                        "127.0.0.1, ::1 and --host (repeatable; '*': any)")
    p.add_argument("--retain-days", type=float, default=None, metavar="DAYS",
                   help="purge finished tasks and closed or finished sessions last changed more than "
                        "DAYS ago, at start-up and hourly (default: keep everything)")
    p.add_argument("--max-stored-steps", type=int, default=100_000, metavar="N",
                   help="episodes x max_steps a task or session may ask for at most: the step "
                        "records it may store (~1.4 KB each)")
    p.add_argument("--max-auth-failures", type=int, default=10, metavar="N",
                   help="wrong tokens (sign-ins or bearer) an address may send in a minute before "
                        "it is refused with 429 until they age out (10 N over all addresses)")
    p.add_argument("--forwarded-allow-ips", default=None, metavar="IPS",
                   help="trust X-Forwarded-For/-Proto from these proxy addresses (comma-separated, "
                        "'*': any); default: trust none, so the address a sign-in throttle "
                        "counts is the connection's")
    p.set_defaults(func=main)


def is_loopback(host: str) -> bool:
    """True if every address `host` names is a loopback address."""
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except (socket.gaierror, UnicodeError) as exc:
        raise UsageError(f"--host: cannot resolve {host!r} ({exc})") from None
    return bool(infos) and all(ipaddress.ip_address(i[4][0].split("%")[0]).is_loopback for i in infos)


def check_args(args) -> str | None:
    """Validate the flags; returns the API token (None: no auth)."""
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port: {args.port} is outside [0, 65535]")
    for flag in ("max_particles", "max_episodes", "max_steps", "max_queued", "max_sessions",
                 "max_connections"):
        if getattr(args, flag, 1) < 1:
            raise UsageError(f"--{flag.replace('_', '-')}: must be at least 1 (got {getattr(args, flag)})")
    for flag, field in (("max_particles", "particles"), ("max_episodes", "episodes"), ("max_steps", "max_steps")):
        most = field_bounds(field)[1]              # RunConfig's limit: the one place for it
        if getattr(args, flag) > most:
            raise UsageError(f"--{flag.replace('_', '-')}: {getattr(args, flag)} is over {most}, "
                             "the most a task can use")
    rows = getattr(args, "max_counterfactual_rows", 32)
    if not 0 <= rows <= field_bounds("counterfactual_rows")[1]:
        raise UsageError(f"--max-counterfactual-rows: must be in [0, {field_bounds('counterfactual_rows')[1]}] "
                         f"(got {rows})")
    idle = getattr(args, "session_idle_s", 3600.0)
    if not 1.0 <= idle <= 366 * 86400:
        raise UsageError(f"--session-idle-s: must be in [1, 31622400] seconds (got {idle})")
    budget = getattr(args, "max_task_runtime_s", 3600.0)
    if not 1.0 <= budget <= 366 * 86400:       # also refuses nan and inf
        raise UsageError(f"--max-task-runtime-s: must be in [1, 31622400] seconds (got {budget})")
    retain = getattr(args, "retain_days", None)
    if retain is not None and not 0.0 < retain <= 36600:       # also refuses nan and inf
        raise UsageError(f"--retain-days: must be in (0, 36600] days (got {retain})")
    if not 1 <= getattr(args, "max_auth_failures", 10) <= 10**6:
        raise UsageError(f"--max-auth-failures: must be in [1, 1000000] (got {args.max_auth_failures})")
    if not 1 <= getattr(args, "max_stored_steps", 1) <= 10**8:
        raise UsageError(f"--max-stored-steps: must be in [1, 100000000] (got {args.max_stored_steps})")
    if getattr(args, "max_frames", 0) < 0 or getattr(args, "max_frames", 0) > 10000:
        raise UsageError(f"--max-frames: must be in [0, 10000] (got {args.max_frames})")
    if args.shards is not None and args.shards < 1:
        raise UsageError(f"--shards: must be at least 1 (got {args.shards})")
    token = os.environ.get("TMOC_API_TOKEN")
    if token is not None and not token.strip():
        raise UsageError("TMOC_API_TOKEN is set but empty: set a token or unset it")
    if not token and not is_loopback(args.host) and not args.insecure:
        raise UsageError(f"--host {args.host}: without TMOC_API_TOKEN the service binds only to "
                         "loopback (127.0.0.1, ::1); set TMOC_API_TOKEN or pass --insecure")
    return token or None


# An IPv6 literal arrives in brackets (`Host: [::1]:8000`, RFC 3986), and Starlette keeps
# them; both spellings are listed (issue 38: `Host: [::1]` got 400).
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1", "[::1]")


def allowed_hosts(args, token: str | None) -> tuple[str, ...] | None:
    """The Host names a server without a token answers to (None: any; a token guards it).
    Issue 25: without one, `Host: evil.example` reached the whole API (DNS rebinding)."""
    extra = list(getattr(args, "allowed_host", []) or [])
    if token or "*" in extra:
        return None
    names = [*LOOPBACK_NAMES, *extra]
    if args.host not in ("0.0.0.0", "::", ""):
        names.append(args.host)
    names += [f"[{n}]" for n in list(names) if ":" in n and not n.startswith("[")]
    return tuple(dict.fromkeys(names))


def _server_class():
    import uvicorn

    class Server(uvicorn.Server):
        """uvicorn's server that tells the app a stop began (its event streams end at once)."""

        def __init__(self, config, app) -> None:
            super().__init__(config)
            self.app = app

        def handle_exit(self, sig, frame) -> None:
            begin = getattr(self.app.state, "begin_shutdown", None)
            if begin is not None:
                begin()
            super().handle_exit(sig, frame)

        @contextlib.contextmanager
        def capture_signals(self):
            # uvicorn raises the caught SIGTERM/SIGINT again after its shutdown, so a clean
            # stop exited with -15 (issue 25): a stop that completed exits 0. If serving
            # failed, the yield raises and the signal is re-raised as before.
            with super().capture_signals():
                yield
                captured = getattr(self, "_captured_signals", None)
                if isinstance(captured, list):
                    captured.clear()

    return Server


def _Server(config, app):
    return _server_class()(config, app)


def main(args) -> int:
    token = check_args(args)
    from api.app import Settings, create_app
    from api.database import lock_database
    from api.store import Store

    if args.db == ":memory:" or args.db.startswith("file:"):
        raise UsageError(f"--db {args.db}: an in-memory or URI database is not shared by the "
                         "server's threads; give a file path (created if missing)")
    try:
        lock = lock_database(args.db)        # one server per database (its folder made first)
        Store(args.db).close()
    except (sqlite3.Error, OSError) as exc:
        raise UsageError(f"--db {args.db}: {exc}") from None

    import uvicorn

    settings = Settings(db=args.db, ray_address=args.ray_address, token=token,
                        max_particles=args.max_particles, max_episodes=args.max_episodes,
                        max_steps=args.max_steps, max_queued=args.max_queued,
                        max_counterfactual_rows=args.max_counterfactual_rows,
                        max_sessions=args.max_sessions, n_shards=args.shards,
                        max_frames=args.max_frames, allowed_hosts=allowed_hosts(args, token),
                        max_task_runtime_s=args.max_task_runtime_s,
                        session_idle_s=args.session_idle_s, retain_days=args.retain_days,
                        max_stored_steps=args.max_stored_steps,
                        max_auth_failures=args.max_auth_failures)
    app = create_app(settings)
    config = uvicorn.Config(app, host=args.host, port=args.port, workers=1,
                            log_level=args.log_level, access_log=not args.no_access_log,
                            timeout_graceful_shutdown=10, lifespan="on",
                            limit_concurrency=args.max_connections,
                            # uvicorn trusts X-Forwarded-For from loopback by default: a local
                            # proxy's header would pick the address a throttle counts (issue 38).
                            proxy_headers=args.forwarded_allow_ips is not None,
                            forwarded_allow_ips=args.forwarded_allow_ips)
    server = _Server(config, app)
    # Our own Ray's agents outlived a kill -9 by 60 s; a reaper takes them down (issue 25).
    # A cluster we join is not ours to reap.
    reaper = start_reaper() if not args.ray_address else None
    try:
        server.run()
        if not args.ray_address:
            # Ray is shut down by now, or was still starting and not waited for (a SIGTERM
            # at start-up, issue 38 row 11). Then its GCS and raylet die with this process
            # as after a kill -9, and the agents and workers the raylet started would wait
            # up to a minute for them (issue 25), with the reaper told the exit was clean:
            # the whole tree goes now. (Seen once in CI, under load: Ray outlived the test's 15 s.)
            left = sweep(os.getpid(), exclude={reaper.pid} if reaper is not None else ())
            if left:
                logging.getLogger("uvicorn.error").info("killed %d of Ray's processes left at exit", left)
        clean(reaper)
    finally:
        lock.close()
    return 0 if server.started else 1
