"""Scaling over nodes: particle-actions per second with 1, 2, ... Ray nodes of 1 CPU each.

A ``ray.cluster_utils.Cluster`` on this machine (every node its own raylet, as separate
machines would be; its CPU count is Ray's logical resource, the OS shares this machine's
cores). The workload is bench_worlds' three actions (pickup, stack onto a pile, push a
loaded tray), one batch of particles (sizes from the prior) per action, sent through a
``coordinator.distributed.fanout.ShardPool`` exactly as a run does: one remote call per shard per
action. With k nodes the pool holds one shard per node (it is re-planned with
``refresh()`` after each node joins, as the service does between tasks).

Prints one line per node count (particle-actions, seconds, throughput) and, last,
``efficiency=<throughput_2 / (2 x throughput_1)>``. With ``--max-nodes N`` (N up to the
cores of the machine) it also prints the curve ``efficiency_k = throughput_k / (k x
throughput_1)``.

    python benchmarks/bench_scaling.py                # 1 and 2 nodes, ~30 s on 2 cores
    python benchmarks/bench_scaling.py --max-nodes 8  # the curve, on a machine with 8 cores
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--particles", type=int, default=48, help="particles per action")
    ap.add_argument("--rounds", type=int, default=3, help="times every action is run")
    ap.add_argument("--max-nodes", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domain", default="container", help="a registered domain (tmoc domains)")
    args = ap.parse_args(argv)
    if args.max_nodes < 2:
        ap.error("--max-nodes: at least 2")
    if args.max_nodes > (os.cpu_count() or 1):
        print(f"note: {args.max_nodes} nodes on {os.cpu_count()} cores: the nodes share cores")

    import ray
    from ray.cluster_utils import Cluster

    domain = load(args.domain)
    cases = make_cases(domain, args.seed) if args.domain == "container" else domain_cases(args.domain)
    sizes = particle_sizes(domain, args.particles, args.seed + 1)
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    results = {}
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
    print(f"efficiency={results[2] / (2 * results[1]):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
