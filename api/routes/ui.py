"""The dashboard at ``/ui`` (issue 16): plain HTML, JS and CSS shipped in ``api/ui/`` (no
build step), and the browser's sign-in (``POST /ui/login`` -> the ``tmoc_session`` cookie,
``POST /ui/logout``; see api.auth).

The shell and its static files are open (they hold no data); everything shown comes from
the gated /v1 routes. Files are read once, on import, so no route touches the disk.
"""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
import json
import math
import time
from importlib import resources
from urllib.parse import parse_qs, urlsplit

from fastapi import APIRouter, HTTPException, Path, Request
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response

from ..auth import COOKIE, SESSION_TTL_S, LoginThrottle, client_address, session_id, token_ok
from ..deps import CookieSessionsDep, SettingsDep

TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8", ".svg": "image/svg+xml", ".png": "image/png"}
NEXT_PAGES = ("/ui", "/docs")          # where a sign-in may send the browser on
# No inline script runs and nothing loads from elsewhere: a reflected string can do nothing.
CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
       "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'")


def _static_files() -> dict[str, bytes]:
    root = resources.files("api") / "ui"
    return {f.name: f.read_bytes() for f in root.iterdir()
            if f.is_file() and any(f.name.endswith(ext) for ext in TYPES)}


def _headers(name: str) -> dict[str, str]:
    ext = name[name.rfind("."):]
    return {"Content-Type": TYPES[ext], "Cache-Control": "no-cache", "X-Content-Type-Options": "nosniff",
            "Content-Security-Policy": CSP, "Referrer-Policy": "no-referrer"}


def _failed_page(message: str) -> str:
    return ("<!doctype html><html><head><meta charset='utf-8'><title>TMOC: sign-in failed</title>"
            "<link rel='stylesheet' href='/ui/static/app.css'></head><body><main class='signin'>"
            f"<h1>Sign-in failed</h1><p id='signin-error'>{message}</p>"
            "<p><a href='/ui'>Try again</a></p></main></body></html>")


async def _login_fields(request: Request) -> dict[str, str]:
    """`token` and `next` from a form or a JSON body (the body is buffered by BodyLimit)."""
    body = await request.body()
    ctype = request.headers.get("content-type", "").lower()
    if "json" in ctype:
        try:
            data = json.loads(body or b"{}")
        except ValueError:
            raise HTTPException(422, "body: malformed JSON") from None
        if not isinstance(data, dict):
            raise HTTPException(422, "body: expected a JSON object with `token`")
        return {k: v for k, v in data.items() if isinstance(v, str)}
    try:
        form = parse_qs(body.decode("utf-8"), max_num_fields=8)
    except (UnicodeDecodeError, ValueError):
        raise HTTPException(422, "body: expected a form (token=...) or JSON {\"token\": ...}") from None
    return {k: v[0] for k, v in form.items()}


_FILES = _static_files()
router = APIRouter(include_in_schema=False)


@router.get("/ui")
@router.get("/ui/")
async def index():
    return Response(_FILES["index.html"], headers=_headers("index.html"))


@router.get("/ui/static/{name}")
async def static(name: str = Path(max_length=64)):
    if name not in _FILES:
        raise HTTPException(404, f"/ui/static/{name}: no such file")
    return Response(_FILES[name], headers=_headers(name))


@router.post("/ui/login")
async def login(request: Request, settings: SettingsDep, sessions: CookieSessionsDep):
    """Sign a browser in: the token (form field or JSON key `token`) for a session cookie."""
    token = settings.token
    if not token:
        return JSONResponse({"detail": "this server has no token (TMOC_API_TOKEN): no sign-in "
                                       "needed"}, 409)
    throttle = getattr(request.app.state, "login_throttle", None)
    if throttle is None:
        throttle = request.app.state.login_throttle = LoginThrottle()
    address = client_address(request.scope)
    wait = throttle.retry_after(address, time.monotonic())
    if wait is not None:
        raise HTTPException(429, "too many failed sign-ins: wait and retry",
                            headers={"Retry-After": str(max(1, math.ceil(wait)))})
    fields = await _login_fields(request)
    as_json = "json" in request.headers.get("content-type", "").lower()
    if not fields.get("token"):
        raise HTTPException(422, "token: missing")
    if not token_ok(fields["token"], token):
        throttle.failed(address, time.monotonic())
        if as_json:
            return JSONResponse({"detail": "token: invalid"}, 401, headers={"WWW-Authenticate": "Bearer"})
        return HTMLResponse(_failed_page("The token is not this server's."), 401,
                            headers={"WWW-Authenticate": "Bearer", "Content-Security-Policy": CSP})
    nxt = fields.get("next") if fields.get("next") in NEXT_PAGES else "/ui"
    response = (JSONResponse({"signed_in": True, "next": nxt}) if as_json
                else RedirectResponse(nxt, 303))
    secure = (request.url.scheme == "https"
              or request.headers.get("x-forwarded-proto", "").lower() == "https")
    response.set_cookie(COOKIE, sessions.issue(), max_age=int(SESSION_TTL_S), path="/",
                        httponly=True, samesite="strict", secure=secure)
    return response


def cross_site(request: Request) -> bool:
    """A browser's request from another page than ours. Sec-Fetch-Site, which every current
    browser sends, decides: only `same-origin` (our page) and `none` (typed, a bookmark)
    pass. Without it (a script, an old browser) an Origin must be this server's; our page's
    own form sends `Origin: null` under its `no-referrer` policy, as a sandboxed frame
    would, so `null` passes only with Sec-Fetch-Site."""
    fetch_site = request.headers.get("sec-fetch-site")
    if fetch_site is not None:
        return fetch_site.lower() not in ("same-origin", "none")
    origin = request.headers.get("origin")
    if origin is None:
        return False
    return urlsplit(origin).netloc.lower() != request.headers.get("host", "").lower()


@router.post("/ui/logout")
async def logout(request: Request, sessions: CookieSessionsDep):
    """Sign the browser out (its session id revoked, the cookie cleared). Another site's
    page may not do it (issue 25: a cross-site POST cleared the cookie): 403."""
    if cross_site(request):
        raise HTTPException(403, "sign-out from another site's page refused")
    sessions.revoke(session_id(request.headers.get("cookie", "")))
    response = RedirectResponse("/ui", 303)
    response.delete_cookie(COOKIE, path="/", httponly=True, samesite="strict")
    return response


__all__ = ["router"]
