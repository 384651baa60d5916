"""The process's Ray driver and its shard pools, one per scene (:class:`ShardPools`).

A :class:`~coordinator.distributed.fanout.ShardPool` serves one scene (domain, block count, domain
options). A process that runs many tasks (the HTTP service) keeps the pools of the scenes
in use and shares them: ``acquire`` builds a scene's pool on first need (evicting the
least recently used idle one past ``max_pools``) and ``release`` hands it back; ``lease``
pairs the two. A process that runs one task (``tmoc run``, one run of an experiment) uses
the same class with ``max_pools=1``::

    with ShardPools(n_shards=0, max_pools=1, own_ray_thread=False) as shard_pools:
        with shard_pools.lease(Scene.of("container", 4)) as pool:
            pool.simulate(...)

"Shard pool" here: the simulation actors; not the experience pool of a session.
"""
from __future__ import annotations

import logging
import threading
import time
from contextlib import contextmanager
from typing import Iterator

from sim_workers.domains import Scene

from .fanout import ShardPool, init_ray

log = logging.getLogger("tmoc.shard_pools")

MAX_POOLS = 4


class PoolsClosed(RuntimeError):
    """A lease asked for after close(): the server is stopping."""


class ShardPools:
    """The Ray driver and the shard pools of the scenes in use, created on first use.

    With ``own_ray_thread`` (a server) Ray is started on a thread that lives until
    ``close()``, which shuts Ray down; without it (a command, a Ray task) Ray is joined from
    the calling thread as ``coordinator.distributed.fanout.init_ray`` does and ``close()`` leaves it up.
    Each shard actor reserves ``1 / max_pools`` CPU, so ``max_pools`` scenes fit at once;
    with ``n_shards=0`` a pool simulates in-process (Ray still names the node it ran on).
    """

    def __init__(self, ray_address: str | None = None, n_shards: int | None = None,
                 max_pools: int = MAX_POOLS, own_ray_thread: bool = True) -> None:
        self.ray_address = ray_address
        self.n_shards = n_shards
        self.max_pools = max_pools
        self.own_ray_thread = own_ray_thread
        self._cond = threading.Condition()
        self._pools: dict[Scene, ShardPool] = {}
        self._users: dict[tuple, int] = {}
        self._last_used: dict[tuple, float] = {}
        self._ray_lock = threading.Lock()
        self._ray_thread: threading.Thread | None = None
        self._ray_ready = threading.Event()
        self._ray_stop = threading.Event()
        self._ray_error: Exception | None = None
        self._closed = False
        self.ray_status = "not started"
        self.on_ray_ready = None          # called (from the initialising thread) after ray.init

    # -- the Ray driver --------------------------------------------------------------------
    def ensure_ray(self, timeout: float = 180.0) -> None:
        """Start (once) or wait for the process's Ray driver.

        A server's Ray is started on a thread of its own that lives as long as the process:
        the processes ``ray.init`` starts die with the *thread* that started them (Linux's
        parent-death signal is per thread), and the request threads that first need Ray
        are recycled after 10 s idle (measured: the server hung ~59 s, then exited, on
        the first request after the starting thread went away).
        """
        self._refuse_if_closed()
        if not self.own_ray_thread:
            with self._ray_lock:
                init_ray(self.ray_address)
                self.ray_status = "ready"
            return
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
        deadline = time.monotonic() + timeout
        while not self._ray_ready.wait(0.1):        # woken by close() too
            self._refuse_if_closed()
            if time.monotonic() > deadline:
                raise RuntimeError(f"ray: not ready after {timeout:.0f} s")
        self._refuse_if_closed()
        if self._ray_error is not None:
            raise self._ray_error

    def _refuse_if_closed(self) -> None:
        """After close() nothing may start: a pool made then would call Ray after its
        shutdown, and Ray's auto-init would start a second cluster as the process stops
        (seen in issue 38 row 11's reproduction)."""
        if self._closed:
            raise PoolsClosed("shard pools: closed (the server is stopping)")

    def _own_ray(self) -> None:
        """The thread that starts Ray, then keeps it alive until close()."""
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

    # -- the pools -------------------------------------------------------------------------
    @staticmethod
    def _key(scene: Scene | str, n_blocks: int | None = None, options: dict | None = None) -> Scene:
        """The scene (a ``Scene``, or the loose domain, block count and options)."""
        return scene if isinstance(scene, Scene) else Scene.of(scene, n_blocks, options)

    def acquire(self, scene: Scene | str, n_blocks: int | None = None, options: dict | None = None) -> ShardPool:
        """The shared pool of this scene (created if needed; one per domain, block count
        and domain options, since the options reach every world); pair with release()."""
        key = self._key(scene, n_blocks, options)
        self.ensure_ray()
        with self._cond:
            self._refuse_if_closed()
            while key not in self._pools and len(self._pools) >= self.max_pools:
                idle = [k for k in self._pools if self._users[k] == 0]
                if idle:
                    victim = min(idle, key=lambda k: self._last_used[k])
                    self._pools.pop(victim).close()
                    del self._users[victim], self._last_used[victim]
                else:
                    self._cond.wait(timeout=1.0)
                    self._refuse_if_closed()
            fresh = key not in self._pools
            if fresh:
                self._pools[key] = ShardPool(key.domain, key.physics_options(),
                                             self.n_shards, num_cpus=1.0 / self.max_pools)
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
                self.release(key)
                raise
            if added:
                log.info("pool %s: %d shards added (cluster grew), %d in all", key, added,
                         len(pool.actors))
        return pool

    def release(self, scene: Scene | str, n_blocks: int | None = None, options: dict | None = None) -> None:
        """Hand back a pool from acquire() (it stays cached until evicted or close())."""
        key = self._key(scene, n_blocks, options)
        with self._cond:
            if key in self._users:
                self._users[key] = max(0, self._users[key] - 1)
                self._last_used[key] = time.monotonic()
            self._cond.notify_all()

    @contextmanager
    def lease(self, scene: Scene | str, n_blocks: int | None = None,
              options: dict | None = None) -> Iterator[ShardPool]:
        """acquire() for the duration of a with block."""
        key = self._key(scene, n_blocks, options)
        pool = self.acquire(key)
        try:
            yield pool
        finally:
            self.release(key)

    def __enter__(self) -> "ShardPools":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close every pool; stop Ray if this object's thread started it. Leases
        refused from here on (PoolsClosed)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
            for pool in self._pools.values():
                try:
                    pool.close()
                except Exception:  # pragma: no cover - Ray already down
                    pass
            self._pools.clear()
            self._users.clear()
        self._ray_stop.set()                 # the owner thread shuts Ray down
        if self._ray_thread is None:
            return
        if self._ray_ready.is_set():
            self._ray_thread.join(timeout=30)
        else:
            # Still inside ray.init (3-5 s on 2 cores), which cannot be interrupted: not
            # waited for, so a SIGTERM at start-up ends the server at once (issue 38 row
            # 11). What it started so far is killed at the server's exit
            # (coordinator.distributed.reaper.sweep): Ray's parent-death signal misses a
            # process forked in the last moments.
            log.info("ray was still starting: not waited for")


__all__ = ["MAX_POOLS", "PoolsClosed", "ShardPools"]
