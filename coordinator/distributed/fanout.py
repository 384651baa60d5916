"""Fan-out of particle simulations to shard actors placed over the Ray cluster's nodes.

One remote call per *node* per action carries that node's contiguous slice of the
particles to the node's dispatcher (``coordinator.distributed.node_dispatcher``), which
splits it over the node's shards; so the driver's serial submission grows with the nodes,
not the cores (``dispatch="shard"``, one call per shard, is kept for comparison).
Shards are stateless from the coordinator's point of view, and every
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

from sim_workers.engines.registry import BATCH_ENGINES
from sim_workers.shard import Shard, decode_state, remote_shard

from .node_dispatcher import NodeShardsLost, remote_dispatcher, slice_args

DISPATCH = ("node", "shard")


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
    """The alive Ray nodes: node_id, hostname, address, cpus, gpus; the driver's node first."""
    import ray

    here = ray.get_runtime_context().get_node_id()
    nodes = [{"node_id": n["NodeID"], "hostname": n.get("NodeManagerHostname", ""),
              "address": n.get("NodeManagerAddress", ""),
              "cpus": int(n.get("Resources", {}).get("CPU", 0)),
              "gpus": int(n.get("Resources", {}).get("GPU", 0))}
             for n in ray.nodes() if n.get("Alive")]
    nodes.sort(key=lambda n: (n["node_id"] != here, n["address"], n["node_id"]))
    return nodes


