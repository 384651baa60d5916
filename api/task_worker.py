"""The task worker: one thread that runs queued tasks one at a time, in submission order,
with ``coordinator.loop.runner.run``.

Every episode boundary stores the episode record and the run's checkpoint in one SQLite
transaction; cancellation and shutdown stop a run before its next action (the episode
under way is dropped: the run stays at its last episode boundary)
(``should_stop``). After a restart, interrupted runs resume from their checkpoint and
queued tasks run.
"""
from __future__ import annotations

import logging
import sqlite3
import threading
import time
import traceback
from contextlib import nullcontext

from coordinator.agents import agent_spec
from coordinator.distributed.shard_pools import ShardPools

from .notify import Notifier
from .schemas import run_config
from .store import Store

log = logging.getLogger("tmoc.api")


class TaskWorker:
    """Runs tasks one at a time, in the order queued, on a background thread."""

    def __init__(self, store: Store, shard_pools: ShardPools, notifier: Notifier,
                 stall_s: float = 3600.0, max_frames: int = 48,
                 max_runtime_s: float = 3600.0) -> None:
        self.store = store
        self.max_runtime_s = max_runtime_s    # a task's budget at most (`tmoc serve --max-task-runtime-s`)
        self.max_frames = max_frames          # scene pictures kept per task (0: none rendered)
        self.shard_pools = shard_pools
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
        """Ask the running task to stop before its next action (it stays `running`
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
        from coordinator.engines import installed

        # (pictures are pybullet's: a server without it renders none, whatever the spec says)
        if not spec.get("frames", True) or self.max_frames <= 0 or not installed("pybullet"):
            return None
        from .frames import StoreFrameSink

        return StoreFrameSink(self.store, task_id, self.max_frames)

    def _run(self, task_id: str) -> None:
        from coordinator.loop.runner import run

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
        budget = _Budget(row["spec"].get("max_runtime_s"), self.max_runtime_s, resume)

        def on_episode(record: dict, session, checkpoint: dict) -> None:
            self.beat()
            checkpoint[_Budget.KEY] = budget.spent()
            belief = session.belief.summary() if session.belief is not None else None
            self.store.record_episode(task_id, record, checkpoint, belief, session.transition_table(),
                                      steps=session.step_records)
            self._nodes[task_id] = checkpoint.get("nodes", [])
            self.notifier.notify(task_id)

        def should_stop() -> bool:
            self.beat()
            return task_id in self._cancel or self._stopping.is_set() or budget.over()

        lease = (self.shard_pools.lease(config.scene) if learns
                 else nullcontext())
        try:
            with lease as pool:
                if should_stop():
                    result = None
                else:
                    result = run(config, on_episode=on_episode, resume=resume, should_stop=should_stop,
                                 pool=pool, frames=self._frames_sink(task_id, row["spec"]))
        except sqlite3.Error:
            raise                         # storage, not the task: retried, resumes
        except Exception as exc:
            if self._stopping.is_set():
                return                    # shutting down: resume from the checkpoint later
            log.error("task %s failed\n%s", task_id, traceback.format_exc())
            self.store.finish_task(task_id, "failed", error=f"{type(exc).__name__}: {exc}")
            return
        done = self.store.task_status(task_id)[1]
        if done >= config.episodes:
            summary = {"summary": result["summary"], "runtime": result["runtime"]} if result else None
            self.store.finish_task(task_id, "succeeded", result=summary)
        elif task_id in self._cancel or self.store.get_task(task_id)["cancel_requested"]:
            self.store.finish_task(task_id, "cancelled")
        elif budget.over():
            self.store.finish_task(task_id, "failed", error=(
                f"budget: the task ran past its max_runtime_s of {budget.limit:g} s after {done} of "
                f"{config.episodes} episodes (the finished episodes are kept; the one under way "
                "was dropped)"))
        elif not self._stopping.is_set():  # pragma: no cover - run() ends early only when told
            self.store.finish_task(task_id, "failed", error=f"stopped after {done} episodes")
        # else: stopped by shutdown; it stays `running` and resumes after a restart.
        self._cancel.discard(task_id)


class _Budget:
    """A task's running time against its `max_runtime_s` (capped by the server's). The time
    spent before a restart travels in the checkpoint (as of the last finished episode), so a
    task cannot outlive its budget by being interrupted."""

    KEY = "task_runtime_s"

    def __init__(self, asked: float | None, cap: float, resume: dict | None) -> None:
        self.limit = min(float(asked), cap) if asked is not None else cap
        before = (resume or {}).get(self.KEY, 0.0)
        self.before = float(before) if isinstance(before, (int, float)) else 0.0
        self.t0 = time.monotonic()

    def spent(self) -> float:
        return self.before + time.monotonic() - self.t0

    def over(self) -> bool:
        return self.spent() > self.limit


__all__ = ["TaskWorker"]
