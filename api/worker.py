"""The work inside the server process, off the event loop.

- :class:`PoolManager`: the process's Ray driver (started lazily, on first need) and the
  shard pools shared by every task and session (one pool per scene: domain and block
  count; each actor reserves a fraction of a CPU so several scenes can coexist).
- :class:`TaskWorker`: one thread that runs queued tasks one at a time, in submission
  order, with ``coordinator.runner.run``; every episode boundary stores the episode record
  and the run's checkpoint in one SQLite transaction; cancellation and shutdown stop a run
  at the next episode boundary (``should_stop``). After a restart, interrupted runs resume
  from their checkpoint and queued tasks run.
- :class:`SessionManager`: external-robot sessions. Every call that plans or simulates
  runs in a thread (the routes ``await`` it), serialised per session by a lock. A session
  is persisted as its checkpoint at the last episode boundary plus the observations of the
  current episode; after a restart it is rebuilt by replaying them (deterministic: same
  seeds, same shard results), so it resumes exactly where it was.
- :class:`Notifier`: wakes the event streams of a task when its worker stores something.
"""
from __future__ import annotations

import asyncio
import json
import logging
import sqlite3
import threading
import time
import traceback
import uuid
import weakref
from dataclasses import dataclass, field

import numpy as np

from coordinator.agents import agent as agent_spec
from coordinator.domains import measurement_channels
from coordinator.reality import Observation
from coordinator.run_config import RunConfig, stored_run_config
from sim_workers.configuration import Configuration

from .store import QueueFull, Store

log = logging.getLogger("tmoc.api")

MAX_POOLS = 4


def new_id(prefix: str) -> str:
    return f"{prefix}_{uuid.uuid4().hex[:20]}"


# Channels read from the sensors during an action (issue 14), last in a domain's vector.
SENSED_CHANNELS = ("held_weight", "grasp_width")


def run_config(spec: dict) -> RunConfig:
    """The RunConfig of a stored task or session spec (service-only fields dropped)."""
    fields = {k: v for k, v in spec.items() if k in RunConfig.model_fields}
    fields["shards"] = None
    return stored_run_config(fields)