def shard_slots(nodes: list[dict], threads: int = 1, gpus: bool = False) -> list[dict]:
    """`nodes` with ``cpus`` as the shards each can hold: one per GPU (`gpus`: a batch
    engine's shard steps all its particles on one), else one per `threads` CPUs.

    >>> nodes = [{"node_id": "A", "cpus": 16, "gpus": 2}, {"node_id": "B", "cpus": 8, "gpus": 0}]
    >>> [n["cpus"] for n in shard_slots(nodes)], [n["cpus"] for n in shard_slots(nodes, 4)]
    ([16, 8], [4, 2])
    >>> [n["cpus"] for n in shard_slots(nodes, gpus=True)]
    [2, 0]
    """
    if gpus:
        return [{**n, "cpus": int(n.get("gpus", 0))} for n in nodes]
    return [{**n, "cpus": max(1, n["cpus"] // threads) if n["cpus"] else 0} for n in nodes]


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


@dataclass(eq=False)
class _NodeRef:
    """A node's dispatcher and the shards it deals to (as of plan number `epoch`)."""
    actor: object
    node_id: str
    hostname: str
    shards: list
    epoch: int


class ShardPool:
    """Shard actors over the cluster's nodes (default: one per CPU of every node), or one
    in-process shard if `n_shards` is 0.

    Each actor reserves `num_cpus` of Ray's CPU resource (a long-lived service that keeps
    pools for several scenes at once gives each a fraction, so they never starve each other).

    In-process (no Ray): one pickup simulated under two beliefs of the blocks' size, the
    true 45 mm and 60 mm, wider than the fingers open for a 45 mm block at 1.15 sides (the
    option ``grasp_clearance=0``; they land on it):

    >>> from sim_workers.domains import load
    >>> physics = load("container", grasp_clearance=0.0)
    >>> truth = physics.true_properties()
    >>> config = physics.initial_configuration(truth)
    >>> action = "pickup(r,b3,init)"
    >>> trajectory = physics.action_trajectory(config, action, physics.action_pose(truth, config, action))
    >>> pool = ShardPool("container", {"grasp_clearance": 0.0}, n_shards=0)
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
                 wait_for_cpus_s: float = 60.0, dispatch: str = "node", threads: int = 1) -> None:
        if dispatch not in DISPATCH:
            raise ValueError(f"dispatch: {dispatch!r} is not one of {', '.join(DISPATCH)}")
        if threads < 1:
            raise ValueError(f"threads: {threads} must be at least 1")
        # threads > 1: each shard steps its worlds on that many threads (an engine whose
        # worlds step without the GIL: MuJoCo; others run one) and holds that many CPUs,
        # so a node of C CPUs gets C // threads shards.
        self.threads = threads
        self.domain = domain
        self.options = dict(options or {})
        # ray_calls: remote calls the driver submitted; submit_s: the driver's time spent
        # submitting them (the serial part that grows with the targets, docs/SCALING.md);
        # node_calls, node_submit_s: the same for the dispatchers' calls to their shards.
        self.timings = {"ray_s": 0.0, "calls": 0, "reruns": 0, "ray_calls": 0, "submit_s": 0.0,
                        "node_calls": 0, "node_submit_s": 0.0, "plans_resent": 0}
        self.requested = n_shards
        self.num_cpus = num_cpus
        self.check_s = check_s
        self.dispatch = dispatch
        self._shards: list[_ShardRef] = []
        self._nodes: dict[str, _NodeRef] = {}
        self._epoch = 0
        self._actor_cls = None
        self._dispatcher_cls = None
        self._lock = threading.Lock()
        if n_shards == 0:
            self._local = Shard(domain, self.options, threads=threads)
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
        slots = shard_slots(nodes, self.threads, self.on_gpus(nodes))
        self._drop([s for s in self._shards if s.node_id not in alive])
        with self._lock:
            have = Counter(s.node_id for s in self._shards)
            missing = []
            for node_id in plan_shards(slots, self.requested):
                if have[node_id] > 0:
                    have[node_id] -= 1
                else:
                    missing.append(node_id)
            if self.requested is not None:
                missing = missing[:max(0, self.requested - len(self._shards))]
            if missing and self._actor_cls is None:
                gpus = self.num_cpus if self.on_gpus(nodes) else 0.0
                self._actor_cls = remote_shard(self.num_cpus * self.threads, num_gpus=gpus)
            for node_id in missing:
                actor = self._actor_cls.options(
                    scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=True),
                ).remote(self.domain, self.options, threads=self.threads)
                self._shards.append(_ShardRef(actor, node_id, alive[node_id]["hostname"]))
        self._sync_dispatchers()
        return len(missing)

    def on_gpus(self, nodes: list[dict]) -> bool:
        """Whether this pool's shards go one per GPU: a batch engine (MuJoCo Warp) on a
        cluster with GPUs. Each such shard reserves `num_cpus` of a GPU as well (a whole
        one in a command, 1 / max_pools in the service), and its Warp sees that GPU."""
        engine = self.options.get("engine")
        return bool(engine in BATCH_ENGINES and any(n.get("gpus", 0) > 0 for n in nodes))

    def _sync_dispatchers(self) -> None:
        """One dispatcher per node that has shards, holding that node's shards: created
        for a new node, told its new shard list (a new plan number) where it changed,
        ended where the node has no shard left."""
        if self._local is not None or self.dispatch != "node":
            return
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy
        import ray

        with self._lock:
            by_node: dict[str, list[_ShardRef]] = {}
            for s in self._shards:
                by_node.setdefault(s.node_id, []).append(s)
            for node_id in [k for k in self._nodes if k not in by_node]:
                self._end(self._nodes.pop(node_id).actor)
            changed = []
            for node_id, shards in by_node.items():
                ref = self._nodes.get(node_id)
                if ref is not None and len(ref.shards) == len(shards) and \
                        all(a is b for a, b in zip(ref.shards, shards)):
                    continue
                self._epoch += 1
                if ref is None:
                    # Created empty (plan 0) and sent its shards as plan >= 1: a dispatcher
                    # Ray restarts comes back empty, answers "stale" and is sent the plan again
                    # (actor handles as constructor arguments would also pin them in the
                    # object store for the restart).
                    if self._dispatcher_cls is None:
                        self._dispatcher_cls = remote_dispatcher()
                    actor = self._dispatcher_cls.options(
                        scheduling_strategy=NodeAffinitySchedulingStrategy(node_id, soft=True),
                    ).remote()
                    ref = self._nodes[node_id] = _NodeRef(actor, node_id, shards[0].hostname, shards, self._epoch)
                ref.shards, ref.epoch = shards, self._epoch
                changed.append(ref.actor.set_shards.remote([x.actor for x in shards], self._epoch))
        if changed:
            try:
                ray.get(changed)
            except ray.exceptions.RayActorError:
                pass              # its node just left: the next call finds it gone

    @staticmethod
    def _end(actor) -> None:
        import ray

        try:
            ray.kill(actor, no_restart=True)
        except Exception:  # pragma: no cover - already gone
            pass

    def _drop(self, shards: list[_ShardRef]) -> None:
        """Forget these shards and end their actors for good (no restart)."""
        if not shards:
            return
        with self._lock:
            self._shards = [s for s in self._shards if all(s is not d for d in shards)]
        for s in shards:
            self._end(s.actor)

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
                 start_time=0.0, arm=None) -> dict:
        """Simulate `action` for every particle; results in particle order.

        The split into shards changes nothing in the results: every particle-action runs
        in a freshly built world (sim_workers.grounded_world). Besides the arrays, key
        ``nodes`` maps each node that answered to its hostname and particle-action count,
        and ``reruns`` counts slices re-run because their node was lost. `arm`: an arm's
        joints (``sim_workers.robots.motion.ArmMotion``), sent whole to every shard.
        """
        sizes = np.asarray(sizes, dtype=np.float64)
        n = len(sizes)
        starts = np.broadcast_to(np.asarray(start_time, dtype=np.float64), (n,))
        traj = np.asarray(trajectory, dtype=np.float64)
        if self._local is not None:
            parts = [self._local.simulate_batch(start, sizes, action, traj, starts, arm)]
            reruns = 0
        else:
            parts, reruns = self._fan_out(start, sizes, action, traj, starts, arm)
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

    def probe_rows(self, jobs: list, truths: list[dict], belief: dict, seeds: np.ndarray, arm=None) -> dict:
        """Counterfactual trials of every job for every row (``Shard.probe_rows``), the rows
        split over the shards as particles are; ``successes`` (M, J) in row order (1, 0, or
        -1: not reached), the same on any split (each trial has its own seed and a freshly built world).
        `arm`: a factory of the arm that does the trials' actions, sent to every shard."""
        jobs = [(str(a), int(k)) for a, k in jobs]
        seeds = np.asarray(seeds, dtype=np.int64)
        args = (jobs, truths, belief, seeds) + (() if arm is None else (arm,))
        if self._local is not None:
            parts = [self._local.probe_rows(*args)]
        else:
            parts, _ = self._fan_out_slices(len(truths), "probe_rows", args, (1, 3))
        self.timings["calls"] += 1
        return {"successes": np.concatenate([p["successes"] for p in parts])}

    def _fan_out(self, start, sizes, action, traj, starts, arm=None) -> tuple[list[dict], int]:
        """One simulate call per node, or per shard (``_fan_out_slices``)."""
        sliced = (1, 3, 4) if traj.ndim == 3 else (1, 4)
        args = (start, sizes, action, traj, starts) + (() if arm is None else (arm,))
        return self._fan_out_slices(len(sizes), "simulate_batch", args, sliced)

    def _targets(self) -> list:
        """Where the driver sends calls: the nodes' dispatchers, or every shard."""
        with self._lock:          # the service's tasks share a pool: another may re-plan it
            if self.dispatch == "node":
                return [n for n in self._nodes.values() if n.shards]
            return list(self._shards)

    def _submit(self, target, method: str, args: tuple, sliced: tuple, a: int, b: int):
        """One remote call for rows a..b: to a node's dispatcher or straight to a shard."""
        part_args = slice_args(args, sliced, a, b)
        if isinstance(target, _NodeRef):
            return target.actor.fan.remote(method, part_args, sliced, b - a, target.epoch)
        return getattr(target.actor, method).remote(*part_args)

    def _weights(self, targets: list) -> list[int]:
        return [len(t.shards) if isinstance(t, _NodeRef) else 1 for t in targets]

    def _fan_out_slices(self, n: int, method: str, args: tuple, sliced: tuple) -> tuple[list[dict], int]:
        """``method`` over rows 0..n of the `sliced` arguments: one call per target (node
        dispatcher or shard), each a contiguous slice sized by the target's shards; a
        slice whose node is lost is re-split over the survivors. Returns the shards'
        results in row order and the number of slices re-run."""
        import ray

        pending: dict = {}                # ref -> (lo, hi, target)

        def submit(lo: int, hi: int, targets: list) -> None:
            t_sub = time.perf_counter()
            weights = self._weights(targets)
            cuts = np.concatenate([[0], np.cumsum(weights)])
            bounds = np.linspace(lo, hi, int(cuts[-1]) + 1).astype(int)
            for t, c0, c1 in zip(targets, cuts[:-1], cuts[1:]):
                a, b = int(bounds[c0]), int(bounds[c1])
                if b > a:
                    pending[self._submit(t, method, args, sliced, a, b)] = (a, b, t)
                    self.timings["ray_calls"] += 1
            self.timings["submit_s"] += time.perf_counter() - t_sub

        submit(0, n, self._targets())
        parts: dict[int, list[dict]] = {}
        reruns = 0
        gone: list[_ShardRef] = []            # shards a node's dispatcher found ended for good
        t0 = time.perf_counter()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=len(pending), timeout=self.check_s)
            lost_slices, lost = [], []
            for ref in ready:
                lo, hi, t = pending.pop(ref)
                try:
                    out = ray.get(ref)
                except (ray.exceptions.RayActorError, NodeShardsLost):   # ended for good
                    lost_slices.append((lo, hi))
                    lost.append(t)
                    continue
                if isinstance(t, _NodeRef):
                    if out.get("stale"):              # restarted, or the plan not yet there
                        self._resend_plan(t)
                        submit(lo, hi, [t])
                        continue
                    reruns += out["reruns"]
                    gone += [t.shards[i] for i in out.get("lost", ()) if i < len(t.shards)]
                    self.timings["node_calls"] += out["calls"]
                    self.timings["node_submit_s"] += out["submit_s"]
                    got = out["parts"]
                else:
                    got = [out]
                if isinstance(t, _ShardRef):
                    t.node_id, t.hostname = got[0]["node"]["node_id"], got[0]["node"]["hostname"]
                parts[lo] = got
            if pending:                                   # still waiting: any node lost?
                dead = self._on_dead_nodes({id(t): t for _, _, t in pending.values()}.values())
                for ref, (lo, hi, t) in list(pending.items()):
                    if any(t is d for d in dead):
                        del pending[ref]
                        lost_slices.append((lo, hi))
                lost += dead
            if lost_slices:
                self._lose(lost)
                survivors = self._targets()
                if not survivors:
                    self.refresh()
                    survivors = self._targets()
                if not survivors:
                    raise RuntimeError("every node running shards was lost and no alive node "
                                       "has a CPU for a new one")
                for lo, hi in lost_slices:
                    submit(lo, hi, survivors)
                    reruns += 1
        self.timings["ray_s"] += time.perf_counter() - t0
        if gone:
            # forgotten now, not at the next re-plan: the node's dispatcher gets its new list
            self._drop(gone)
            self._sync_dispatchers()
        return [p for lo in sorted(parts) for p in parts[lo]], reruns

    def _resend_plan(self, node: _NodeRef) -> None:
        import ray

        self.timings["plans_resent"] += 1
        ray.get(node.actor.set_shards.remote([x.actor for x in node.shards], node.epoch))

    def _lose(self, targets: list) -> None:
        """Forget lost targets for good: a lost node takes its dispatcher and its shards."""
        shards = [t for t in targets if isinstance(t, _ShardRef)]
        for t in targets:
            if isinstance(t, _NodeRef):
                shards += [s for s in self._shards if s.node_id == t.node_id]
                with self._lock:
                    if self._nodes.get(t.node_id) is t:
                        del self._nodes[t.node_id]
                self._end(t.actor)
        self._drop(shards)
        self._sync_dispatchers()

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            return
        for node in list(self._nodes.values()):
            self._end(node.actor)
        self._nodes.clear()
        self._drop(list(self._shards))
