"""The sessions resource: an external robot driven step by step (create, read, close, start
an episode, the pending step, post an observation, the belief and the learning curve).

Built per app (:func:`router`): POST /sessions takes this server's SessionCreate, whose
limits are part of the OpenAPI schema; the other routes are shared (``routes``).
"""
# No `from __future__ import annotations`: FastAPI must see the real classes in signatures.
import json
from typing import Annotated

from fastapi import APIRouter, HTTPException, Query, Response
from starlette.concurrency import run_in_threadpool

from .. import exports
from .. import schemas as S
from .. import views
from ..deps import ExportsDep, SessionId, SessionsDep, SettingsDep, StoreDep, session_or_404
from ..errors import error_responses, refuse_invalid_config, refuse_unstorable
from ..sessions import SessionBusy, SessionConflict, SessionGone
from ..store import QueueFull


def _conflict(exc: SessionConflict) -> HTTPException:
    if isinstance(exc, SessionBusy):
        return HTTPException(409, str(exc), headers={"Retry-After": "1"})
    return HTTPException(409, str(exc))


def router(session_create: type) -> APIRouter:
    """The sessions routes of one app; `session_create` is its SessionCreate model."""
    r = APIRouter()

    async def create_session(body: session_create, response: Response, store: StoreDep,
                             sessions: SessionsDep, settings: SettingsDep):
        """A TMOC session whose real world is an external robot. With `observation`, its
        first episode starts at once and `next` is the first action to execute."""
        spec = S.spec_body(body, exclude={"observation"})
        refuse_invalid_config(spec)
        refuse_unstorable(spec, settings.max_stored_steps)
        initial = body.observation.model_dump(mode="json") if body.observation is not None else None
        try:
            session_id, nxt = await run_in_threadpool(sessions.create, spec, initial)
        except QueueFull as exc:
            raise HTTPException(429, f"max_sessions: {exc.queued} sessions are active, this "
                                     f"server's limit is {exc.limit} (--max-sessions); a session "
                                     f"idle for {sessions.idle_s:g} s (--session-idle-s) stops "
                                     "counting, or close one with DELETE /v1/sessions/{id}",
                                headers={"Retry-After": "30"}) from None
        except SessionConflict as exc:
            raise _conflict(exc) from None
        response.headers["Location"] = f"/v1/sessions/{session_id}"
        return {**views.session_view(session_or_404(store, session_id)), "next": nxt}

    r.add_api_route("/sessions", create_session, methods=["POST"], status_code=201,
                    response_model=S.SessionCreated, tags=["sessions"],
                    responses=error_responses(409, 413, 429))
    r.include_router(routes)
    return r


routes = APIRouter()


@routes.get("/sessions", response_model=S.SessionList, tags=["sessions"])
async def list_sessions(store: StoreDep, limit: Annotated[int, Query(ge=1, le=200)] = 50,
                        offset: Annotated[int, Query(ge=0, le=10**9)] = 0):
    rows, total = store.list_sessions(limit, offset)
    items, skipped = views.shown(rows, views.session_view, S.SessionView)
    return views.page(items, total, limit, offset, skipped)


@routes.get("/sessions/{session_id}", response_model=S.SessionView, tags=["sessions"],
            responses=error_responses(404))
async def get_session(session_id: SessionId, store: StoreDep):
    return views.session_view(session_or_404(store, session_id))


@routes.delete("/sessions/{session_id}", response_model=S.SessionView, tags=["sessions"],
               responses=error_responses(404))
async def close_session(session_id: SessionId, store: StoreDep, sessions: SessionsDep):
    """Close the session: it frees its memory; its stored episodes stay readable."""
    status = await run_in_threadpool(sessions.close, session_id)
    if status is None:
        raise HTTPException(404, f"session {session_id!r}: no such session")
    return views.session_view(session_or_404(store, session_id))