# ----------------------------------------------------------------------------- Ray pools
class PoolManager:
    """The Ray driver and the shared shard pools, created on first use."""

    def __init__(self, ray_address: str | None = None, n_shards: int | None = None,
                 max_pools: int = MAX_POOLS) -> None:
        self.ray_address = ray_address
        self.n_shards = n_shards
        self.max_pools = max_pools
        self._cond = threading.Condition()
        self._pools: dict[tuple, object] = {}
        self._users: dict[tuple, int] = {}
        self._last_used: dict[tuple, float] = {}
        self._ray_lock = threading.Lock()
        self._ray_thread: threading.Thread | None = None
        self._ray_ready = threading.Event()
        self._ray_stop = threading.Event()
        self._ray_error: Exception | None = None
        self.ray_status = "not started"
        self.on_ray_ready = None          # called (from the initialising thread) after ray.init

    def ensure_ray(self, timeout: float = 180.0) -> None:
        """Start (once) or wait for the process's Ray driver.

        Ray is started on a thread of its own that lives as long as the process: the
        processes ``ray.init`` starts die with the *thread* that started them (Linux's
        parent-death signal is per thread), and the request threads that first need Ray
        are recycled after 10 s idle (measured: the server hung ~59 s, then exited, on
        the first request after the starting thread went away).
        """
        with self._ray_lock:
            import ray

            if ray.is_initialized() and self.ray_status == "ready":
                return
            if self._ray_thread is None or not self._ray_thread.is_alive():
                self._ray_ready.clear()
                self._ray_error = None
                self.ray_status = "starting"
                self._ray_thread = threading.Thread(target=self._own_ray, name="tmoc-ray-driver",
                                                    daemon=True)
                self._ray_thread.start()
        if not self._ray_ready.wait(timeout):
            raise RuntimeError(f"ray: not ready after {timeout:.0f} s")
        if self._ray_error is not None:
            raise self._ray_error

    def _own_ray(self) -> None:
        """The thread that starts Ray, then keeps it alive until close()."""
        from coordinator.fanout import init_ray

        try:
            init_ray(self.ray_address)
        except Exception as exc:
            self._ray_error = exc
            self.ray_status = f"error: {exc}"
            self._ray_ready.set()
            return                         # the next ensure_ray() tries again
        self.ray_status = "ready"
        self._ray_ready.set()
        if self.on_ray_ready is not None:
            self.on_ray_ready()
        self._ray_stop.wait()
        try:
            import ray

            ray.shutdown()
        except Exception:  # pragma: no cover - Ray already gone
            pass
        self.ray_status = "stopped"

    @staticmethod
    def _key(domain: str, n_blocks: int, options: dict | None) -> tuple:
        return (domain, int(n_blocks), tuple(sorted((options or {}).items())))

    def acquire(self, domain: str, n_blocks: int, options: dict | None = None):
        """The shared pool of this scene (created if needed; one per domain, block count
        and domain options, since the options reach every world); pair with release()."""
        key = self._key(domain, n_blocks, options)
        self.ensure_ray()
        with self._cond:
            while key not in self._pools and len(self._pools) >= self.max_pools:
                idle = [k for k in self._pools if self._users[k] == 0]
                if idle:
                    victim = min(idle, key=lambda k: self._last_used[k])
                    self._pools.pop(victim).close()
                    del self._users[victim], self._last_used[victim]
                else:
                    self._cond.wait(timeout=1.0)
            fresh = key not in self._pools
            if fresh:
                from coordinator.fanout import ShardPool

                self._pools[key] = ShardPool(domain, {"n_blocks": int(n_blocks), **(options or {})},
                                             self.n_shards,
                                             num_cpus=1.0 / self.max_pools)
                self._users[key] = 0
            self._users[key] += 1
            self._last_used[key] = time.monotonic()
            pool = self._pools[key]
        if not fresh:
            # Nodes may have joined (or left) since this pool was planned: each task (and
            # session step) starts with one shard per CPU of the cluster as it is now.
            try:
                added = pool.refresh()
            except Exception:
                self.release(domain, n_blocks, options)
                raise
            if added:
                log.info("pool %s: %d shards added (cluster grew), %d in all", key, added,
                         len(pool.actors))
        return pool

    def release(self, domain: str, n_blocks: int, options: dict | None = None) -> None:
        key = self._key(domain, n_blocks, options)
        with self._cond:
            if key in self._users:
                self._users[key] = max(0, self._users[key] - 1)
                self._last_used[key] = time.monotonic()
            self._cond.notify_all()

    def close(self) -> None:
        with self._cond:
            for pool in self._pools.values():
                try:
                    pool.close()
                except Exception:  # pragma: no cover - Ray already down
                    pass
            self._pools.clear()
            self._users.clear()
        self._ray_stop.set()                 # the owner thread shuts Ray down
        if self._ray_thread is not None:
            self._ray_thread.join(timeout=30)


