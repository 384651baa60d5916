"""Motion-planner latency: RRT* transit per action and straight approach per particle.

A container-domain-like scene of axis-aligned boxes (table, tray with low walls, a row of
blocks, a tall post between the block row and the tray so the transit needs a detour),
checked with the pure-geometry `box_checker` (a physics world's query costs more per call;
the report's validity-call counts let you scale). Each action plans the transit from above
a block to a pre-pose above the tray with RRT* (``plan_rrtstar``: the search always runs), once per
action, then one checked straight approach per particle to a jittered grasp pose.

    python benchmarks/bench_motion.py [--quick] [--actions 20] [--particles 100]

The last line is machine-readable: transit_median_ms=... approach_median_ms=...
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner.motion import (  # noqa: E402
    Bounds,
    MotionPlanningError,
    box_checker,
    plan_approach,
    plan_rrtstar,
)

BLOCK = 0.045


def scene() -> list[tuple[np.ndarray, np.ndarray]]:
    """Boxes (center, half extents) in metres; table top at z = 0."""
    boxes = [(np.array([0.3, 0.0, -0.02]), np.array([0.8, 0.5, 0.02]))]  # table
    # tray at x = 0.4: floor 0.1 x 0.06 inside, walls 0.035 high and 5 mm thick
    tx, ty, hx, hy, h, t = 0.4, 0.0, 0.05, 0.03, 0.035, 0.0025
    boxes += [
        (np.array([tx, ty, 0.0025]), np.array([hx + 2 * t, hy + 2 * t, 0.0025])),
        (np.array([tx - hx - t, ty, h / 2]), np.array([t, hy + 2 * t, h / 2])),
        (np.array([tx + hx + t, ty, h / 2]), np.array([t, hy + 2 * t, h / 2])),
        (np.array([tx, ty - hy - t, h / 2]), np.array([hx + 2 * t, t, h / 2])),
        (np.array([tx, ty + hy + t, h / 2]), np.array([hx + 2 * t, t, h / 2])),
    ]
    for i in range(8):  # the block row at init, along y
        boxes.append((np.array([0.0, -0.21 + 0.06 * i, BLOCK / 2]), np.full(3, BLOCK / 2)))
    boxes.append((np.array([0.2, 0.0, 0.2]), np.array([0.03, 0.15, 0.2])))  # a tall post
    return boxes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="few actions and particles (smoke run)")
    ap.add_argument("--actions", type=int, default=20, help="actions (RRT* transits) to time")
    ap.add_argument("--particles", type=int, default=100, help="particles per action")
    ap.add_argument("--iterations", type=int, default=500, help="RRT* iterations per transit")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.quick:
        args.actions, args.particles = 5, 20

    bounds = Bounds(np.array([-0.3, -0.5, 0.0, -math.pi]), np.array([0.9, 0.5, 0.6, math.pi]))
    # Grasp poses put the fingers around the target block, so the checker is the scene
    # without the block being approached (the caller's job with a physics world too).
    boxes = scene()
    gripper = (0.015, 0.06, 0.02)
    rng = np.random.default_rng(args.seed)

    transit_ms: list[float] = []
    approach_ms: list[float] = []
    action_ms: list[float] = []
    calls: list[int] = []
    blocked = 0
    for a in range(args.actions):
        block_i = a % 8
        target = boxes[6 + block_i][0]
        chk = box_checker([b for k, b in enumerate(boxes) if k != 6 + block_i], gripper)
        start = np.array([0.4, 0.0, 0.15, 0.0])                     # above the tray
        pre = np.array([target[0], target[1], 0.15, math.pi / 2])   # above the block, turned
        x = np.column_stack([
            np.full(args.particles, target[0]) + rng.normal(0, 0.004, args.particles),
            np.full(args.particles, target[1]) + rng.normal(0, 0.004, args.particles),
            rng.uniform(0.023, 0.035, args.particles),
            np.full(args.particles, math.pi / 2) + rng.normal(0, 0.05, args.particles),
        ])
        n_calls = [0]

        def counted(q, chk=chk):
            n_calls[0] += 1  # noqa: B023 (called within this iteration)
            return chk(q)

        t0 = time.perf_counter()
        try:
            transit = plan_rrtstar(start, pre, counted, bounds, seed=args.seed + a,
                                   iterations=args.iterations)
        except MotionPlanningError as exc:
            print(f"action {a}: {exc}")
            continue
        transit_ms.append(1e3 * (time.perf_counter() - t0))
        calls.append(n_calls[0])
        for xi in x:  # each particle's approach from the shared pre-pose, timed on its own
            t1 = time.perf_counter()
            try:
                plan_approach(transit[-1], xi, chk, bounds=bounds)
            except MotionPlanningError:
                blocked += 1
            approach_ms.append(1e3 * (time.perf_counter() - t1))
        action_ms.append(transit_ms[-1] + sum(approach_ms[-len(x):]))

    if not transit_ms:
        print("no action could be planned")
        return 1
    print(f"actions={len(transit_ms)} particles={args.particles} iterations={args.iterations}")
    print(f"transit RRT* (checks, solve, simplify, interpolation): median {statistics.median(transit_ms):.1f} ms, "
          f"max {max(transit_ms):.1f} ms, median validity calls {int(statistics.median(calls))}")
    print(f"approach per particle: median {statistics.median(approach_ms):.3f} ms "
          f"({blocked} of {len(approach_ms)} blocked)")
    print(f"whole action (transit + {args.particles} approaches): "
          f"median {statistics.median(action_ms):.1f} ms")
    print(f"transit_median_ms={statistics.median(transit_ms):.2f} "
          f"approach_median_ms={statistics.median(approach_ms):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
