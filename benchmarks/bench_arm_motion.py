"""An arm's motion per action (issue 41): the joint trajectory for each step of real
episodes (inverse kinematics along the tool path to 1 mm, every link checked against the
believed scene, joint-space RRT* where the transit cannot be followed, toppra's timing);
median and p95 in milliseconds on one core, the share of the timing in it, and the actions
the arm cannot do, by reason, measured in this run.

    python benchmarks/bench_arm_motion.py [--robot ur5e] [--domains container,stack_and_push] [--seeds 3]

The episodes are the floating gripper's (seeded sessions, 8 particles, the noisy simulated
reality at 45 mm); each step's tool rows, scene and transit are then planned for the arm from
the joints the arm would stand at.
"""
from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

from coordinator.loop.arm_motion import ArmPlanningError, plan_arm_step, robot_of, start_joints
from coordinator.loop.reality import SimulatedReality
from coordinator.loop.session import Session
from coordinator.loop.transit import transit_checker
from coordinator.run_config import RunConfig
from planner.motion.joint_space import time_joint_path


def _steps(domain: str, seed: int) -> tuple[Session, list[tuple]]:
    """(session, [(configuration, step, clearance sizes, held size)]) of one gripper episode."""
    cfg = RunConfig(domain=domain, particles=8, true_size=0.045, episodes=1, seed=seed, max_steps=20)
    s = Session(cfg)
    reality = SimulatedReality(domain, {"n_blocks": cfg.n_blocks}, s.props_of(s.truth_row()))
    out = []
    try:
        s.start_episode(reality.start_episode(np.random.default_rng(seed)))
        while (step := s.next_step()) is not None:
            sizes = s.clearance_sizes()
            out.append((s.observation.configuration, step, sizes, s._held_size(sizes)))
            report = s.observe(reality.execute(step.trajectory, step.action))
            if "episode" in report:
                break
    finally:
        reality.close()
    return s, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", default="ur5e")
    ap.add_argument("--domains", default="container,stack_and_push")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args(argv)
    for domain in args.domains.split(","):
        total, timing, failed, rrt = [], [], Counter(), 0
        for seed in range(args.seeds):
            s, steps = _steps(domain, seed)
            arm = robot_of(args.robot, s.domain)
            q = None
            for config, step, sizes, held in steps:
                obstacles = s.domain.obstacles(config, sizes)
                opening = float(np.max(step.trajectory[:, 5]))
                t0 = time.perf_counter()
                try:
                    start = q if q is not None else start_joints(arm, config.robot, obstacles)
                    plan = plan_arm_step(arm, step.trajectory, obstacles, start=start, seed=seed,
                                         transit_end=step.transit_end,
                                         tool_valid=transit_checker(s.domain, config, sizes, held, opening))
                except ArmPlanningError as exc:
                    failed[f"{step.action.split('(')[0]}: {str(exc).split(': ', 1)[-1][:60]}"] += 1
                    q = None
                    continue
                total.append(time.perf_counter() - t0)
                rrt += plan.replanned > 0
                t1 = time.perf_counter()
                time_joint_path(plan.path.q, np.array([j.max_velocity for j in arm.joints]),
                                np.full(len(arm.joints), arm.acceleration),
                                nominal_dt=None)
                timing.append(time.perf_counter() - t1)
                q = plan.end
        ms = np.array(total) * 1e3
        tm = np.array(timing) * 1e3
        n = len(ms) + sum(failed.values())
        print(f"{domain}: {n} actions, {len(ms)} planned for {args.robot} ({rrt} with a joint-space move)")
        if len(ms):
            print(f"  plan per action: median {np.median(ms):.1f} ms, p95 {np.percentile(ms, 95):.1f} ms, "
                  f"max {ms.max():.1f} ms")
            print(f"  of which timing (toppra): median {np.median(tm):.1f} ms "
                  f"(ratio {np.median(tm) / np.median(ms):.2f} of the plan)")
        for why, k in failed.most_common():
            print(f"  cannot: {k} x {why}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
