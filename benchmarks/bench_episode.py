"""Wall time of one TMOC episode on local Ray, split into physics, planning and Ray overhead.

    python benchmarks/bench_episode.py [--domain NAME] [--particles 100] [--quick]

Particle-actions per second over the episode are printed with the physics share of the
episode's wall time, and against pybullet stepping the resting scene for the same number of
steps in 2 plain processes (an upper bound no action reaches; bench_worlds.py measures the
limit for the same action physics).
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time


sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from coordinator.run_config import RunConfig  # noqa: E402
from coordinator.loop.runner import run  # noqa: E402


def raw_steps_per_second(args: tuple[str, int]) -> float:
    """pybullet stepping of the domain's scene (blocks resting, gripper held), one core."""
    import pybullet as pb

    from sim_workers.domains import load
    from sim_workers.engines.pybullet_engine import build_scene

    domain, steps = args
    d = load(domain)
    c = pb.connect(pb.DIRECT)
    build_scene(c, d.scene_description(d.properties(d.true_properties())))
    t0 = time.perf_counter()
    for _ in range(steps):
        pb.stepSimulation(physicsClientId=c)
    dt = time.perf_counter() - t0
    pb.disconnect(c)
    return steps / dt


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", default="container", help="a registered domain (tmoc domains)")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="24 particles")
    args = ap.parse_args()
    n = 24 if args.quick else args.particles
    cfg = RunConfig(domain=args.domain, agent="tmoc", particles=n, episodes=1, seed=args.seed)
    t0 = time.perf_counter()
    result = run(cfg)
    wall = time.perf_counter() - t0
    ep = result["episodes"][0]
    rt = result["runtime"]
    pa = rt["particle_actions"]
    physics = ep["physics_s"]
    planning = ep["planning_s"]
    real = ep["wall_s"] - physics - planning
    with mp.Pool(2) as pool:
        raw = sum(pool.map(raw_steps_per_second, [(args.domain, 4000)] * 2))
    steps_per_pa = rt["particle_steps"] / pa   # measured in this run
    raw_pa = raw / steps_per_pa
    print(f"domain={args.domain} particles={n} actions={ep['actions']} loads={ep['loads']} utility={ep['utility']}")
    print(f"episode_wall_s={ep['wall_s']:.2f} (run incl. Ray start {wall:.2f})")
    print(f"  particle physics (Ray wait) {physics:.2f} s, planning (clingo + OMPL) {planning:.2f} s, "
          f"real world + Y + bookkeeping {real:.2f} s")
    print(f"particle_actions={pa} -> {pa / physics:.1f}/s during physics, {pa / ep['wall_s']:.1f}/s over the episode")
    print(f"physics share of the episode: {physics / ep['wall_s']:.2f}")
    print(f"raw stepping of a resting scene, 2 processes: {raw:.0f} steps/s = {raw_pa:.1f} "
          f"particle-actions/s at {steps_per_pa:.0f} steps each (not reachable by actions, whose")
    print("  moving contacts use every solver iteration; benchmarks/bench_worlds.py measures the")
    print("  limit for the same action physics, ratio_vs_raw there)")
    print(f"ratio_vs_static_scene={pa / physics / raw_pa:.3f}")


if __name__ == "__main__":
    main()
