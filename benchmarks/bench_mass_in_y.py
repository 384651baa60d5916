"""What learning the weight costs per particle-action (issue 14), measured in one run.

Stack-and-push, one in-process shard, the same particle batch for each action kind
(pickup of b3, stack of b3 onto a tower of two, push of a tower of four), replayed from
the pre-pose as particle worlds do, in two settings:

  size only         L = size, the scene's fixed grip force and wrist limit, no sensor log;
  log only          L = (size, density) and the sensor log, but the fixed grip and limit
                    (--option force_from_mass=false): what sensing alone costs;
  mass in Y         --option unknown_density=true: L = (size, density), the grip force and
                    the push's force limit from the believed mass (a guarded, gravity-
                    compensated push), the wrist force and opening logged every step.

Prints microseconds per physics step and milliseconds per particle-action for each, and
``ratio=`` (mass in Y / size only) per action and over all three (and the log alone's).

    python benchmarks/bench_mass_in_y.py            # 32 particles, best of 3
    python benchmarks/bench_mass_in_y.py --quick    # 12 particles, best of 2
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from sim_workers.domains import load
from sim_workers.engines import make_world
from sim_workers.shard import Shard
from sim_workers.stack_and_push.probes import tower_configuration

TRUE = (0.045, 2400.0)
SETTINGS = {"size only": {}, "log only": {"unknown_density": True, "force_from_mass": False},
            "mass in Y": {"unknown_density": True}}


def cases(options: dict, seed: int) -> dict:
    """(start array, action, trajectory, start time) per action kind, Y at the truth."""
    d = load("stack_and_push", **options)
    sizes = np.full(8, TRUE[0])
    truth = {"block_sizes": sizes, "density": TRUE[1]}
    rng = np.random.default_rng(seed)
    out = {}
    with make_world(d) as w:
        for kind, load_k, action in (("pickup", 0, "pickup(r,b3,init)"), ("stack", 2, "stack(r,b3,tower)"),
                                     ("push", 4, "push(r,tower,start,goal)")):
            config = w.reset(tower_configuration(d, sizes, load_k, rng), truth)
            if kind == "stack":          # hold b3 first: the stack starts in the hand
                key = d.action_pose(truth, config, "pickup(r,b3,init)")
                traj = d.action_trajectory(config, "pickup(r,b3,init)", key)
                config = w.execute(traj, "pickup(r,b3,init)",
                                   start_time=d.transit_end_time(config, "pickup(r,b3,init)", key)).configuration
            key = d.action_pose(truth, config, action)
            traj = d.action_trajectory(config, action, key)
            out[kind] = (config.to_array(), action, traj, d.transit_end_time(config, action, key))
    return out


def rows(options: dict, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    size = rng.uniform(0.040, 0.050, n)
    if options.get("unknown_density"):
        return np.column_stack([size, rng.uniform(1800.0, 3000.0, n)])
    return size[:, None]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--particles", type=int, default=None)
    ap.add_argument("--rounds", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    n = args.particles or (12 if args.quick else 32)
    rounds = args.rounds or (2 if args.quick else 3)
    print(f"stack_and_push, {n} particles per action, best of {rounds}, one in-process shard")
    per = {}
    for label, options in SETTINGS.items():
        shard = Shard("stack_and_push", options, 1)
        batch = rows(options, n, args.seed + 1)
        per[label] = {}
        for kind, (start, action, traj, t0) in cases(options, args.seed).items():
            shard.simulate(start, batch[:2], action, traj, t0)             # warm up
            best, steps = np.inf, 0
            for _ in range(rounds):
                tic = time.perf_counter()
                res = shard.simulate(start, batch, action, traj, t0)
                best = min(best, time.perf_counter() - tic)
                steps = int(res["steps"].sum())
            per[label][kind] = (best, steps)
            print(f"  {label:10s} {kind:6s}: {best / n * 1e3:6.2f} ms per particle-action, "
                  f"{steps / n:5.0f} steps, {best / steps * 1e6:6.1f} us per step")
        shard.close()
    total = {k: sum(v[0] for v in per[k].values()) for k in per}
    for kind in per["size only"]:
        a, b, c = (per[k][kind][0] for k in ("size only", "log only", "mass in Y"))
        print(f"ratio_{kind}={c / a:.3f}  (log only: {b / a:.3f})")
    print(f"ratio_log_only={total['log only'] / total['size only']:.3f}  (all three actions)")
    print(f"ratio={total['mass in Y'] / total['size only']:.3f}  (mass in Y / size only, all three actions)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
