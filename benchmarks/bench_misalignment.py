"""How a grasp's outcome depends on the perception error (issue 37; docs/LOOP.md,
"Perception in the likelihood"): the container's particle worlds, a pickup planned for a
believed size, the target block shifted by e along the fingers' closing axis and across
it. Prints, per world size, the finger opening each shift reads (0: the grasp missed),
then per size the largest |e| along the closing axis that still holds, against the
clearance per side, (opening - size) / 2.

    python benchmarks/bench_misalignment.py                       # believed 50.4 mm (57.9 open)
    python benchmarks/bench_misalignment.py --believed 0.0584     # a right belief at 58.4 mm
"""
from __future__ import annotations

import argparse
import os

import numpy as np

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from coordinator.distributed.fanout import ShardPool  # noqa: E402
from coordinator.run_config import RunConfig  # noqa: E402
from coordinator.loop.session import Session  # noqa: E402

ACTION = "pickup(r,b1,init)"
SHIFTS_MM = (-3.46, -2.0, -1.0, 0.0, 1.0, 2.0, 3.46)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--believed", type=float, default=0.0504, help="the size (m) the grasp is planned for")
    ap.add_argument("--sizes", default="0.045,0.052,0.055,0.057,0.0579,0.0585,0.060",
                    help="the worlds' block sizes (m), comma-separated")
    args = ap.parse_args()
    sizes = np.array([float(v) for v in args.sizes.split(",")])
    s = Session(RunConfig(true_size=float(sizes[0]), particles=len(sizes), seed=0, particle_budget="fixed"),
                shard_pool=ShardPool("container", {}, n_shards=0))
    d = s.domain
    config = d.initial_configuration(d.properties({"block_sizes": np.full(d.n_blocks, sizes[0])}))
    pose = d.action_pose(s.props_of(np.full(d.n_blocks, args.believed)), config, ACTION)
    traj = d.action_trajectory(config, ACTION, pose)
    t_pre = d.transit_end_time(config, ACTION, pose)
    row, along = d.misalignment(config, ACTION)
    across = np.array([along[1], -along[0]])
    rows = np.repeat(sizes[:, None], d.n_blocks, axis=1)
    print(f"grasp planned for {args.believed * 1000:.1f} mm: {pose[4] * 1000:.1f} mm open")
    held = {}
    for name, axis in (("along the closing axis", along), ("across it", across)):
        print(f"\n{name}: finger opening read (mm) per shift e (mm)")
        print("size  " + " ".join(f"{e:>6}" for e in SHIFTS_MM))
        table = []
        for e in SHIFTS_MM:
            start = config.to_array().copy()
            k = 5 + 7 * row
            start[k:k + 2] += e / 1000 * axis
            res = s.shard_pool.simulate(start, rows, ACTION, traj, t_pre)
            table.append(res["measurements"][:, 0] * 1000)
        table = np.array(table).T
        for size, readings in zip(sizes, table):
            print(f"{size * 1000:5.1f} " + " ".join(f"{r:6.0f}" for r in readings))
        if axis is along:
            for size, readings in zip(sizes, table):
                ok = [abs(e) for e, r in zip(SHIFTS_MM, readings) if r > 1.0]
                held[size] = max(ok) if ok and 0.0 in [e for e, r in zip(SHIFTS_MM, readings) if r > 1.0] else None
    print("\nsize  clearance/side  largest |e| along that holds (mm)")
    for size, e in held.items():
        c = (pose[4] - size) / 2 * 1000
        print(f"{size * 1000:5.1f} {c:14.2f}  {'-' if e is None else f'{e:.2f}'}")


if __name__ == "__main__":
    main()
