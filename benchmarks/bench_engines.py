"""Particle-actions per core-second in both engines, on the same particles and trajectories.

For each domain's three actions (the workload of ``bench_worlds``: pickup(r,b3,init); a
stack onto a pile or tower of two, starting from a real grasp; a push of four blocks), one
batch of particles (sizes drawn from the prior) replays one trajectory from Y with the
true size, from the pre-pose, in one ``sim_workers.shard.Shard`` per engine (the service's
particle worlds: pybullet leaves out what an action cannot reach; MuJoCo's bodies at rest
sleep). Time is the process's CPU time (``time.process_time``), so the figure is per core
whatever else the machine does; best of ``--rounds``.

Printed per domain and action: milliseconds per particle-action in each engine, the ratio
(MuJoCo's particle-actions per core-second over pybullet's), and the agreement of the
outcomes particle by particle: the share with the same Y^-1 (symbolic state) and the
largest difference of each weighed measurement channel in its sensor sigmas; beside MuJoCo's
time, the same particles in the one-step loop (a Python call per physics step, as before
the worlds stepped in blocks: ``sim_workers/engines/mujoco_world.py``), checked
bit-identical; and the share of MuJoCo's time in its stepping calls. The last line
is the ratio over all six actions (total particle-actions over total CPU seconds).

    python benchmarks/bench_engines.py --quick     # 16 particles, 1 round (about a minute)
    python benchmarks/bench_engines.py             # 64 particles, best of 3
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from bench_worlds import DOMAINS, make_cases, particle_sizes  # noqa: E402

from sim_workers.domains import load  # noqa: E402
from sim_workers.engines import ENGINES, installed  # noqa: E402
from sim_workers.shard import Shard  # noqa: E402


class StepClock:
    """CPU seconds MuJoCo worlds spend in their stepping calls (``MujocoWorld._advance``:
    one ``rollout`` or ``mj_step(nstep)`` per block, with the few arrays it fills)."""

    def __init__(self) -> None:
        from sim_workers.engines.mujoco_world import MujocoWorld

        self.seconds = 0.0
        clock, advance = self, MujocoWorld._advance

        def _advance(world, rows, logging):
            t = time.process_time()
            out = advance(world, rows, logging)
            clock.seconds += time.process_time() - t
            return out

        MujocoWorld._advance = _advance


class OneStepLoop:
    """Within the block: MuJoCo worlds stepped by the engine-neutral one-step loop
    (``GroundedWorld._run``: a Python call per physics step), as before batching."""

    def __enter__(self):
        from sim_workers.engines.mujoco_world import MujocoWorld
        from sim_workers.grounded_world import GroundedWorld

        self.blocked, MujocoWorld._run = MujocoWorld._run, GroundedWorld._run
        return self

    def __exit__(self, *exc):
        from sim_workers.engines.mujoco_world import MujocoWorld

        MujocoWorld._run = self.blocked


def identical(a: dict, b: dict) -> bool:
    return all(np.array_equal(a[k], b[k], equal_nan=True) for k in ("configurations", "measurements", "steps")) \
        and bool(np.all(a["states"] == b["states"]))


def run_case(shard: Shard, case, rows: np.ndarray, rounds: int) -> tuple[float, dict]:
    """(best CPU seconds over `rounds`, the outcome arrays) of one batch."""
    start, action, traj, t0 = case
    shard.simulate(start, rows[:1], action, traj, t0)          # warm: imports, first compile
    best, out = np.inf, None
    for _ in range(rounds):
        c0 = time.process_time()
        out = shard.simulate(start, rows, action, traj, t0)
        best = min(best, time.process_time() - c0)
    return best, out


def agreement(domain, a: dict, b: dict) -> tuple[float, list[float]]:
    """Share of particles with the same symbolic outcome, and per weighed channel the
    largest difference between the engines in sensor sigmas."""
    same = float(np.mean(a["states"] == b["states"]))
    idx, sig = domain.measurement_model()
    idx, sig = np.atleast_1d(idx), np.broadcast_to(np.asarray(sig, dtype=np.float64), np.shape(np.atleast_1d(idx)))
    diffs = [float(np.max(np.abs(a["measurements"][:, i] - b["measurements"][:, i])) / s)
             for i, s in zip(idx, sig)]
    return same, diffs


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="16 particles, 1 round")
    p.add_argument("--particles", type=int, default=None)
    p.add_argument("--rounds", type=int, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--domains", default=",".join(DOMAINS))
    args = p.parse_args(argv)
    n = args.particles or (16 if args.quick else 64)
    rounds = args.rounds or (1 if args.quick else 3)
    missing = [e for e in ENGINES if not installed(e)]
    if missing:
        sys.exit(f"bench_engines: needs both engines ({', '.join(missing)} not installed)")
    print(f"bench_engines: {n} particles per action, best of {rounds}, CPU time per particle-action")
    total = {e: [0.0, 0] for e in ENGINES}
    clock = StepClock()
    total_loop, same_bits = [0.0], True
    mujoco_all = 0.0           # every round and warm-up, as the clock counts
    for name in args.domains.split(","):
        domain = load(name)
        cases = make_cases(domain, args.seed)
        rows = particle_sizes(domain, n, args.seed)[:, :1]
        shards = {e: Shard(name, {"engine": e}) for e in ENGINES}
        for action, case in cases.items():
            secs, outs = {}, {}
            for e in ENGINES:
                c0 = time.process_time()
                secs[e], outs[e] = run_case(shards[e], case, rows, rounds)
                if e == "mujoco":
                    mujoco_all += time.process_time() - c0
                total[e][0] += secs[e]
                total[e][1] += n
            with OneStepLoop():
                loop_secs, loop_out = run_case(shards["mujoco"], case, rows, rounds)
            total_loop[0] += loop_secs
            same_bits &= identical(loop_out, outs["mujoco"])
            ms = {e: 1000.0 * secs[e] / n for e in ENGINES}
            same, diffs = agreement(domain, outs["pybullet"], outs["mujoco"])
            steps = {e: float(np.mean(outs[e]["steps"])) for e in ENGINES}
            print(f"{name:<15} {action:<7} pybullet {ms['pybullet']:6.2f} ms ({steps['pybullet']:.0f} steps)  "
                  f"mujoco {ms['mujoco']:6.2f} ms ({steps['mujoco']:.0f} steps; one-step loop "
                  f"{1000.0 * loop_secs / n:6.2f} ms)  "
                  f"ratio {ms['pybullet'] / ms['mujoco']:4.2f}  same Y^-1 {same:5.1%}  "
                  f"weighed channels max diff {', '.join(f'{d:.2f}' for d in diffs)} sigma")
        for s in shards.values():
            s.close()
    rate = {e: total[e][1] / total[e][0] for e in ENGINES}
    print(f"MuJoCo time in its stepping calls: {clock.seconds / mujoco_all:.0%} (the rest is Python per particle and block)")
    print(f"MuJoCo stepped in blocks against the one-step loop: x{total_loop[0] / total['mujoco'][0]:.2f} "
          f"particle-actions per core-second, outcomes {'bit-identical' if same_bits else 'DIFFERENT'}")
    print(f"particle-actions per core-second: pybullet {rate['pybullet']:.1f}, mujoco {rate['mujoco']:.1f}")
    print(f"ratio_mujoco_vs_pybullet={rate['mujoco'] / rate['pybullet']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
