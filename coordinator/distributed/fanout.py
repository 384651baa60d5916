"""Fan-out of particle simulations to shard actors placed over the Ray cluster's nodes.

One remote call per shard per action carries that shard's contiguous slice of the
particles. Shards are stateless from the coordinator's point of view, and every
particle-action runs in a freshly rebuilt world, so a batch gives bit-identical results on
any shard of any node: that is what makes placement free and failure recovery exact.

Placement. A pool plans one shard per CPU of every alive node (or ``n_shards`` dealt over
the nodes' CPUs in turn) and pins each shard to its planned node with a *soft* node
affinity. Why not the alternatives:

- Ray's ``SPREAD`` scheduling strategy is best effort: it deals actors round robin over
  nodes with room, which is even for a pool created at once, but when a node joins it
  does not promise that the shards added for it land on it (the service's pools reserve a
  fraction of a CPU per shard, so the old nodes still "have room").
- A placement group reserves fixed bundles: it cannot grow when nodes join, and a bundle
  whose node died is only rescheduled where a whole free bundle fits, so the shard's
  restart waits (for ever on a fixed cluster) while its batch is in flight.

Soft affinity gives the exact plan, and being soft it never pins a restart to a dead node.
``refresh()`` re-plans against the cluster as it is now (the service calls it at the start
of every task): shards on dead nodes are dropped, shards are added where nodes or CPUs
were added.

Failure. A shard whose process dies is restarted by Ray in place and its call retried
(``max_restarts``/``max_task_retries``). A shard whose *node* is gone usually cannot be
restarted (the survivors' CPUs are taken by their own shards), so while a call is in flight
the pool checks every ``check_s`` seconds whether a node it waits on left the cluster; if
so it drops that node's shards and re-runs their slices on the surviving shards (one more
call each). Results are concatenated in particle order, so the action's outcome is
identical to an undisturbed one.
"""
from __future__ import annotations

import os
import threading
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np

from sim_workers.shard import Shard, decode_state, remote_shard


def init_ray(address: str | None = None, num_cpus: int = 2) -> dict:
    """Join `address` (a running cluster; "auto": the one on this machine) or start a
    local Ray of our own with `num_cpus` CPUs. Without an address ``ray.init`` would join
    any cluster already running on the machine, and refuse `num_cpus` there (issue 25: a
    `ray start` beside `tmoc serve` turned every observation into a 500)."""
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    if not ray.is_initialized():
        if address:
            ray.init(address=address, logging_level="ERROR", log_to_driver=False)
        else:
            ray.init(address="local", num_cpus=num_cpus, include_dashboard=False,
                     logging_level="ERROR", log_to_driver=False)
    return ray.cluster_resources()


def cluster_nodes() -> list[dict]:
    """The alive Ray nodes: node_id, hostname, address, cpus; the driver's node first."""
    import ray

    here = ray.get_runtime_context().get_node_id()
    nodes = [{"node_id": n["NodeID"], "hostname": n.get("NodeManagerHostname", ""),
              "address": n.get("NodeManagerAddress", ""),
              "cpus": int(n.get("Resources", {}).get("CPU", 0))}
             for n in ray.nodes() if n.get("Alive")]
    nodes.sort(key=lambda n: (n["node_id"] != here, n["address"], n["node_id"]))
    return nodes


def plan_shards(nodes: list[dict], n_shards: int | None = None) -> list[str]:
    """The node of every shard: one per CPU of each node (`n_shards` None), else `n_shards`
    dealt over the nodes' CPUs in turn (node A's 1st CPU, node B's 1st, A's 2nd, ...).

    >>> nodes = [{"node_id": "A", "cpus": 2}, {"node_id": "B", "cpus": 1}]
    >>> plan_shards(nodes), plan_shards(nodes, n_shards=4)
    (['A', 'B', 'A'], ['A', 'B', 'A', 'A'])
    """
    slots = [n["node_id"] for k in range(max((n["cpus"] for n in nodes), default=0))
             for n in nodes if n["cpus"] > k]
    if not slots or n_shards is None:
        return slots
    return [slots[i % len(slots)] for i in range(n_shards)]


@dataclass(eq=False)
class _ShardRef:
    actor: object
    node_id: str            # where it was placed, then where it last answered from
    hostname: str


