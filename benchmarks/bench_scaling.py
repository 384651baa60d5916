"""Scaling over nodes: throughput on 1, 2, ... Ray nodes; Ray calls per action; the model.

A ``ray.cluster_utils.Cluster`` on this machine (every node its own raylet, as separate
machines would be; its CPU count is Ray's logical resource, the OS shares this machine's
cores). Three parts, one run:

1. Throughput. bench_worlds' three actions (pickup, stack onto a pile, push a loaded
   tray), one batch of particles (sizes from the prior) per action, through a
   ``coordinator.distributed.fanout.ShardPool`` exactly as a run does, on 1 and 2 nodes of
   1 CPU (re-planned with ``refresh()`` after a node joins, as the service does between
   tasks). Prints ``efficiency=<throughput_2 / (2 x throughput_1)>``.
2. Dispatch. Nodes of ``--cpus-per-node`` logical CPUs (one shard each), 1, 2, 4, ...
   of them: per action, the Ray calls the driver submits and its time submitting them,
   with one call per node (the default) and one call per shard (before issue 42), the
   same particles (``dispatch_<mode>_<work>_nodes=<k> calls_per_action= submit_ms=``); and a
   dispatcher's time per shard call it submits. Work "physics" is the real action (here
   the shards' physics competes with the submissions for this machine's cores); "noop"
   the same path with no work per row (a probe with no jobs): Ray's own cost per call.
3. The model. ``bench_coordinator``'s action time with these measured constants (physics
   per particle-action from part 1, the coordinator's serial time at N = 1000 and 5000
   measured here, a round trip to a dispatcher, the submission costs of part 2):
   predicted efficiency at 16, 64, 256 and 1024 cores (16-core nodes), per dispatch.

    python benchmarks/bench_scaling.py                # ~2 min on 2 cores
    python benchmarks/bench_scaling.py --max-nodes 8  # the throughput curve, on 8 cores
    python benchmarks/bench_scaling.py --domain NAME  # another registered domain: the first
                                                      # action of each kind of its optimistic plan
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402
from bench_worlds import make_cases, particle_sizes  # noqa: E402

from coordinator.distributed.fanout import ShardPool  # noqa: E402
from sim_workers.domains import load  # noqa: E402


def domain_cases(name: str) -> dict:
    """Per action kind: (start, action, trajectory, transit end) of its first occurrence in
    the domain's optimistic plan, run once in a true world (any registered domain)."""
    from coordinator.domains import load as load_domain
    from sim_workers.engines import make_world

    d = load_domain(name)
    phys, task, n = d.physics, d.task, d.n_blocks
    truth = phys.true_properties()
    config = phys.initial_configuration(truth)
    plan = task.plan(task.initial_state(n), task.optimistic_transition(n))
    cases = {}
    with make_world(phys) as world:
        config = world.reset(config, truth)
        for action in plan.actions:
            key = phys.action_pose(truth, config, action)
            traj = phys.action_trajectory(config, action, key)
            t0 = phys.transit_end_time(config, action, key)
            cases.setdefault(action.split("(")[0], (config.to_array(), action, traj, t0))
            config = world.execute(traj, action, start_time=t0).configuration
    return cases


def measure(pool: ShardPool, cases: dict, sizes, rounds: int) -> tuple[int, float]:
    """(particle-actions, seconds) for `rounds` x every action, one batch per action."""
    done, t0 = 0, time.perf_counter()
    for _ in range(rounds):
        for start, action, traj, t_start in cases.values():
            out = pool.simulate(start, sizes, action, traj, t_start)
            done += len(out["steps"])
    return done, time.perf_counter() - t0


