"""What the arm costs a counterfactual snapshot (issue 41): one snapshot of every context the
domain declares, with the floating gripper doing the trials and with the UR5e (planned,
timed by toppra and tracked as its steps are, its links in the world), in one process on
one core, and the contexts whose simulated success the two robots disagree on.

    python benchmarks/bench_arm_counterfactual.py [--domains container,stack_and_push]
                                                  [--rows 2] [--size 0.045]

Each robot's snapshot runs with the domain's options as that robot runs it
(``coordinator.robots.options_for``: an arm pushes with the open front finger where the
domain can). Prints, per domain: seconds per snapshot for each robot, their ratio, seconds
per trial, and the contexts whose success rates differ.
"""
from __future__ import annotations

import argparse
import os
import time
from functools import partial

import numpy as np

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from coordinator.distributed.fanout import ShardPool  # noqa: E402
from coordinator.domains import task_half  # noqa: E402
from coordinator.loop.arm_trials import ArmForTrials  # noqa: E402
from coordinator.robots import options_for  # noqa: E402
from coordinator.transition.counterfactual import simulate  # noqa: E402
from sim_workers.domains import load as load_world  # noqa: E402


def snapshot(domain: str, robot: str | None, rows: int, size: float, n_blocks: int) -> tuple[float, dict, int]:
    """(seconds, counts, trials) of one snapshot of `rows` rows at `size`, in this process."""
    options = {"n_blocks": n_blocks}
    physics0 = load_world(domain, **options)
    if robot is not None:
        options = options_for(robot, physics0, options)
    physics = load_world(domain, **options)
    pool = ShardPool(domain, options, n_shards=0)
    try:
        arm = None if robot is None else partial(ArmForTrials, robot)
        t0 = time.perf_counter()
        snap = simulate(pool, physics, ["size"], 1, np.full((rows, 1), size), np.full(rows, 1.0 / rows),
                        {"size": size}, rows, n_blocks, task_half(domain).contexts(n_blocks),
                        np.random.SeedSequence(0), 0, arm=arm)
        return time.perf_counter() - t0, snap.counts, snap.trials
    finally:
        pool.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--domains", default="container,stack_and_push")
    ap.add_argument("--rows", type=int, default=2, help="rows of L the snapshot draws (M)")
    ap.add_argument("--size", type=float, default=0.045, help="every row's and the belief's size (m)")
    ap.add_argument("--blocks", type=int, default=8)
    args = ap.parse_args(argv)
    import toppra  # noqa: F401  (imported once, before the clock: the arm's first plan would pay it)

    print("| domain | trials | gripper (s) | ur5e (s) | ur5e / gripper | ur5e s per trial | contexts that differ |")
    print("|---|---|---|---|---|---|---|")
    for domain in [d.strip() for d in args.domains.split(",") if d.strip()]:
        tg, cg, n = snapshot(domain, None, args.rows, args.size, args.blocks)
        ta, ca, _ = snapshot(domain, "ur5e", args.rows, args.size, args.blocks)
        differ = [f"{a} {k}: {cg[(a, k)][0]:g}/{cg[(a, k)][1]:g} vs {ca[(a, k)][0]:g}/{ca[(a, k)][1]:g}"
                  for a, k in sorted(cg) if (a, k) in ca and cg[(a, k)] != ca[(a, k)]]
        print(f"| {domain} | {n} | {tg:.1f} | {ta:.1f} | {ta / tg:.2f} | {ta / n:.3f} | "
              f"{'; '.join(differ) or 'none'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
