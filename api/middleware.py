"""The service's ASGI middlewares: the request body limit (bytes and JSON keys) and a
complete Allow header on 405; ``add_middlewares`` stacks them with the token gate.
"""
from __future__ import annotations

import json
import re

from fastapi import FastAPI

from .auth import CookieSessions, TokenGate, send_json
from .settings import Settings


class BodyLimit:
    """Read the whole request body first (at most `limit` bytes: 413 over it, declared or
    streamed in chunks), refuse a JSON body with more than `max_keys` object keys (422:
    validating 300k unknown keys stalled the event loop for seconds), then hand the
    buffered body to the app."""

    # Sign-in and sign-out bodies are a token and a page name: a few hundred bytes. These
    # paths are open (no token needed), so a big body there costs the reader nothing.
    SMALL_PATHS = {"/ui/login": 4096, "/ui/logout": 4096}
    # JSON objects and arrays in one body: no route takes more than a few hundred; counted
    # in C (bytes.count) before any parse (issue 25: 4 MiB of `[[{}],[{}],...]` kept the
    # key counter's per-object hook busy for seconds on the event loop).
    MAX_CONTAINERS = 20000

    def __init__(self, app, limit: int, max_keys: int = 2000) -> None:
        self.app, self.limit, self.max_keys = app, limit, max_keys

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers", ()))
        limit = min(self.limit, self.SMALL_PATHS.get(scope.get("path", ""), self.limit))
        try:
            if int(headers.get(b"content-length", b"0")) > limit:
                return await self._refuse(send, limit)
        except ValueError:
            pass
        chunks, seen, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] != "http.request":        # the client went away
                return
            body = message.get("body", b"")
            seen += len(body)
            if seen > limit:
                return await self._refuse(send, limit)
            chunks.append(body)
            more = message.get("more_body", False)
        body = b"".join(chunks)
        if body and b"json" in headers.get(b"content-type", b"").lower():
            if body.count(b"{") + body.count(b"[") > self.MAX_CONTAINERS:
                return await send_json(send, 422, {
                    "detail": [{"loc": ["body"], "type": "too_many_containers",
                                "msg": f"over {self.MAX_CONTAINERS} JSON objects and arrays in one body"}],
                    "message": f"body: over {self.MAX_CONTAINERS} JSON objects and arrays in one body"})
            keys = _count_keys(body, self.max_keys)
            if keys > self.max_keys:
                return await send_json(send, 422, {
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

    async def _refuse(self, send, limit: int | None = None) -> None:
        await send_json(send, 413, {"detail": f"request body over {limit or self.limit} bytes"})


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


def add_middlewares(app: FastAPI, settings: Settings, cookie_sessions: CookieSessions) -> None:
    """Starlette runs the last added outermost: the token first, then the body."""
    app.add_middleware(BodyLimit, limit=settings.max_body_bytes)
    app.add_middleware(AllowHeader, fastapi_app=app)
    if settings.token:
        # One throttle for bearer guesses and sign-ins (app.state.login_throttle).
        app.add_middleware(TokenGate, token=settings.token, sessions=cookie_sessions,
                           throttle=getattr(app.state, "login_throttle", None))


__all__ = ["AllowHeader", "BodyLimit", "add_middlewares"]