# ----------------------------------------------------------------------------- notifier
class Notifier:
    """Thread-safe wake-ups for the event streams (asyncio events on the server's loop)."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self._subs: dict[str, set[asyncio.Event]] = {}

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    def subscribe(self, key: str) -> asyncio.Event:
        ev = asyncio.Event()
        self._subs.setdefault(key, set()).add(ev)
        return ev

    def unsubscribe(self, key: str, ev: asyncio.Event) -> None:
        subs = self._subs.get(key)
        if subs is not None:
            subs.discard(ev)
            if not subs:
                self._subs.pop(key, None)

    def _wake(self, key: str) -> None:
        for ev in list(self._subs.get(key, ())):
            ev.set()

    def notify(self, key: str) -> None:
        loop = self.loop
        if loop is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(self._wake, key)
        except RuntimeError:  # loop closed meanwhile
            pass


# ----------------------------------------------------------------------------- tasks
class TaskWorker:
    """Runs tasks one at a time, in the order queued, on a background thread."""

    def __init__(self, store: Store, pools: PoolManager, notifier: Notifier,
                 stall_s: float = 3600.0, max_frames: int = 48) -> None:
        self.store = store
        self.max_frames = max_frames          # scene pictures kept per task (0: none rendered)
        self.pools = pools
        self.notifier = notifier
        self._wake = threading.Event()
        self._cancel: set[str] = set()
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None
        self.current: str | None = None
        self._nodes: dict[str, list[dict]] = {}   # running task -> nodes that ran its particles
        self.stall_s = stall_s
        self._beat = time.monotonic()
        self._errors = 0
        self._last_error: str | None = None

    def nodes_of(self, task_id: str) -> list[dict] | None:
        """The Ray nodes that ran a running task's particles so far (as of its last episode)."""
        return self._nodes.get(task_id)

    def start(self) -> None:
        self._thread = threading.Thread(target=self._loop, name="tmoc-task-worker", daemon=True)
        self._thread.start()

    def submit(self, task_id: str) -> None:
        """A task was stored as queued: wake the worker (the store is the queue)."""
        self._wake.set()

    def cancel(self, task_id: str) -> None:
        self._cancel.add(task_id)

    def stop(self, timeout: float) -> bool:
        """Ask the running task to stop at its next episode boundary (it stays `running`
        in the store and resumes from its checkpoint after a restart); wait `timeout`."""
        self._stopping.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
            return not self._thread.is_alive()
        return True

    # -- health ------------------------------------------------------------------------
    def health(self) -> dict:
        """The worker's state for /health: `ok` is False when the thread is dead, backing
        off after storage errors, or has not beaten for `stall_s` seconds."""
        alive = self._thread is not None and self._thread.is_alive()
        quiet = time.monotonic() - self._beat
        if not alive:
            state = "stopped" if self._stopping.is_set() else "dead"
        elif self._errors:
            state = "retrying"
        elif quiet > self.stall_s:
            state = "stalled"
        else:
            state = "running" if self.current else "idle"
        return {"state": state, "ok": state in ("idle", "running"),
                "last_error": self._last_error, "consecutive_errors": self._errors,
                "last_beat_s": round(quiet, 1)}

    def beat(self) -> None:
        self._beat = time.monotonic()

    def _loop(self) -> None:
        # The store is the queue: an interrupted run first (only after a restart is a task
        # `running` while this thread looks for work), then queued tasks in submission order.
        # A storage error never ends this thread: it backs off (0.5 s doubling to 30 s) and
        # tries again; an interrupted task is `running` in the store, so it resumes from its
        # last checkpoint (its episodes are deterministic, so nothing changes but time).
        while not self._stopping.is_set():
            self.beat()
            try:
                task_id = self.store.next_runnable()
                if task_id is None:
                    self._errors = 0
                    self._wake.wait(timeout=2.0)
                    self._wake.clear()
                    continue
                self._run_guarded(task_id)
                self._errors = 0
            except Exception as exc:
                self._errors += 1
                self._last_error = f"{type(exc).__name__}: {exc}"
                delay = min(30.0, 0.5 * 2 ** (self._errors - 1))
                log.error("task worker: %s; retrying in %.1f s", self._last_error, delay)
                self._stopping.wait(delay)

    def _run_guarded(self, task_id: str) -> None:
        try:
            self._run(task_id)
        except sqlite3.Error:
            raise                                  # storage: back off, the task resumes
        except Exception as exc:  # pragma: no cover - a bug in the bookkeeping itself
            log.error("task %s: worker error\n%s", task_id, traceback.format_exc())
            if not self._stopping.is_set():
                self.store.finish_task(task_id, "failed", error=f"internal error: {exc!r}")
        finally:
            self.current = None
            self._nodes.pop(task_id, None)        # stored with the result by now
            self.notifier.notify(task_id)

    def _frames_sink(self, task_id: str, spec: dict):
        """Where the task's scene pictures go (None: the task or the server has them off)."""
        if not spec.get("frames", True) or self.max_frames <= 0:
            return None
        from .frames import StoreFrameSink

        return StoreFrameSink(self.store, task_id, self.max_frames)

    def _run(self, task_id: str) -> None:
        from coordinator.runner import run

        row = self.store.claim_task(task_id)
        if row is None:
            return                                       # cancelled while queued, or unknown
        self.current = task_id
        self.notifier.notify(task_id)
        if row["cancel_requested"]:
            self.store.finish_task(task_id, "cancelled")
            return
        try:
            config = run_config(row["spec"])
        except Exception as exc:
            self.store.finish_task(task_id, "failed", error=f"spec: {exc}")
            return
        learns = agent_spec(config.agent).learn_belief
        resume = row["checkpoint"]

        def on_episode(record: dict, session, checkpoint: dict) -> None:
            self.beat()
            belief = session.belief.summary() if session.belief is not None else None
            self.store.record_episode(task_id, record, checkpoint, belief, session.transition_table())
            self._nodes[task_id] = checkpoint.get("nodes", [])
            self.notifier.notify(task_id)

        def should_stop() -> bool:
            self.beat()
            return task_id in self._cancel or self._stopping.is_set()

        pool = None
        try:
            if learns:
                pool = self.pools.acquire(config.domain, config.n_blocks, config.options)
            if should_stop():
                result = None
            else:
                result = run(config, on_episode=on_episode, resume=resume,
                             should_stop=should_stop, pool=pool, frames=self._frames_sink(task_id, row["spec"]))
        except sqlite3.Error:
            raise                         # storage, not the task: retried, resumes
        except Exception as exc:
            if self._stopping.is_set():
                return                    # shutting down: resume from the checkpoint later
            log.error("task %s failed\n%s", task_id, traceback.format_exc())
            self.store.finish_task(task_id, "failed", error=f"{type(exc).__name__}: {exc}")
            return
        finally:
            if pool is not None:
                self.pools.release(config.domain, config.n_blocks, config.options)
        done = self.store.task_status(task_id)[1]
        if done >= config.episodes:
            summary = {"summary": result["summary"], "runtime": result["runtime"]} if result else None
            self.store.finish_task(task_id, "succeeded", result=summary)
        elif task_id in self._cancel or self.store.get_task(task_id)["cancel_requested"]:
            self.store.finish_task(task_id, "cancelled")
        elif not self._stopping.is_set():  # pragma: no cover - run() ends early only when told
            self.store.finish_task(task_id, "failed", error=f"stopped after {done} episodes")
        # else: stopped by shutdown; it stays `running` and resumes after a restart.
        self._cancel.discard(task_id)


