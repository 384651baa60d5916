"""The shard: a Ray actor that owns grounded worlds and simulates one action for a batch.

One remote call per shard per action carries the whole batch: numpy arrays in (start
configuration, per-particle properties, trajectory or per-particle trajectories), numpy
arrays out (configurations, symbolic outcomes as text, measurements, step counts). A shard
keeps no state the coordinator cannot resend, so Ray may restart a dead one and re-run its
batch with identical results (every particle-action runs in a freshly rebuilt world).
"""
from __future__ import annotations

import os
import resource
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .configuration import Configuration
from .domains import load
from .engines.registry import batch_class, make_world


def encode_state(state: frozenset[str]) -> str:
    """A symbolic state as one plain string (sorted atoms joined by spaces)."""
    return " ".join(sorted(state))


def decode_state(text: str) -> frozenset[str]:
    return frozenset(text.split()) if text else frozenset()


class Shard:
    """K grounded worlds of one domain in one process; particles are dealt round-robin,
    or with ``threads`` > 1 (an engine whose worlds step without the GIL: MuJoCo) one
    contiguous run of them to each thread's world.

    Wrap with ``ray.remote`` (see ``remote_shard``) to run as an actor; the plain class
    runs in-process (tests, benchmarks, the probe).
    """

    def __init__(self, domain: str, options: dict | None = None, n_worlds: int = 1,
                 leave_out: bool = True, threads: int = 1) -> None:
        if n_worlds < 1:
            raise ValueError(f"n_worlds: {n_worlds} must be at least 1")
        if threads < 1:
            raise ValueError(f"threads: {threads} must be at least 1")
        # Worlds are built here, inside the process that uses them: a pybullet client id
        # does not survive pickling. Particle worlds leave out the bodies an action cannot
        # reach (sim_workers/reach.py; guarded, so outcomes do not depend on it).
        self.domain = load(domain, **(options or {}))
        self.domain_name, self.options = domain, dict(options or {})
        self.worlds = [make_world(self.domain, leave_out=leave_out) for _ in range(n_worlds)]
        # Threads only where the engine's worlds step without the GIL (MuJoCo): one world
        # per thread, each batch cut into one contiguous run of rows per thread.
        self.threads = threads if type(self.worlds[0]).steps_in_threads else 1
        while len(self.worlds) < self.threads:
            self.worlds.append(make_world(self.domain, leave_out=leave_out))
        self._executor = ThreadPoolExecutor(self.threads, thread_name_prefix="tmoc-world") \
            if self.threads > 1 else None
        # A batch engine (MuJoCo Warp) steps the whole batch at once instead.
        batch_cls = batch_class(getattr(self.domain, "engine", None))
        self._batch = batch_cls(self.domain) if batch_cls is not None else None

    def simulate(self, start: np.ndarray, sizes: np.ndarray, action: str, trajectory: np.ndarray,
                 start_time=0.0, arm=None) -> dict:
        """Run `action` once per particle.

        start:      (5 + 7M,) flat observed configuration (re-grounded per particle)
        sizes:      (B, D) rows of L, one per particle (the domain's ``props_from_row``
                    expands a row; for block domains D is 1, one size for every block,
                    or n_blocks)
        trajectory: (T, 6) shared by every particle ("replay") or (B, T, 6) one each ("paper")
        start_time: where to start in the trajectory (scalar, or (B,) one per particle)
        arm:        an arm's joints over the shared trajectory (``sim_workers.robots.motion
                    .ArmMotion``): every world moves the arm's links along them
        Returns arrays: configurations (B, 5 + 7M), states (B,) text, measurements (B, P),
        steps (B,).
        """
        config = Configuration.from_array(start)
        sizes = np.atleast_2d(np.asarray(sizes, dtype=np.float64))
        traj = np.asarray(trajectory, dtype=np.float64)
        shared = traj.ndim == 2
        if not shared and traj.shape[0] != len(sizes):
            raise ValueError(f"trajectory: {traj.shape[0]} trajectories for {len(sizes)} particles")
        starts = np.broadcast_to(np.asarray(start_time, dtype=np.float64), (len(sizes),))
        if arm is not None and (not shared or self._batch is not None):
            raise ValueError("arm: an arm's links follow one shared trajectory in a world engine "
                             f"(not per-particle trajectories{', nor the batch engine' if self._batch else ''})")

        def run(world, rows) -> list:
            outs = []
            for b in rows:
                world.reset(config, self._props(sizes[b]))
                outs.append(world.execute(traj if shared else traj[b], action, start_time=float(starts[b]), arm=arm))
            return outs

        if self._batch is not None:
            outs = self._batch.run(config, [self._props(row) for row in sizes], action,
                                   [traj if shared else traj[b] for b in range(len(sizes))], starts)
        elif self._executor is None:
            outs = [run(self.worlds[b % len(self.worlds)], [b])[0] for b in range(len(sizes))]
        else:
            # Every particle-action starts from a reset world, so which thread's world runs
            # a row changes nothing in its result (tests/sim_workers/test_determinism.py).
            chunks = np.array_split(np.arange(len(sizes)), self.threads)
            futures = [self._executor.submit(run, w, c) for w, c in zip(self.worlds, chunks) if len(c)]
            outs = [o for f in futures for o in f.result()]
        return {"configurations": np.array([o.configuration.to_array() for o in outs]),
                "states": np.array([encode_state(o.state) for o in outs], dtype=object),
                "measurements": np.array([o.measurements for o in outs]),
                "steps": np.array([o.steps for o in outs], dtype=np.int64)}

    def _props(self, row: np.ndarray) -> dict:
        return self.domain.props_from_row(row)

    def simulate_batch(self, start: np.ndarray, sizes: np.ndarray, action: str,
                       trajectory: np.ndarray, start_time=0.0, arm=None) -> dict:
        """``simulate`` plus where it ran (key ``node``: node_id, hostname, pid): the one
        remote call a pool makes per shard per action, so that it can tell which node
        simulated which particles even after Ray restarted this actor elsewhere."""
        out = self.simulate(start, sizes, action, trajectory, start_time, arm)
        out["node"] = self.where()
        return out

    def probe_rows(self, jobs: list, truths: list[dict], belief: dict, seeds: np.ndarray, arm=None) -> dict:
        """Counterfactual trials (issue 40): for each row m (its truth by L's names, and
        its seed), one trial of every job (probe action, load) with Y at `belief`, each in
        a freshly built world; trial m of every job replays the same seeded world (the
        common random numbers the domains' T* estimates rely on). Returns ``successes``
        (M, J) int8: 1 a success, 0 a failure, -1 a context the probe could not reach;
        ``node`` (where it ran). `arm`: a factory of the arm that does each trial's actions
        (``robots.acting.arm_moves``: the run's robot, planned as the session plans it);
        None: the floating gripper."""
        from .probe import trial_by_names
        from .robots.acting import arm_moves

        opts = dict(self.options)
        n_blocks = int(opts.pop("n_blocks", self.domain.n_objects))
        out = np.zeros((len(truths), len(jobs)), dtype=np.int8)
        with arm_moves(arm):
            for m, (truth, seed) in enumerate(zip(truths, np.asarray(seeds).tolist())):
                for j, (action, load_k) in enumerate(jobs):
                    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
                    ok = trial_by_names(action, int(load_k), rng, domain=self.domain_name,
                                        n_blocks=n_blocks, options=opts, truth=truth, belief=belief)
                    out[m, j] = -1 if ok is None else int(ok)
        return {"successes": out, "node": self.where()}

    def where(self) -> dict:
        """The Ray node (``local`` outside Ray), host name and process of this shard."""
        try:
            import ray
            node_id = ray.get_runtime_context().get_node_id() if ray.is_initialized() else "local"
        except Exception:  # pragma: no cover - ray absent in a plain process
            node_id = "local"
        return {"node_id": node_id, "hostname": os.uname().nodename, "pid": os.getpid()}

    def node(self) -> dict:
        """Where this shard runs and what it costs in memory (RSS in MB)."""
        rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        return {**self.where(), "rss_mb": rss_mb, "worlds": len(self.worlds)}

    def close(self) -> None:
        if self._executor is not None:
            self._executor.shutdown(wait=True)
        if self._batch is not None:
            self._batch.close()
        for w in self.worlds:
            w.close()


def remote_shard(num_cpus: float = 1.0, num_gpus: float = 0.0):
    """The Ray actor class: restarted by Ray when its process dies, its task retried.

    When a whole node is lost, a restart may find no room on the surviving nodes (they
    already run their own shards); ``coordinator.distributed.fanout.ShardPool`` then drops that node's
    shards and re-runs their batches on the survivors instead of waiting for a restart."""
    import ray

    return ray.remote(num_cpus=num_cpus, num_gpus=num_gpus, max_restarts=-1, max_task_retries=-1)(Shard)
