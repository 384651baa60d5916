"""A Gymnasium agent against TMOC on the same truths and seeds (issue 28).

The agent is tabular Q-learning over symbolic states on the Gymnasium view
(``coordinator/gym_baselines.py``), every action grounded at the prior's mean size: it
knows the task's actions and nothing of L. TMOC is ``tmoc run`` with the embedded
defaults (32 particles) at the same truth and seed. Both run the container with
``--blocks`` blocks; the truths span the prior. Printed per truth and seed: TMOC's mean
utility over its episodes and in its last; Q's over the same number of episodes, over its
last ten of ``--q-episodes``, and greedy after them (5 episodes, no exploration); and the
share of Q's learning episodes that reached the goal.

    python benchmarks/bench_gym_agent.py                  # 3 truths, seed 0: ~7 min on 2 cores
    python benchmarks/bench_gym_agent.py --seeds 0,1      # more seeds
    python benchmarks/bench_gym_agent.py --quick          # the middle truth only

A truth the prior's mean does not grasp (25 % off) keeps Q at max_steps failed pickups
every episode: those runs take minutes.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from coordinator.baselines.gym_baselines import tabular_q  # noqa: E402
from coordinator.integrations.gym_env import TmocEnv  # noqa: E402
from coordinator.run_config import RunConfig  # noqa: E402
from coordinator.loop.runner import run  # noqa: E402


def tmoc_utilities(truth: float, seed: int, blocks: int, episodes: int) -> list[float]:
    config = RunConfig(domain="container", n_blocks=blocks, true_size=truth, seed=seed, episodes=episodes)
    return [float(e["utility"]) for e in run(config)["episodes"]]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true")
    p.add_argument("--blocks", type=int, default=4)
    p.add_argument("--episodes", type=int, default=8, help="TMOC's episodes (and Q's first window)")
    p.add_argument("--q-episodes", type=int, default=100)
    p.add_argument("--truths", default="0.035,0.045,0.055")
    p.add_argument("--seeds", default="0")
    args = p.parse_args(argv)
    truths = [float(t) for t in args.truths.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.quick:
        truths, seeds = truths[1:2], seeds[:1]
    print(f"bench_gym_agent: container, {args.blocks} blocks; TMOC {args.episodes} episodes; "
          f"tabular Q (prior-mean grounding) {args.q_episodes} episodes, then 5 greedy")
    print(f"{'truth':>7} {'seed':>4} | {'TMOC mean':>9} {'last':>6} | {'Q first':>8} {'Q last10':>8} "
          f"{'Q greedy':>8} {'Q goal':>6} | {'TMOC s':>6} {'Q s':>5}")
    rows = []
    for truth in truths:
        for seed in seeds:
            t0 = time.perf_counter()
            tm = tmoc_utilities(truth, seed, args.blocks, args.episodes)
            t1 = time.perf_counter()
            env = TmocEnv("container", n_blocks=args.blocks, truth=[truth])
            q = tabular_q(env, args.q_episodes, np.random.default_rng(seed), seed=seed * 100000)
            greedy = tabular_q(env, 5, np.random.default_rng(seed), seed=seed * 100000 + 50000,
                               greedy=True, table=q.table)
            env.close()
            t2 = time.perf_counter()
            row = (truth, seed, np.mean(tm), tm[-1], np.mean(q.returns[:args.episodes]),
                   np.mean(q.returns[-10:]), np.mean(greedy.returns), np.mean(q.reached_goal))
            rows.append(row)
            print(f"{truth * 1000:5.1f}mm {seed:>4} | {row[2]:9.1f} {row[3]:6.1f} | {row[4]:8.1f} {row[5]:8.1f} "
                  f"{row[6]:8.1f} {row[7]:6.0%} | {t1 - t0:6.0f} {t2 - t1:5.0f}")
    a = np.array([r[2:] for r in rows])
    print(f"{'mean':>12} | {a[:, 0].mean():9.1f} {a[:, 1].mean():6.1f} | {a[:, 2].mean():8.1f} "
          f"{a[:, 3].mean():8.1f} {a[:, 4].mean():8.1f} {a[:, 5].mean():6.0%} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