@routes.post("/sessions/{session_id}/purge", response_model=S.PurgeView, tags=["sessions"],
             responses=error_responses(404, 409))
async def purge_session(session_id: SessionId, sessions: SessionsDep, built: ExportsDep):
    """Delete a closed or finished session's stored rows (the session, its episodes, step
    records and observations); 409 while it is active (close it first)."""
    return await exports.purged(sessions.purge, built, "session", session_id, "close")


async def _session_call(fn, *args):
    if fn.__self__.busy(args[0]):        # a SessionManager method; answered on the loop
        raise _conflict(SessionBusy(args[0], restoring=fn.__self__.restoring(args[0])))
    try:
        return await run_in_threadpool(fn, *args)
    except SessionGone:
        raise HTTPException(404, f"session {args[0]!r}: no such session") from None
    except SessionConflict as exc:
        raise _conflict(exc) from None


@routes.post("/sessions/{session_id}/episodes", status_code=201, response_model=S.EpisodeStarted,
             tags=["sessions"], responses=error_responses(404, 409, 413))
async def start_episode(session_id: SessionId, observation: S.InitialObservation,
                        sessions: SessionsDep):
    """Start the next episode from the robot's initial observation; returns the first step."""
    episode, nxt = await _session_call(sessions.start_episode, session_id,
                                       observation.model_dump(mode="json"))
    return {"session_id": session_id, "episode": episode, "next": nxt}


@routes.get("/sessions/{session_id}/next", response_model=S.NextView, tags=["sessions"],
            responses=error_responses(404, 409))
async def next_step(session_id: SessionId, sessions: SessionsDep):
    """The pending action: its key pose, the trajectory to execute (columns t, x, y, z,
    yaw, opening) and the expected symbolic state after it. 409 when no episode is in
    progress."""
    episode, nxt = await _session_call(sessions.next, session_id)
    return {"session_id": session_id, "episode": episode, "in_episode": True, "pending": nxt}


@routes.post("/sessions/{session_id}/observations", response_model=S.ObservationResult,
             tags=["sessions"], responses=error_responses(404, 409, 413))
async def observe(session_id: SessionId, observation: S.StepObservation, sessions: SessionsDep):
    """What the robot observed after executing the pending action: updates the belief
    and T, and returns the step's report and the next step. An observation that does not
    fit the pending action (none pending, another action, a configuration of another
    scene) gets a 409 and changes nothing."""
    return await _session_call(sessions.observe, session_id, observation.model_dump(mode="json"))


@routes.get("/sessions/{session_id}/export", tags=["sessions"], response_class=Response,
            responses={**exports.RESPONSES, **error_responses(404, 429)})
async def export_session(session_id: SessionId, store: StoreDep, built: ExportsDep):
    """Every step the robot took in this session (action, commanded trajectory, observed
    configurations, measurements, outcome, belief) as MCAP (``tmoc export``), streamed as
    it is written; 429 while too many exports are being built."""
    row = session_or_404(store, session_id)
    return await exports.serve(built, store, session_id, "session", row["spec"])


@routes.get("/sessions/{session_id}/belief", response_model=S.BeliefView, tags=["sessions"],
            responses=error_responses(404))
async def session_belief(session_id: SessionId, store: StoreDep):
    """The session's posterior over the block size, now (updated at every observation)."""
    row = session_or_404(store, session_id, belief=True)
    return views.belief_view(session_id, row["spec"], row.get("belief"),
                             row.get("posterior") or {}, row["episodes_done"], None)


@routes.get("/sessions/{session_id}/curve", response_model=S.CurveView, tags=["sessions"],
            responses=error_responses(404))
async def session_curve(session_id: SessionId, store: StoreDep):
    row = session_or_404(store, session_id)
    records = [json.loads(r) for _, r in store.episodes(session_id)]
    return {"run_id": session_id, "agent": row["spec"]["agent"], "true_size": None,
            "points": views.curve_points(records)}


__all__ = ["router", "routes"]
