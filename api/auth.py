"""Access to the service: the bearer token, and a session cookie for browsers (issue 16).

A browser cannot put ``Authorization: Bearer`` on a page load, an ``<img>`` or an
EventSource, and a token in a URL ends up in logs and history. So ``POST /ui/login`` with
the token (form or JSON) sets ``tmoc_session``: a random id the server maps in memory to an
expiry (never the token, nor anything derived from it), HttpOnly (page scripts cannot read
it) and SameSite=Strict (no other site's page sends it, so no cross-site request forgery).
Every gated route accepts either credential. A restart forgets the sessions: sign in again.
"""
from __future__ import annotations

import hmac
import json
import math
import secrets
import threading
import time

from starlette.requests import cookie_parser

COOKIE = "tmoc_session"
SESSION_TTL_S = 12 * 3600
MAX_SESSIONS = 1000          # sign-ins kept at once; the oldest goes first beyond it

# Paths open without credentials: liveness, and the dashboard's shell (sign-in page,
# static files, login/logout). The shell holds no data: everything it shows comes from
# the gated /v1 routes.
OPEN_PATHS = ("/health",)
OPEN_PREFIXES = ("/ui",)


class CookieSessions:
    """Signed-in browser sessions: random ids -> expiry (monotonic clock), in memory."""

    def __init__(self, ttl_s: float = SESSION_TTL_S, max_sessions: int = MAX_SESSIONS) -> None:
        self.ttl_s, self.max_sessions = ttl_s, max_sessions
        self._expiry: dict[str, float] = {}
        self._lock = threading.Lock()

    def issue(self) -> str:
        sid = secrets.token_urlsafe(32)
        now = time.monotonic()
        with self._lock:
            self._expiry = {k: t for k, t in self._expiry.items() if t > now}
            while len(self._expiry) >= self.max_sessions:
                self._expiry.pop(min(self._expiry, key=self._expiry.get))
            self._expiry[sid] = now + self.ttl_s
        return sid

    def valid(self, sid: str | None) -> bool:
        if not sid:
            return False
        with self._lock:
            expiry = self._expiry.get(sid)
        return expiry is not None and expiry > time.monotonic()

    def revoke(self, sid: str | None) -> None:
        with self._lock:
            self._expiry.pop(sid or "", None)


def bearer_ok(header: bytes, token: bytes) -> bool:
    scheme, _, credentials = header.partition(b" ")
    return scheme.lower() == b"bearer" and hmac.compare_digest(credentials.strip(), token)


def token_ok(given: str, token: str) -> bool:
    return hmac.compare_digest(given.strip().encode(), token.encode())


def session_id(cookie_header: bytes | str) -> str | None:
    """The tmoc_session cookie of a Cookie header, if any."""
    text = cookie_header.decode("latin-1") if isinstance(cookie_header, bytes) else cookie_header
    return cookie_parser(text).get(COOKIE) if text else None


def authorised(headers: dict[bytes, bytes], token: bytes, sessions: CookieSessions) -> bool:
    """A valid bearer token, or the cookie of a signed-in session."""
    return (bearer_ok(headers.get(b"authorization", b""), token)
            or sessions.valid(session_id(headers.get(b"cookie", b""))))


def is_open(path: str) -> bool:
    return path in OPEN_PATHS or any(path == p or path.startswith(p + "/") for p in OPEN_PREFIXES)


async def send_json(send, status: int, payload: dict, headers: list | None = None) -> None:
    """A whole JSON response straight onto the ASGI channel (middleware answers with it
    before any route runs)."""
    body = json.dumps(payload).encode()
    await send({"type": "http.response.start", "status": status,
                "headers": [(b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()), *(headers or [])]})
    await send({"type": "http.response.body", "body": body})


def client_address(scope) -> str:
    """The address a request came from, as the server saw it (a proxy's header counts only
    where `tmoc serve --forwarded-allow-ips` trusts that proxy: uvicorn rewrites it)."""
    client = scope.get("client")
    return str(client[0]) if client else ""


