"""The arm's kinematics per call (issue 41): forward kinematics, the closed-form inverse with
every branch, and the branch the arm takes (nearest its joints within the limits), over random
reachable tool poses; median and p95 in microseconds on one core, and their ratios to the
forward kinematics, measured in this run.

    python benchmarks/bench_robot_kinematics.py [--robot ur5e] [--poses 2000] [--seed 0]
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from sim_workers.robots import robot
from sim_workers.robots.kinematics import forward, inverse


def _timed(fn, items) -> np.ndarray:
    out = np.empty(len(items))
    for i, item in enumerate(items):
        t0 = time.perf_counter()
        fn(item)
        out[i] = time.perf_counter() - t0
    return out * 1e6


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="ur5e")
    ap.add_argument("--poses", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    arm = robot(args.robot)
    rng = np.random.default_rng(args.seed)
    qs = rng.uniform(arm.low, arm.high, size=(args.poses, len(arm.joints)))
    flanges = [forward(arm.dh, q) for q in qs]
    # Tool points a task asks for: over a table in front of the arm, pointing down.
    targets = [(rng.uniform(0.25, 0.6), rng.uniform(-0.4, 0.4), rng.uniform(0.02, 0.3), rng.uniform(-math.pi, math.pi))
               for _ in range(args.poses)]
    fk = _timed(lambda q: forward(arm.dh, q), qs)
    ik = _timed(lambda t: inverse(arm.dh, t), flanges)
    take = _timed(lambda t: arm.joints_for(*t, arm.home), targets)
    print(f"{args.robot}, {args.poses} poses, one core (microseconds: median / p95; ratio of medians to FK)")
    for name, t in (("forward kinematics", fk), ("inverse, every branch", ik), ("the branch taken (joints_for)", take)):
        print(f"  {name:30s} {np.median(t):8.1f} / {np.percentile(t, 95):8.1f}   x{np.median(t) / np.median(fk):.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
