"""Error responses of the service: the 422 body (friendly messages naming the field and the
server's limit), the OpenAPI entries of error statuses, and the exception handlers
(validation, HTTP errors, storage errors, bugs).
"""
from __future__ import annotations

import logging
import sqlite3

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from . import schemas as S
from .settings import Settings

log = logging.getLogger("tmoc.api")

MAX_ERRORS = 20     # a body with 300k unknown keys made a 27 MB 422 and stalled the loop 8 s


def error_responses(*codes: int) -> dict:
    """The `responses` entry of a route for these error statuses (body: ErrorBody)."""
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
    if typ == "less_than_equal" and loc[-1:] == ("counterfactual_rows",):
        return f"{msg} (this server's limit --max-counterfactual-rows {settings.max_counterfactual_rows})"
    if typ == "less_than_equal" and loc[-1:] == ("episodes",):
        return f"{msg} (this server's limit --max-episodes {settings.max_episodes})"
    if typ == "less_than_equal" and loc[-1:] == ("max_steps",):
        return f"{msg} (this server's limit --max-steps {settings.max_steps})"
    if typ == "less_than_equal" and loc[-1:] == ("max_runtime_s",):
        return f"{msg} (this server's limit --max-task-runtime-s {settings.max_task_runtime_s:g})"
    if loc == ("header", "Last-Event-ID"):
        return "expected an episode index (an integer >= -1)"
    if typ == "json_invalid":
        ctx = err.get("ctx") or {}
        return f"malformed JSON at character {loc[-1] if len(loc) > 1 else '?'}: {ctx.get('error', msg)}"
    return msg


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

    try:
        S.run_config(spec)
    except ValidationError as exc:
        err = exc.errors()[0]
        msg = str(err.get("msg", "invalid")).removeprefix("Value error, ")
        field = [str(p) for p in err.get("loc", ())] or [msg.split(":", 1)[0].split(".")[0]]
        raise RequestValidationError([{"loc": ["body", *field], "msg": msg, "type": err.get("type", "value_error")}]) from None


def refuse_unstorable(spec: dict, max_stored_steps: int) -> None:
    """A 422 naming `episodes` when episodes x max_steps exceeds what this server stores
    for one task or session (`--max-stored-steps`; issue 38: one session of the allowed
    size could store ~2.9 GB that nothing reclaimed)."""
    episodes, steps = int(spec.get("episodes", 1)), int(spec.get("max_steps", 1))
    if episodes * steps > max_stored_steps:
        msg = (f"episodes x max_steps = {episodes} x {steps} = {episodes * steps} steps is over this "
               f"server's limit of {max_stored_steps} stored steps (--max-stored-steps)")
        raise RequestValidationError([{"loc": ["body", "episodes"], "msg": msg, "type": "value_error"}])


def unprocessable(settings: Settings, loc: list, msg: str, typ: str = "value_error") -> JSONResponse:
    """A 422 shaped like a validation error, for a check made inside a route."""
    return JSONResponse(validation_body([{"loc": loc, "msg": msg, "type": typ}], settings), 422)


# ----------------------------------------------------------------------------- handlers
async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
    errors = list(exc.errors())
    ctype = request.headers.get("content-type", "")
    if request.method in ("POST", "PUT", "PATCH") and "json" not in ctype.lower():
        for e in errors:
            # the domain union's tag is part of `loc` (text/plain reached the union: issue 25)
            loc = tuple(p for p in e.get("loc", ()) if not str(p).startswith(S.TAG_PREFIX))
            if loc == ("body",):
                e["msg"] = (f"expected a JSON object sent with Content-Type: application/json "
                            f"(got {ctype or 'no Content-Type'})")
    return JSONResponse(validation_body(errors, request.app.state.settings), 422)


async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    if exc.status_code == 400:       # FastAPI: a body that is not even text (bad UTF-8, ...)
        return JSONResponse(validation_body([{"loc": ["body"], "type": "json_invalid",
                                              "msg": f"could not parse the body: {exc.detail}"}],
                                            request.app.state.settings), 422)
    return JSONResponse({"detail": exc.detail}, exc.status_code, headers=exc.headers)


async def _storage(request: Request, exc: sqlite3.Error) -> JSONResponse:
    log.error("storage error on %s %s: %s", request.method, request.url.path, exc)
    return JSONResponse({"detail": f"storage unavailable ({exc}); nothing was changed, "
                                   "retry later"}, 503, headers={"Retry-After": "5"})


async def _internal(request: Request, exc: Exception) -> JSONResponse:  # pragma: no cover - a bug
    log.exception("internal error on %s %s", request.method, request.url.path)
    # Connection: close, so a keep-alive client does not send its next request down the
    # connection uvicorn closes after a server error (issue 38: one 500 became a
    # "connection reset" on the client's next, unrelated request).
    return JSONResponse({"detail": f"internal error: {type(exc).__name__}"}, 500,
                        headers={"Connection": "close"})


def add_exception_handlers(app: FastAPI) -> None:
    """422 for every malformed request, the {detail} body for HTTP errors, 503 when the
    store fails, 500 naming only the exception's type for a bug."""
    app.add_exception_handler(RequestValidationError, _validation)
    app.add_exception_handler(StarletteHTTPException, _http)
    app.add_exception_handler(sqlite3.Error, _storage)
    app.add_exception_handler(Exception, _internal)


__all__ = ["MAX_ERRORS", "add_exception_handlers", "error_responses", "refuse_invalid_config", "refuse_unstorable",
           "unprocessable", "validation_body"]