class ShardPool:
    """Shard actors over the cluster's nodes (default: one per CPU of every node), or one
    in-process shard if `n_shards` is 0.

    Each actor reserves `num_cpus` of Ray's CPU resource (a long-lived service that keeps
    pools for several scenes at once gives each a fraction, so they never starve each other).

    In-process (no Ray): one pickup simulated under two beliefs of the blocks' size, the
    true 45 mm and 60 mm, wider than the fingers open for a 45 mm block (they land on it):

    >>> from sim_workers.domains import load
    >>> physics = load("container")
    >>> truth = physics.true_properties()
    >>> config = physics.initial_configuration(truth)
    >>> action = "pickup(r,b3,init)"
    >>> trajectory = physics.action_trajectory(config, action, physics.action_pose(truth, config, action))
    >>> pool = ShardPool("container", n_shards=0)
    >>> out = pool.simulate(config.to_array(), np.array([[0.045] * 8, [0.060] * 8]), action,
    ...                     trajectory, start_time=float(trajectory[3, 0]))
    >>> sorted(out)
    ['configurations', 'measurements', 'nodes', 'reruns', 'states', 'steps']
    >>> ["is_holding(r,b3)" in state for state in out["states"]], out["reruns"], pool.n_shards
    ([True, False], 0, 1)
    >>> pool.close()
    """

    def __init__(self, domain: str, options: dict | None = None,
                 n_shards: int | None = None, num_cpus: float = 1.0, check_s: float = 1.0,
                 wait_for_cpus_s: float = 60.0) -> None:
        self.domain = domain
        self.options = dict(options or {})
        self.timings = {"ray_s": 0.0, "calls": 0, "reruns": 0}
        self.requested = n_shards
        self.num_cpus = num_cpus
        self.check_s = check_s
        self._shards: list[_ShardRef] = []
        self._actor_cls = None
        self._lock = threading.Lock()
        if n_shards == 0:
            self._local = Shard(domain, self.options)
            return
        self._local = None
        # A cluster whose head offers no CPU may not have its workers yet (just deployed).
        deadline = time.monotonic() + wait_for_cpus_s
        while self.refresh() == 0:
            if time.monotonic() > deadline:
                raise RuntimeError(f"no alive Ray node has a CPU for a shard (waited "
                                   f"{wait_for_cpus_s:.0f} s): start a worker node "
                                   "(`ray start --address HEAD_IP:6379`)")
            time.sleep(1.0)

    # -- placement ---------------------------------------------------------------------
    @property
    def actors(self) -> list:
        return [s.actor for s in self._shards]

    @property
    def n_shards(self) -> int:
        return max(1, len(self._shards))

    def refresh(self) -> int:
        """Re-plan against the cluster as it is now: drop the shards of nodes that left and
        add shards where the plan has more than there are (nodes joined, CPUs added).
        Returns how many shards were added."""
        if self._local is not None:
            return 0
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        nodes = cluster_nodes()
        alive = {n["node_id"]: n for n in nodes}
        self._drop([s for s in self._shards if s.node_id not in alive])
        with self._lock:
            have = Counter(s.node_id for s in self._shards)
            missing = []
            for node_id in plan_shards(nodes, self.requested):
                if have[node_id] > 0:
                    have[node_id] -= 1
                else:
                    missing.append(node_id)
            if self.requested is not None:
                missing = missing[:max(0, self.requested - len(self._shards))]
            if missing and self._actor_cls is None:
                self._actor_cls = remote_shard(self.num_cpus)
            for node_id in missing:
                actor = self._actor_cls.options(
                    scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=True),
                ).remote(self.domain, self.options)
                self._shards.append(_ShardRef(actor, node_id, alive[node_id]["hostname"]))
        return len(missing)

    def _drop(self, shards: list[_ShardRef]) -> None:
        """Forget these shards and end their actors for good (no restart)."""
        if not shards:
            return
        import ray

        with self._lock:
            self._shards = [s for s in self._shards if all(s is not d for d in shards)]
        for s in shards:
            try:
                ray.kill(s.actor, no_restart=True)
            except Exception:  # pragma: no cover - already gone
                pass

    def _on_dead_nodes(self, shards) -> list[_ShardRef]:
        import ray

        alive = {n["NodeID"] for n in ray.nodes() if n.get("Alive")}
        return [s for s in shards if s.node_id not in alive]

    def nodes(self, timeout: float = 30.0) -> list[dict]:
        """Where every shard runs (node_id, hostname, pid, rss_mb, worlds); a shard that does
        not answer within `timeout` (still starting, or its node just died) is reported
        where it was placed."""
        if self._local is not None:
            return [self._local.node()]
        import ray

        shards = list(self._shards)
        refs = [s.actor.node.remote() for s in shards]
        if not refs:
            return []
        ready, _ = ray.wait(refs, num_returns=len(refs), timeout=timeout)
        done = set(ready)
        out = []
        for s, ref in zip(shards, refs):
            if ref in done:
                try:
                    info = ray.get(ref)
                    s.node_id, s.hostname = info["node_id"], info["hostname"]
                    out.append(info)
                    continue
                except ray.exceptions.RayActorError:
                    pass
            out.append({"node_id": s.node_id, "hostname": s.hostname, "pid": None})
        return out

    # -- simulation --------------------------------------------------------------------
    def simulate(self, start: np.ndarray, sizes: np.ndarray, action: str, trajectory: np.ndarray,
                 start_time=0.0) -> dict:
        """Simulate `action` for every particle; results in particle order.

        The split into shards changes nothing in the results: every particle-action runs
        in a freshly built world (sim_workers.grounded_world). Besides the arrays, key
        ``nodes`` maps each node that answered to its hostname and particle-action count,
        and ``reruns`` counts slices re-run because their node was lost.
        """
        sizes = np.asarray(sizes, dtype=np.float64)
        n = len(sizes)
        starts = np.broadcast_to(np.asarray(start_time, dtype=np.float64), (n,))
        traj = np.asarray(trajectory, dtype=np.float64)
        if self._local is not None:
            parts = [self._local.simulate_batch(start, sizes, action, traj, starts)]
            reruns = 0
        else:
            parts, reruns = self._fan_out(start, sizes, action, traj, starts)
        self.timings["calls"] += 1
        self.timings["reruns"] += reruns
        nodes: dict[str, dict] = {}
        for p in parts:
            where = p.pop("node")
            entry = nodes.setdefault(where["node_id"], {"hostname": where["hostname"],
                                                         "particle_actions": 0})
            entry["particle_actions"] += len(p["steps"])
        out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        out["states"] = [decode_state(s) for s in out["states"]]
        out["nodes"] = nodes
        out["reruns"] = reruns
        return out

    def probe_rows(self, jobs: list, truths: list[dict], belief: dict, seeds: np.ndarray) -> dict:
        """Counterfactual trials of every job for every row (``Shard.probe_rows``), the rows
        split over the shards as particles are; ``successes`` (M, J) in row order (1, 0, or
        -1: not reached), the same on any split (each trial has its own seed and a freshly built world)."""
        jobs = [(str(a), int(k)) for a, k in jobs]
        seeds = np.asarray(seeds, dtype=np.int64)
        if self._local is not None:
            parts = [self._local.probe_rows(jobs, truths, belief, seeds)]
        else:
            parts, _ = self._fan_out_slices(
                len(truths), lambda s, a, b: s.actor.probe_rows.remote(jobs, truths[a:b], belief, seeds[a:b]))
        self.timings["calls"] += 1
        return {"successes": np.concatenate([p["successes"] for p in parts])}

    def _fan_out(self, start, sizes, action, traj, starts) -> tuple[list[dict], int]:
        """One simulate call per shard (``_fan_out_slices``)."""
        def call(s: _ShardRef, a: int, b: int):
            tr = traj if traj.ndim == 2 else traj[a:b]
            return s.actor.simulate_batch.remote(start, sizes[a:b], action, tr, starts[a:b])

        return self._fan_out_slices(len(sizes), call)

    def _fan_out_slices(self, n: int, call) -> tuple[list[dict], int]:
        """One call per shard (``call(shard, lo, hi)``: the remote call for rows lo..hi);
        a slice whose node is lost is re-split over the survivors."""
        import ray

        pending: dict = {}                # ref -> (lo, hi, shard)

        def submit(lo: int, hi: int, shards: list[_ShardRef]) -> None:
            bounds = np.linspace(lo, hi, len(shards) + 1).astype(int)
            for s, a, b in zip(shards, bounds[:-1], bounds[1:]):
                if b > a:
                    pending[call(s, a, b)] = (a, b, s)

        submit(0, n, list(self._shards))
        parts: dict[int, dict] = {}
        reruns = 0
        t0 = time.perf_counter()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=self.check_s)
            lost_slices, lost = [], []
            for ref in ready:
                lo, hi, s = pending.pop(ref)
                try:
                    part = ray.get(ref)
                except ray.exceptions.RayActorError:      # ended for good: re-run elsewhere
                    lost_slices.append((lo, hi))
                    lost.append(s)
                    continue
                s.node_id, s.hostname = part["node"]["node_id"], part["node"]["hostname"]
                parts[lo] = part
            if pending:                                   # still waiting: any node lost?
                dead = self._on_dead_nodes({id(s): s for _, _, s in pending.values()}.values())
                for ref, (lo, hi, s) in list(pending.items()):
                    if any(s is d for d in dead):
                        del pending[ref]
                        lost_slices.append((lo, hi))
                lost += dead
            if lost_slices:
                self._drop(lost)
                survivors = list(self._shards)
                if not survivors:
                    self.refresh()
                    survivors = list(self._shards)
                if not survivors:
                    raise RuntimeError("every node running shards was lost and no alive node "
                                       "has a CPU for a new one")
                for lo, hi in lost_slices:
                    submit(lo, hi, survivors)
                    reruns += 1
        self.timings["ray_s"] += time.perf_counter() - t0
        return [parts[lo] for lo in sorted(parts)], reruns

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            return
        self._drop(list(self._shards))