class TokenGate:
    """With a token set: 401 for every path but the open ones unless the request carries
    the token (bearer) or a signed-in session's cookie, before anything else (the body
    included) is read or parsed. A wrong bearer token counts as a failed sign-in of its
    address (`throttle`, shared with ``POST /ui/login``), and an address over the limit is
    refused (429) whatever it sends until its failures age out (issue 38: 1000 wrong tokens
    went through in 1.1 s as `Authorization`, bypassing the sign-in page's throttle)."""

    def __init__(self, app, token: str, sessions: CookieSessions | None = None,
                 throttle: "LoginThrottle | None" = None) -> None:
        self.app, self.token = app, token.encode()
        self.sessions = sessions if sessions is not None else CookieSessions()
        self.throttle = throttle if throttle is not None else LoginThrottle()

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http" or is_open(scope["path"]):
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers", ()))
        address, now = client_address(scope), time.monotonic()
        wait = self.throttle.retry_after(address, now)
        if wait is not None:
            return await send_json(send, 429, {"detail": "too many failed sign-ins from this address: "
                                                         "wait and retry"},
                                   [(b"retry-after", str(max(1, math.ceil(wait))).encode())])
        if not authorised(headers, self.token, self.sessions):
            if headers.get(b"authorization"):          # a guess, not a missing credential
                self.throttle.failed(address, now)
            return await send_json(send, 401, {"detail": "missing or invalid token: send Authorization: "
                                                         "Bearer <token>, or sign in at /ui"},
                                   [(b"www-authenticate", b"Bearer")])
        await self.app(scope, receive, send)


class LoginThrottle:
    """Failed sign-ins (a wrong token at ``/ui/login`` or as a bearer) per client address in
    a sliding window: at most `per_address` per `window_s`, then 429 for that address until
    its oldest failure ages out (issue 25: 2000 wrong tokens went through at 736 a second).
    Past `in_all` failures over every address in the window, an address that has failed in
    it waits too, but one that has not is never refused: guessers from many addresses slow
    down, and nobody else is locked out (issue 38: 100 failures a minute from anywhere
    locked everyone out, the right token included). Memory is bounded: at most
    `max_addresses` addresses are remembered (the stalest forgotten first). Thread-safe."""

    def __init__(self, per_address: int = 10, in_all: int = 100, window_s: float = 60.0,
                 max_addresses: int = 4096) -> None:
        self.per_address, self.in_all, self.window_s = per_address, in_all, window_s
        self.max_addresses = max_addresses
        self._fails: dict[str, list[float]] = {}
        self._all: list[float] = []
        self._lock = threading.Lock()

    def _trim(self, times: list[float], now: float) -> list[float]:
        return [t for t in times if now - t < self.window_s]

    def retry_after(self, address: str, now: float) -> float | None:
        """Seconds until `address` may try again (None: it may now)."""
        with self._lock:
            self._all = self._trim(self._all, now)
            mine = self._trim(self._fails.get(address, []), now)
            if mine:
                self._fails[address] = mine
            else:
                self._fails.pop(address, None)
            waits = []
            if len(mine) >= self.per_address:
                waits.append(self.window_s - (now - mine[0]))
            if mine and len(self._all) >= self.in_all:
                waits.append(self.window_s - (now - self._all[0]))
            return max(waits) if waits else None

    def failed(self, address: str, now: float) -> None:
        with self._lock:
            self._fails.setdefault(address, []).append(now)
            self._all.append(now)
            if len(self._all) > 4 * self.in_all:
                del self._all[:-4 * self.in_all]          # bounded; only the count over in_all matters
            if len(self._fails) > self.max_addresses:
                stalest = min(self._fails, key=lambda a: self._fails[a][-1] if self._fails[a] else 0.0)
                self._fails.pop(stalest, None)
