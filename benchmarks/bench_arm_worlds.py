"""Particle-actions per core-second with the arm's links in the worlds against the floating
gripper (issue 41), in each engine, on the steps of real episodes; measured in this run.

For each domain, one episode with the UR5e (8 particles, the noisy simulated UR5e reality)
records every step: its start, its action, the domain's own tool rows (what the floating
gripper runs), the arm's rows (toppra's timing of the same path, never faster) and its
joints. Then one in-process shard (one world, one core) replays every step for a batch of
particles drawn from the prior, three ways:

  gripper     the domain's own rows, no links (what a gripper run costs)
  arm rows    the arm's rows, no links (the timing alone)
  arm         the arm's rows with the links moving through the scene (what an arm run costs)

and prints particle-actions per core-second of each, ``ratio_arm_vs_gripper`` (issue 41's
aim: at least 0.7 in each engine) and ``link_overhead`` (arm against arm rows: what the
links alone cost).

    python benchmarks/bench_arm_worlds.py [--domains container,stack_and_push]
                                          [--engines pybullet,mujoco] [--particles 16]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import coordinator.loop.session as session_module
from coordinator.loop.reality import SimulatedReality
from coordinator.loop.session import Session
from coordinator.run_config import RunConfig
from sim_workers.shard import Shard


def record(domain: str, seed: int = 0) -> tuple[list[dict], dict]:
    """The steps of one UR5e episode: start, action, start time, both rows, the arm."""
    steps: list[dict] = []
    original = Session._arm_step

    def arm_step(self, config, step):
        rows = step.trajectory.copy()
        t_pre = step.transit_end
        ok = original(self, config, step)
        if ok:
            steps.append({"start": config.to_array(), "action": step.action, "gripper": rows,
                          "gripper_t0": t_pre, "arm_rows": step.trajectory, "arm_t0": step.transit_end,
                          "arm": step.arm})
        return ok

    session_module.Session._arm_step = arm_step
    try:
        cfg = RunConfig(domain=domain, particles=8, true_size=0.045, episodes=1, seed=seed, robot="ur5e")
        s = Session(cfg)
        opts = {"n_blocks": cfg.n_blocks, **cfg.options}
        reality = SimulatedReality(domain, opts, s.props_of(s.truth_row()))
        try:
            s.run_episode(reality, np.random.default_rng(seed))
        finally:
            reality.close()
    finally:
        session_module.Session._arm_step = original
    return steps, opts


def rate(shard: Shard, steps: list[dict], sizes: np.ndarray, mode: str) -> tuple[float, int]:
    """Particle-actions per second of `shard` over every step in `mode`; physics steps."""
    t0 = time.perf_counter()
    n_steps = 0
    for st in steps:
        if mode == "gripper":
            out = shard.simulate(st["start"], sizes, st["action"], st["gripper"], st["gripper_t0"])
        else:
            out = shard.simulate(st["start"], sizes, st["action"], st["arm_rows"], st["arm_t0"],
                                 arm=st["arm"] if mode == "arm" else None)
        n_steps += int(out["steps"].sum())
    return len(steps) * len(sizes) / (time.perf_counter() - t0), n_steps


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domains", default="container,stack_and_push")
    ap.add_argument("--engines", default="pybullet,mujoco")
    ap.add_argument("--particles", type=int, default=16)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    worst = {}
    for domain in args.domains.split(","):
        steps, opts = record(domain)
        sizes = rng.uniform(0.030, 0.060, (args.particles, 1))
        print(f"{domain}: {len(steps)} steps of one UR5e episode, {args.particles} particles each")
        for engine in args.engines.split(","):
            shard = Shard(domain, {**opts, "engine": engine}, n_worlds=1)
            try:
                rate(shard, steps[:2], sizes[:2], "arm")                     # warm: models compiled
                out = {m: rate(shard, steps, sizes, m) for m in ("gripper", "arm rows", "arm")}
            finally:
                shard.close()
            ratio = out["arm"][0] / out["gripper"][0]
            worst[engine] = min(worst.get(engine, np.inf), ratio)
            print(f"  {engine:9s} " + "  ".join(f"{m}: {r:7.1f} pa/s ({n} steps)" for m, (r, n) in out.items())
                  + f"  ratio_arm_vs_gripper={ratio:.2f}  link_overhead={out['arm rows'][0] / out['arm'][0]:.2f}")
    print("worst ratio_arm_vs_gripper: " + ", ".join(f"{e} {r:.2f}" for e, r in worst.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
