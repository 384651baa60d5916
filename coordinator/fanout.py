"""Fan-out of particle simulations to shard actors spread over the Ray cluster.

One remote call per shard per action carries that shard's contiguous slice of the
particles. Shards are stateless from the coordinator's point of view, so Ray's actor fault
tolerance (restart + task retry) re-runs a dead shard's batch with identical results.
"""
from __future__ import annotations

import os
import time

import numpy as np

from sim_workers.shard import Shard, decode_state, remote_shard


def init_ray(address: str | None = None, num_cpus: int = 2) -> dict:
    """Join `address` (a running cluster) or start a local Ray with `num_cpus` CPUs."""
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if not ray.is_initialized():
        if address:
            ray.init(address=address, logging_level="ERROR", log_to_driver=False)
        else:
            ray.init(num_cpus=num_cpus, include_dashboard=False, logging_level="ERROR",
                     log_to_driver=False)
    return ray.cluster_resources()


class ShardPool:
    """`n_shards` shard actors (default: one per CPU of the cluster), or in-process if 0.

    Each actor reserves `num_cpus` of Ray's CPU resource (a long-lived service that keeps
    pools for several scenes at once gives each a fraction, so they never starve each other).
    """

    def __init__(self, domain: str = "container", options: dict | None = None,
                 n_shards: int | None = None, num_cpus: float = 1.0) -> None:
        self.domain = domain
        self.options = dict(options or {})
        self.timings = {"ray_s": 0.0, "calls": 0}
        if n_shards == 0:
            self._local = Shard(domain, self.options)
            self.actors = []
            return
        import ray

        self._local = None
        if n_shards is None:
            n_shards = max(1, int(ray.cluster_resources().get("CPU", 1)))
        actor_cls = remote_shard(num_cpus).options(scheduling_strategy="SPREAD")
        self.actors = [actor_cls.remote(domain, self.options) for _ in range(n_shards)]

    @property
    def n_shards(self) -> int:
        return max(1, len(self.actors))

    def nodes(self) -> list[dict]:
        if self._local is not None:
            return [self._local.node()]
        import ray

        return ray.get([a.node.remote() for a in self.actors])

    def simulate(self, start: np.ndarray, sizes: np.ndarray, action: str, trajectory: np.ndarray,
                 start_time=0.0) -> dict:
        """Simulate `action` for every particle; results in particle order.

        The split into shards changes nothing in the results: every particle-action runs
        in a freshly built world (sim_workers.grounded_world).
        """
        sizes = np.asarray(sizes, dtype=np.float64)
        n = len(sizes)
        starts = np.broadcast_to(np.asarray(start_time, dtype=np.float64), (n,))
        traj = np.asarray(trajectory, dtype=np.float64)
        if self._local is not None:
            parts = [self._local.simulate(start, sizes, action, traj, starts)]
        else:
            import ray

            bounds = np.linspace(0, n, self.n_shards + 1).astype(int)
            refs = []
            for actor, lo, hi in zip(self.actors, bounds[:-1], bounds[1:]):
                if hi > lo:
                    tr = traj if traj.ndim == 2 else traj[lo:hi]
                    refs.append(actor.simulate.remote(start, sizes[lo:hi], action, tr, starts[lo:hi]))
            t0 = time.perf_counter()
            parts = ray.get(refs)
            self.timings["ray_s"] += time.perf_counter() - t0
        self.timings["calls"] += 1
        out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        out["states"] = [decode_state(s) for s in out["states"]]
        return out

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            return
        import ray

        for a in self.actors:
            ray.kill(a)
        self.actors = []