def dispatch_costs(cluster, domain_name: str, n_blocks: int, cases: dict, sizes, node_counts: list[int],
                   cpus_per_node: int, rounds: int) -> dict:
    """Per node count and dispatch: Ray calls per action, the driver's ms submitting them,
    and the dispatchers' ms per shard call (a fresh node-dispatch pool per node count,
    switched to per-shard dispatch for the same actions)."""
    import ray

    start, action, traj, t_start = next(iter(cases.values()))
    out = {}
    have = 0
    for k in node_counts:
        while have < k:
            cluster.add_node(num_cpus=cpus_per_node)
            have += 1
        cluster.wait_for_nodes()
        pool = ShardPool(domain_name, {"n_blocks": n_blocks}, num_cpus=1.0)
        try:
            shards = len(pool.actors)
            batch = sizes[: 2 * shards] if len(sizes) >= 2 * shards else np.resize(sizes, (2 * shards, sizes.shape[1]))
            pool.simulate(start, batch, action, traj, t_start)        # warm-up: every actor up
            trips = []
            for node in pool._nodes.values():
                for _ in range(20):
                    t0 = time.perf_counter()
                    ray.get(node.actor.ping.remote())
                    trips.append(time.perf_counter() - t0)
            for mode in ("node", "shard"):
                pool.dispatch = mode
                for label in ("physics", "noop"):
                    base = dict(pool.timings)
                    reps = rounds if label == "physics" else 30
                    for _ in range(reps):
                        if label == "physics":
                            pool.simulate(start, batch, action, traj, t_start)
                        else:
                            pool.probe_rows([], [{}] * len(batch), {}, np.arange(len(batch)))
                    d = {key: pool.timings[key] - base[key]
                         for key in ("ray_calls", "submit_s", "node_calls", "node_submit_s")}
                    r = out[(k, mode, label)] = {
                        "shards": shards, "calls_per_action": d["ray_calls"] / reps,
                        "submit_ms": d["submit_s"] / reps * 1e3,
                        "call_ms": d["submit_s"] / max(1, d["ray_calls"]) * 1e3,
                        "node_call_ms": d["node_submit_s"] / d["node_calls"] * 1e3 if d["node_calls"] else None,
                        "trip_ms": float(np.median(trips)) * 1e3}
                    print(f"dispatch_{mode}_{label}_nodes={k} shards={shards} "
                          f"calls_per_action={r['calls_per_action']:.1f} submit_ms={r['submit_ms']:.2f} "
                          f"per_call_us={r['call_ms'] * 1e3:.0f}"
                          + (f" dispatcher_per_call_us={r['node_call_ms'] * 1e3:.0f}" if r["node_call_ms"] else ""),
                          flush=True)
        finally:
            pool.close()
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=48, help="particles per action")
    ap.add_argument("--rounds", type=int, default=3, help="times every action is run")
    ap.add_argument("--max-nodes", type=int, default=2)
    ap.add_argument("--dispatch-nodes", default="1,2,4",
                    help="node counts of part 2 (nodes of --cpus-per-node CPUs; empty: skip parts 2 and 3)")
    ap.add_argument("--cpus-per-node", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domain", default="container", help="a registered domain (tmoc domains)")
    args = ap.parse_args(argv)
    if args.max_nodes < 2:
        ap.error("--max-nodes: at least 2")
    if args.max_nodes > (os.cpu_count() or 1):
        print(f"note: {args.max_nodes} nodes on {os.cpu_count()} cores: the nodes share cores")
    node_counts = [int(v) for v in args.dispatch_nodes.split(",") if v.strip()]

    import ray
    from ray.cluster_utils import Cluster

    domain = load(args.domain)
    cases = make_cases(domain, args.seed) if args.domain == "container" else domain_cases(args.domain)
    sizes = particle_sizes(domain, args.particles, args.seed + 1)
    results = {}
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        ray.init(address=cluster.address, logging_level="ERROR", log_to_driver=False)
        pool = ShardPool(args.domain, {"n_blocks": domain.spec.n_blocks})
        for k in range(1, args.max_nodes + 1):
            if k > 1:
                cluster.add_node(num_cpus=1)
                cluster.wait_for_nodes()
                pool.refresh()
            nodes = {n["node_id"] for n in pool.nodes()}
            assert len(pool.actors) == len(nodes) == k, (len(pool.actors), nodes)
            # Warm-up: every shard answers once (actor start, first world build, imports).
            start, action, traj, t_start = next(iter(cases.values()))
            pool.simulate(start, sizes[: 2 * k], action, traj, t_start)
            n, secs = measure(pool, cases, sizes, args.rounds)
            results[k] = n / secs
            print(f"nodes={k} shards={len(pool.actors)} particle_actions={n} seconds={secs:.2f} "
                  f"throughput={results[k]:.1f}/s", flush=True)
        pool.close()
    finally:
        ray.shutdown()
        cluster.shutdown()
    for k in range(3, args.max_nodes + 1):
        print(f"efficiency_{k}={results[k] / (k * results[1]):.3f}")
    print(f"efficiency={results[2] / (2 * results[1]):.3f}", flush=True)
    if not node_counts:
        return 0
    # Parts 2 and 3: a cluster whose head runs the driver only (no CPU for a shard), as
    # on a cluster whose head is not a worker.
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "include_dashboard": False})
    try:
        ray.init(address=cluster.address, logging_level="ERROR", log_to_driver=False)
        costs = dispatch_costs(cluster, args.domain, domain.spec.n_blocks, cases, sizes, node_counts,
                               args.cpus_per_node, max(3, args.rounds))
    finally:
        ray.shutdown()
        cluster.shutdown()
    model(costs, max(node_counts), 1e3 / results[1], args.domain)
    return 0


def model(costs: dict, k: int, phys_ms: float, domain: str) -> None:
    """Part 3: the coordinator's serial time measured, then the predicted efficiencies."""
    from bench_coordinator import amdahl, measure as coordinator_ms

    # The uncontended costs (no-op calls): on a real cluster every shard has its own core,
    # here 4 x 4 shards share 2, and a dispatcher's submissions wait behind their physics.
    # The driver's per call: the most nodes (it submits alone); a dispatcher's: one node
    # (with more, the dispatchers submit at once on this machine's 2 cores, not their own).
    shard, node = costs[(k, "shard", "noop")], dict(costs[(k, "node", "noop")])
    node["node_call_ms"] = costs[(min(kk for kk, _, _ in costs), "node", "noop")]["node_call_ms"]
    print(f"driver per call: {shard['call_ms'] * 1e3:.0f} us (one per shard), "
          f"{node['call_ms'] * 1e3:.0f} us (one per node); dispatcher per shard call "
          f"{node['node_call_ms'] * 1e3:.0f} us; round trip to a dispatcher {node['trip_ms']:.2f} ms", flush=True)
    per_action_ms, _ = coordinator_ms(domain, {}, [1000, 5000], repeats=3, with_loop=False)
    amdahl(per_action_ms, phys_ms, shard["call_ms"], node["trip_ms"], node_call_ms=node["node_call_ms"])


if __name__ == "__main__":
    sys.exit(main())