# ----------------------------------------------------------------------------- sessions
class SessionConflict(Exception):
    """The request does not fit the session's state (HTTP 409); nothing was changed."""

    def __init__(self, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class SessionGone(Exception):
    """Unknown session id (HTTP 404)."""


@dataclass
class LiveSession:
    id: str
    spec: dict
    session: object                      # coordinator.session.Session
    step: int = 0                        # observations in the current episode
    status: str = "active"
    last_reply: dict | None = None       # {step_id, action, observation, reply} of the last step
    lock: threading.Lock | None = field(default=None, repr=False)   # keeps the weak entry alive


class SessionManager:
    """External-robot sessions, kept in memory and mirrored to the store."""

    def __init__(self, store: Store, pools: PoolManager, max_active: int) -> None:
        self.store = store
        self.pools = pools
        self.max_active = max_active
        self._live: dict[str, LiveSession] = {}
        # Weak: a lock lives while a request holds it or its live session does, so ids that
        # were only asked about (unknown ones included) leave nothing behind.
        self._locks: "weakref.WeakValueDictionary[str, threading.Lock]" = weakref.WeakValueDictionary()
        self._guard = threading.Lock()

    # -- helpers ---------------------------------------------------------------------
    def _lock_for(self, session_id: str) -> threading.Lock:
        with self._guard:
            lock = self._locks.get(session_id)
            if lock is None:
                lock = threading.Lock()
                self._locks[session_id] = lock
            return lock

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

    def observation(self, live: LiveSession, body: dict) -> tuple[Observation, dict]:
        """An Observation for this session's scene from a request body; raises
        SessionConflict naming the field when it does not fit the scene."""
        domain = live.session.domain
        task = live.session.task
        n_objects = len(domain.object_names)
        conf = body["configuration"]
        if len(conf["objects"]) != n_objects:
            raise SessionConflict(
                f"configuration.objects: {len(conf['objects'])} rows, this scene has {n_objects} "
                f"objects ({', '.join(domain.object_names)})", "configuration.objects")
        for i, row in enumerate(conf["objects"]):
            norm = float(np.linalg.norm(row[3:]))
            if abs(norm - 1.0) > 1e-2:
                raise SessionConflict(f"configuration.objects[{i}]: quaternion norm {norm:.4g}, "
                                      "expected a unit quaternion (x, y, z, w)", "configuration.objects")
        config = Configuration(np.array(conf["robot"], dtype=float), np.array(conf["objects"], dtype=float))
        if body.get("state") is not None:
            try:
                state = task.parse_state(body["state"])
            except ValueError as exc:
                raise SessionConflict(f"state: {exc}", "state") from None
            blocks = task.blocks(state)
            if len(blocks) != live.session.n_blocks:
                raise SessionConflict(f"state: names {len(blocks)} blocks, this scene has "
                                      f"{live.session.n_blocks}", "state")
        else:
            state = domain.symbolic_state(config)
        derived = domain.measurements(config)
        if body.get("measurements") is not None:
            # null: a channel the robot did not measure (e.g. the held weight after a stack)
            meas = np.array([np.nan if v is None else v for v in body["measurements"]], dtype=float)
            # Channels a robot does not report at the end (e.g. a client written before the
            # held weight and grasp width existed) are not measured: NaN, never a guess.
            n_sensed = sum(1 for c in measurement_channels(domain) if c["name"] in SENSED_CHANNELS)
            if derived.size - n_sensed <= meas.size < derived.size:
                meas = np.concatenate([meas, np.full(derived.size - meas.size, np.nan)])
            if meas.shape != derived.shape:
                names = ", ".join(c["name"] for c in measurement_channels(domain))
                raise SessionConflict(f"measurements: {meas.size} values, expected {derived.size} "
                                      f"({names})", "measurements")
        else:
            meas = derived
        canonical = {"configuration": config.to_dict(), "state": sorted(state),
                     "measurements": [None if np.isnan(v) else float(v) for v in meas]}
        return Observation(config, frozenset(state), meas), canonical

    def _next(self, live: LiveSession) -> dict | None:
        """The pending step (planned if needed). Planning errors come from the observed
        state (the robot's world), so they are a conflict, not a server error."""
        try:
            return self._step_view(live, live.session.next_step())
        except ValueError as exc:
            raise SessionConflict(f"observation: cannot plan from the observed state: {exc}",
                                  "observation") from None

    @staticmethod
    def _from_canonical(d: dict) -> Observation:
        return Observation(Configuration.from_dict(d["configuration"]), frozenset(d["state"]),
                           np.array([np.nan if v is None else v for v in d["measurements"]], dtype=float))

    def _with_pool(self, live: LiveSession, fn):
        s = live.session
        if s.belief is None:
            return fn()
        s.pool = self.pools.acquire(s.config.domain, s.n_blocks, s.config.options)
        try:
            return fn()
        finally:
            s.pool = None
            self.pools.release(s.config.domain, s.n_blocks, s.config.options)

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
        from coordinator.session import Session

        session = Session.from_checkpoint(row["checkpoint"])
        live = LiveSession(session_id, row["spec"], session, status=row["status"],
                           last_reply=row.get("last_reply"), lock=self._lock_for(session_id))
        if row["status"] == "active" and row["episode_start"] is not None:
            steps = self.store.session_steps(session_id, session.episode)

            def replay() -> None:
                session.start_episode(self._from_canonical(row["episode_start"]))
                session.next_step()
                for obs in steps:
                    session.observe(self._from_canonical(obs))
                    live.step += 1
                    session.next_step()

            self._with_pool(live, replay)
        self._live[session_id] = live
        return live

    def _get(self, session_id: str) -> LiveSession:
        live = self._load(session_id)
        if live.status == "closed":
            raise SessionConflict("session is closed", "session")
        return live

    # -- operations (blocking: call them in a thread) --------------------------------
    def create(self, spec: dict, initial: dict | None) -> tuple[str, dict | None]:
        from coordinator.session import Session

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
            nxt = self._next(live)
            mirror.update(episode_start=canonical, pending=nxt)
        with live.lock:
            self.store.create_session(session_id, spec, checkpoint, mirror, self.max_active)
            self._live[session_id] = live
        return session_id, nxt

    def start_episode(self, session_id: str, initial: dict) -> tuple[int, dict | None]:
        with self._lock_for(session_id):
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
                nxt = self._next(live)
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
        with self._lock_for(session_id):
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
        with self._lock_for(session_id):
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
                    last_reply=last)
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


__all__ = ["PoolManager", "Notifier", "TaskWorker", "SessionManager", "SessionConflict",
           "SessionGone", "QueueFull", "new_id", "run_config"]
