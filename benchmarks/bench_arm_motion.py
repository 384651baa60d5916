"""An arm's motion per action (issue 41): whole episodes run with the arm (`robot` ur5e),
every step's joint trajectory planned as the session plans it (inverse kinematics along the
tool path to 1 mm, every link checked against the believed scene, a joint-space transit by
RRT* where the path cannot be followed, toppra's timing); the planning time per action
(median, p95, max, ms on one core), the share of actions that needed a joint-space transit,
the actions the arm could not do (a failed attempt to T, then a new plan) and the episodes
that ended because the arm could not do an action, with why; measured in this run.

    python benchmarks/bench_arm_motion.py [--robot ur5e] [--domains container,stack_and_push]
                                          [--sizes 0.033,0.045,0.057] [--seeds 2] [--objects N]

Each episode: 8 particles, the noisy simulated reality, the domain's own object count unless
--objects is given.
"""
from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

import coordinator.loop.session as session_module
from coordinator.loop.reality import SimulatedReality
from coordinator.loop.session import Session
from coordinator.run_config import RunConfig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="ur5e")
    ap.add_argument("--domains", default="container,stack_and_push")
    ap.add_argument("--sizes", default="0.033,0.045,0.057")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--objects", type=int, default=None)
    args = ap.parse_args(argv)
    plan = session_module.plan_arm_step
    times: list[float] = []
    plans: list = []

    def timed(*a, **kw):                       # the session's own call, timed
        t0 = time.perf_counter()
        out = plan(*a, **kw)
        times.append(time.perf_counter() - t0)
        plans.append(out)
        return out

    session_module.plan_arm_step = timed
    for domain in args.domains.split(","):
        times.clear()
        plans.clear()
        ended, refused, episodes, utilities = Counter(), Counter(), 0, []
        for size in (float(s) for s in args.sizes.split(",")):
            for seed in range(args.seeds):
                extra = {} if args.objects is None else {"n_blocks": args.objects}
                cfg = RunConfig(domain=domain, particles=8, true_size=size, episodes=1, seed=seed,
                                robot=args.robot, **extra)
                s = Session(cfg)
                reality = SimulatedReality(domain, {"n_blocks": cfg.n_blocks, **cfg.options}, s.props_of(s.truth_row()))
                try:
                    ep = s.run_episode(reality, np.random.default_rng(seed))
                finally:
                    reality.close()
                episodes += 1
                utilities.append(ep["utility"])
                for why in s.stats.arm_refusals:
                    action, _, reason = why[len("the arm cannot "):].partition(": ")
                    refused[f"{action.split('(')[0]}: {reason.rpartition('): ')[2][:70]}"] += 1
                if s.stats.dead_end and s.stats.dead_end.startswith("the arm cannot"):
                    action, _, why = s.stats.dead_end[len("the arm cannot "):].partition(": ")
                    ended[f"{action.split('(')[0]}: {why.rpartition('): ')[2][:70]}"] += 1
        ms = np.array(times) * 1e3
        joint = sum(p.replanned > 0 for p in plans)
        print(f"{domain}: {episodes} episodes ({args.sizes} m x {args.seeds} seeds), {len(ms)} actions planned "
              f"for {args.robot}, {joint} with a joint-space transit; mean utility {np.mean(utilities):.1f}")
        if len(ms):
            print(f"  plan per action: median {np.median(ms):.1f} ms, p95 {np.percentile(ms, 95):.1f} ms, "
                  f"max {ms.max():.1f} ms")
        print(f"  actions the arm could not do (each a failed attempt to T, then a new plan): "
              f"{sum(refused.values())}")
        for why, k in refused.most_common():
            print(f"    {k} x {why}")
        print(f"  episodes ended by an action the arm cannot do: {sum(ended.values())} of {episodes}")
        for why, k in ended.most_common():
            print(f"    {k} x {why}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
