"""External-robot sessions (:class:`SessionManager`).

Every call that plans or simulates runs in a thread (the routes ``await`` it), serialised
per session by a lock. A session is persisted as its checkpoint at the last episode
boundary plus the observations of the current episode; after a restart it is rebuilt by
replaying them (deterministic: same seeds, same shard results), so it resumes exactly
where it was.
"""
from __future__ import annotations

import json
import logging
import threading
import time
import weakref
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from coordinator.loop.observations import ObservationError, from_canonical, parse_observation
from coordinator.loop.reality import Observation
from coordinator.distributed.shard_pools import ShardPools

from .schemas import run_config
from .store import Store, new_id

log = logging.getLogger("tmoc.api")


class SessionConflict(Exception):
    """The request does not fit the session's state (HTTP 409); nothing was changed."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class SessionBusy(SessionConflict):
    """Another request holds the session (a step in progress): HTTP 409 with Retry-After,
    at once or after at most LOCK_WAIT_S, never a pool thread parked behind the step."""

    def __init__(self, session_id: str, restoring: bool = False) -> None:
        super().__init__(f"session {session_id!r}: " + (
            "being restored after a restart (its episode is replayed)" if restoring
            else "a step is in progress") + "; retry in a moment")


class ReplayStopped(SessionBusy):
    """The server began to stop during a session's replay: it ends at its next step, and
    the next start replays the episode again (nothing stored changes)."""

    def __init__(self, session_id: str) -> None:
        super().__init__(session_id, restoring=True)


# How long a request waits for a session another request holds (a pool thread waits
# meanwhile: issue 25, 45 GETs of /next behind one 256-particle step used up all 40).
LOCK_WAIT_S = 0.25


class SessionGone(Exception):
    """Unknown session id (HTTP 404)."""


@dataclass
class LiveSession:
    id: str
    spec: dict
    session: object                      # coordinator.loop.session.Session
    step: int = 0                        # observations in the current episode
    status: str = "active"
    last_reply: dict | None = None       # {step_id, action, observation, reply} of the last step
    lock: threading.Lock | None = field(default=None, repr=False)   # keeps the weak entry alive
    used: float = field(default_factory=time.monotonic)            # last request (monotonic s)


class SessionManager:
    """External-robot sessions, kept in memory and mirrored to the store."""

    def __init__(self, store: Store, shard_pools: ShardPools, max_active: int,
                 idle_s: float = float("inf"), stopping: threading.Event | None = None) -> None:
        self.store = store
        # Set when the server stops: a replay under way ends at its next step (issue 38 row
        # 11: a SIGTERM during the start-up restore waited 7-11 s for it).
        self.stopping = stopping if stopping is not None else threading.Event()
        self.shard_pools = shard_pools
        self.max_active = max_active
        self.idle_s = idle_s          # then a session leaves memory and the max_active count
        self._live: dict[str, LiveSession] = {}
        # Weak: a lock lives while a request holds it or its live session does, so ids that
        # were only asked about (unknown ones included) leave nothing behind.
        self._locks: "weakref.WeakValueDictionary[str, threading.Lock]" = weakref.WeakValueDictionary()
        self._guard = threading.Lock()
        self._restoring: set[str] = set()      # sessions the restore thread replays now

    # -- helpers ---------------------------------------------------------------------
    def _lock_for(self, session_id: str) -> threading.Lock:
        with self._guard:
            lock = self._locks.get(session_id)
            if lock is None:
                lock = threading.Lock()
                self._locks[session_id] = lock
            return lock

    @contextmanager
    def _locked(self, session_id: str):
        """The session's lock, waited for at most LOCK_WAIT_S (SessionBusy after)."""
        lock = self._lock_for(session_id)
        if not lock.acquire(timeout=LOCK_WAIT_S):
            raise SessionBusy(session_id, restoring=session_id in self._restoring)
        try:
            yield lock
        finally:
            lock.release()

    def busy(self, session_id: str) -> bool:
        """Whether a request holds the session now (read on the event loop, no thread)."""
        with self._guard:
            lock = self._locks.get(session_id)
        return lock is not None and lock.locked()

    def restoring(self, session_id: str) -> bool:
        """Whether the start-up restore is replaying this session now."""
        return session_id in self._restoring

    def held_locks(self) -> int:
        """Per-session locks alive now (for the soak test: must not grow with traffic)."""
        with self._guard:
            return len(self._locks)

    def live_count(self) -> int:
        return len(self._live)

    @staticmethod
    def step_id(live: LiveSession, episode: int, step: int) -> str:
        """Unique to the session, the episode and the step: another session's pending step
        of the same action has another id."""
        return f"{live.id}:{episode}:{step}"

    def _step_view(self, live: LiveSession, step) -> dict | None:
        if step is None:
            return None
        d = step.to_dict()
        d.update(episode=live.session.episode, step=live.step,
                 step_id=self.step_id(live, live.session.episode, live.step))
        return d

    @staticmethod
    def observation(live: LiveSession, body: dict) -> tuple[Observation, dict]:
        """An Observation for this session's scene from a request body (read and checked by
        the domain); raises SessionConflict naming the field when it does not fit the scene."""
        s = live.session
        try:
            return parse_observation(s.domain, s.task, s.n_blocks, body, s.robot)
        except ObservationError as exc:
            raise SessionConflict(str(exc), exc.field) from None

    def _next(self, live: LiveSession) -> dict | None:
        """The pending step (planned if needed). Planning errors come from the observed
        state (the robot's world), so they are a conflict, not a server error. Planned
        without particle worlds: a robot session's pose of a split belief is its heaviest
        mode's (the run's candidate simulation, issue 37, would lease a shard pool on every
        plan); a restored session replays its plans the same way (`_load`)."""
        try:
            return self._step_view(live, live.session.next_step())
        except ValueError as exc:
            raise SessionConflict(f"observation: cannot plan from the observed state: {exc}",
                                  "observation") from None

    def _first(self, live: LiveSession) -> dict | None:
        """An episode's first step: as ``_next``, but with the worlds lent where the session
        makes a counterfactual snapshot before its first plan (``counterfactual_rows``)."""
        if live.session.config.counterfactual_rows > 0:
            return self._with_pool(live, lambda: self._next(live))
        return self._next(live)

    def _with_pool(self, live: LiveSession, fn):
        """fn() with a shard pool lent to the session (none needed without a belief)."""
        s = live.session
        if s.belief is None:
            return fn()
        with (self.shard_pools.lease(s.config.scene) as pool,
              s.using_shard_pool(pool)):
            return fn()

    def _belief(self, live: LiveSession) -> dict | None:
        b = live.session.belief
        return b.summary() if b is not None else None

    # -- loading ---------------------------------------------------------------------
    def _load(self, session_id: str) -> LiveSession:
        """The live session (rebuilt from the store after a restart). Call under its lock."""
        live = self._live.get(session_id)
        if live is not None:
            return live
        status = self.store.session_status(session_id)
        if status is None:
            raise SessionGone(session_id)
        if status == "closed":                     # nothing to rebuild for a closed session
            raise SessionConflict("session is closed", "session")
        row = self.store.get_session(session_id, checkpoint=True)
        if row is None:  # pragma: no cover - deleted between the two reads
            raise SessionGone(session_id)
        from coordinator.loop.session import Session

        session = Session.from_checkpoint(row["checkpoint"])
        live = LiveSession(session_id, row["spec"], session, status=row["status"],
                           last_reply=row.get("last_reply"), lock=self._lock_for(session_id))
        if row["status"] == "active" and row["episode_start"] is not None:
            steps = self.store.session_steps(session_id, session.episode)

            def replay() -> None:
                def plan() -> None:             # as `_next` planned it: without the worlds
                    with session.using_shard_pool(None):
                        session.next_step()

                session.start_episode(from_canonical(row["episode_start"]))
                if session.config.counterfactual_rows > 0:      # as `_first` planned it
                    session.next_step()
                else:
                    plan()
                for obs in steps:
                    if self.stopping.is_set():
                        raise ReplayStopped(session_id)
                    session.observe(from_canonical(obs))
                    live.step += 1
                    plan()

            try:
                self._with_pool(live, replay)
            except Exception:
                if self.stopping.is_set():     # its pool closed or its shards killed under it
                    raise ReplayStopped(session_id) from None
                raise
        self._live[session_id] = live
        return live

    def restore(self, stopping: threading.Event | None = None) -> int:
        """Rebuild, after a restart, every session that was in the middle of an episode
        (oldest first), each under its lock; returns how many. Run on a thread at start-up:
        a replay costs the episode's simulations again (22 s at 128 particles and 6 steps,
        issue 25), so the first request must not pay for it past the client's timeout.
        Meanwhile requests to a session get 409 "being restored" with Retry-After. Idle
        sessions (`idle_s`) are left to the request that brings their robot back."""
        stopping = stopping or self.stopping
        done = 0
        for session_id in self.store.sessions_to_restore(self.idle_s):
            if stopping.is_set() or self.stopping.is_set():
                break
            self._restoring.add(session_id)
            try:
                with self._lock_for(session_id):
                    self._load(session_id)
                done += 1
            except ReplayStopped:
                log.info("session %s: restore stopped (the server is stopping)", session_id)
                break
            except Exception as exc:        # left to the first request, which reports it
                log.warning("session %s: restore failed (%s: %s)", session_id, type(exc).__name__, exc)
            finally:
                self._restoring.discard(session_id)
        return done

    def _replays(self, session_id: str) -> bool:
        """Whether rebuilding the session replays observed steps (not only an episode start)."""
        row = self.store.get_session(session_id)
        return bool(row is not None and row["status"] == "active" and row["in_episode"] and row["step"] > 0)

    def _restore_one(self, session_id: str) -> None:
        """Rebuild one session on this thread (added to `_restoring` by the caller)."""
        try:
            with self._lock_for(session_id):
                self._load(session_id)
        except ReplayStopped:
            log.info("session %s: replay stopped (the server is stopping)", session_id)
        except Exception as exc:  # noqa: BLE001 - left to the next request, which reports it
            log.warning("session %s: replay failed (%s: %s)", session_id, type(exc).__name__, exc)
        finally:
            self._restoring.discard(session_id)

    def evict_forever(self, stopping: threading.Event) -> None:
        """Drop idle sessions from memory on a timer (issue 38: only a new session's
        creation did, so an idle server kept them all)."""
        every = max(1.0, min(60.0, self.idle_s / 2))
        while not stopping.wait(every):
            try:
                self._evict_idle()
            except Exception:  # noqa: BLE001 - try again next time
                log.exception("idle eviction failed")

    def _evict_idle(self) -> None:
        """Drop from memory the live sessions unused for `idle_s` that no request holds;
        the store keeps them (the next request rebuilds one, replaying its episode)."""
        cutoff = time.monotonic() - self.idle_s
        for sid, live in list(self._live.items()):
            if live.used < cutoff and live.lock is not None and live.lock.acquire(blocking=False):
                try:
                    if live.used < cutoff:
                        self._live.pop(sid, None)
                finally:
                    live.lock.release()

    def _get(self, session_id: str) -> LiveSession:
        """The live session, for a request under its lock. One that must be rebuilt by
        replaying observed steps (its robot came back after `idle_s`) is replayed on a thread
        of its own, like a restart's, and this request gets SessionBusy (409 "being
        restored", Retry-After) at once: issue 38, the first request waited for the whole
        replay (4.9 s for 4 steps x 64 particles; minutes at 512)."""
        if session_id in self._restoring:
            raise SessionBusy(session_id, restoring=True)
        if session_id not in self._live and self._replays(session_id):
            self._restoring.add(session_id)
            threading.Thread(target=self._restore_one, args=(session_id,), name=f"tmoc-replay-{session_id}",
                             daemon=True).start()
            raise SessionBusy(session_id, restoring=True)
        live = self._load(session_id)
        live.used = time.monotonic()
        if live.status == "closed":
            raise SessionConflict("session is closed", "session")
        return live

    # -- operations (blocking: call them in a thread) --------------------------------
    def create(self, spec: dict, initial: dict | None) -> tuple[str, dict | None]:
        from coordinator.loop.session import Session

        config = run_config(spec)
        session = Session(config)
        session_id = new_id("s")
        live = LiveSession(session_id, spec, session, lock=self._lock_for(session_id))
        checkpoint = session.to_checkpoint()
        mirror: dict = {"posterior": session.posterior(), "belief": self._belief(live)}
        nxt = None
        if initial is not None:
            obs, canonical = self.observation(live, initial)
            if live.session.task.is_goal(obs.state):
                raise SessionConflict("observation: every block is already delivered; nothing to do",
                                      "observation")
            session.start_episode(obs)
            nxt = self._first(live)
            mirror.update(episode_start=canonical, pending=nxt)
        with live.lock:
            self.store.create_session(session_id, spec, checkpoint, mirror, self.max_active, self.idle_s)
            self._live[session_id] = live
        self._evict_idle()
        return session_id, nxt

    def start_episode(self, session_id: str, initial: dict) -> tuple[int, dict | None]:
        with self._locked(session_id):
            live = self._get(session_id)
            s = live.session
            if live.status == "finished" or s.episode >= s.config.episodes:
                raise SessionConflict(f"session finished: all {s.config.episodes} episodes done",
                                      "episodes")
            if self._in_episode(live):
                raise SessionConflict(f"episode {s.episode} is in progress (step {live.step}); "
                                      "post its observations first", "episode")
            obs, canonical = self.observation(live, initial)
            if live.session.task.is_goal(obs.state):
                raise SessionConflict("observation: every block is already delivered; nothing to do",
                                      "observation")
            s.start_episode(obs)
            live.step = 0
            try:
                nxt = self._first(live)
                self.store.session_start_episode(session_id, canonical, nxt)
            except Exception:
                self._live.pop(session_id, None)         # rebuilt from the store next time
                raise
            return s.episode, nxt

    @staticmethod
    def _in_episode(live: LiveSession) -> bool:
        s = live.session
        return s.observation is not None and not s.episode_done()

    @staticmethod
    def _why_idle(live: LiveSession) -> str:
        s = live.session
        if live.status == "finished" or s.episode >= s.config.episodes:
            return f"session finished: all {s.config.episodes} episodes are done"
        return ("no episode in progress: POST /v1/sessions/{id}/episodes with the robot's "
                "initial observation")

    def next(self, session_id: str) -> tuple[int, dict | None]:
        with self._locked(session_id):
            live = self._get(session_id)
            s = live.session
            if not self._in_episode(live):
                raise SessionConflict(self._why_idle(live), "episode")
            pending_before = s.pending
            nxt = self._next(live)
            if pending_before is None:
                self.store.session_set_pending(session_id, nxt)
            return s.episode, nxt

    def _replay(self, live: LiveSession, body: dict) -> dict | None:
        """The stored reply if `body` re-posts the last accepted observation (same step id,
        action and observation); None if it is not about that step; a conflict if it
        reuses that step's id with anything else."""
        last = live.last_reply
        if last is None or body["step_id"] != last["step_id"]:
            return None
        _, canonical = self.observation(live, body)
        same = (body["action"] == last["action"]
                and json.loads(json.dumps(canonical)) == last["observation"])
        if not same:
            raise SessionConflict(f"step_id: step {last['step_id']!r} was already observed with "
                                  "another observation; it cannot be observed twice", "step_id")
        return last["reply"]

    def observe(self, session_id: str, body: dict) -> dict:
        with self._locked(session_id):
            live = self._get(session_id)
            s = live.session
            replay = self._replay(live, body)
            if replay is not None:
                return replay
            if not self._in_episode(live):
                raise SessionConflict(self._why_idle(live), "episode")
            if s.pending is None:
                raise SessionConflict("no pending step: GET /v1/sessions/{id}/next first", "action")
            pending_id = self.step_id(live, s.episode, live.step)
            if body["step_id"] != pending_id:
                raise SessionConflict(f"step_id: observation answers step {body['step_id']!r}, the "
                                      f"pending step is {pending_id!r}", "step_id")
            if body["action"] != s.pending.action:
                raise SessionConflict(f"action: observation answers {body['action']!r}, the pending "
                                      f"action is {s.pending.action!r}", "action")
            obs, canonical = self.observation(live, body)
            episode, step = s.episode, live.step
            try:
                report = self._with_pool(live, lambda: s.observe(obs))
                live.step += 1
                record = report.pop("episode", None)
                nxt = None if record is not None else self._next(live)
                report = _jsonable(report)
                finished = record is not None
                status = "active"
                if finished and s.episode >= s.config.episodes:
                    status = "finished"
                    live.status = status
                reply = {"session_id": session_id, "report": report, "episode_done": finished,
                         "episode": _jsonable(record) if finished else None, "next": nxt,
                         "posterior": s.posterior()}
                last = {"step_id": pending_id, "action": body["action"],
                        "observation": json.loads(json.dumps(canonical)),
                        "reply": json.loads(json.dumps(reply))}
                self.store.session_record_step(
                    session_id, episode, step, canonical, report, pending=nxt,
                    posterior=s.posterior(), belief=self._belief(live),
                    finished=_jsonable(record) if finished else None,
                    checkpoint=s.to_checkpoint() if finished else None, status=status,
                    last_reply=last, step_record=s.step_records[-1] if s.step_records else None)
                live.last_reply = last
            except Exception:
                self._live.pop(session_id, None)         # rebuilt from the store: unchanged
                raise
            return reply

    def close(self, session_id: str) -> str | None:
        with self._lock_for(session_id):
            status = self.store.close_session(session_id)
            live = self._live.pop(session_id, None)
            if live is not None:
                live.status = "closed"
            return status


    def purge(self, session_id: str) -> tuple[str, dict[str, int]] | None:
        """Delete a closed or finished session's stored rows and forget it (``Store.purge_session``)."""
        with self._lock_for(session_id):
            out = self.store.purge_session(session_id)
            if out is not None and out[1]:
                self._live.pop(session_id, None)
            return out


def _jsonable(value):
    """Plain JSON types (numpy scalars/arrays and tuples converted)."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


__all__ = ["LiveSession", "SessionConflict", "SessionGone", "SessionManager"]
