"""Drive a TMOC robot session over HTTP, start to finish, with the Python client.

The "robot" here is a simulated one (a pybullet world holding a hidden block size that
the service does not know); a real integrator replaces `robot.execute` with their
driver (the trajectory's columns are t, x, y, z, yaw, opening of the gripper's tool
point) and `robot.start_episode` with the robot's observed scene.

With `--robot ur5e` the robot is the simulated UR5e (a position-controlled arm in MuJoCo):
it runs each step's `joint_trajectory` (a FollowJointTrajectory goal) from the JSON alone,
with the arm's base where `GET /v1/domains` says the domain puts it, and reports the joints
it reached with its observation, as a real arm's driver does (docs/SERVICE.md, "Driving a
UR5e").

    tmoc serve --port 8000 &
    python docs/examples/robot_loop.py --url http://127.0.0.1:8000 --episodes 2
    python docs/examples/robot_loop.py --robot ur5e --episodes 4 --true-size 0.045

With TMOC_API_TOKEN set on the server, pass --token (or set TMOC_API_TOKEN here too).
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

from api.client import TMOCClient
from coordinator.loop.reality import SimulatedReality
from sim_workers.robots.motion import ArmMotion


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--token", default=os.environ.get("TMOC_API_TOKEN"))
    ap.add_argument("--domain", default="container", help="a block domain: container or stack_and_push")
    ap.add_argument("--robot", default="gripper", help="gripper (the tool rows) or ur5e (the joint trajectory)")
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--particles", type=int, default=16)
    ap.add_argument("--max-steps", type=int, default=30)
    ap.add_argument("--true-size", type=float, default=0.050, help="the robot's hidden block size (m)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    robot = SimulatedReality(args.domain, {"n_blocks": 8}, {"block_sizes": np.full(8, args.true_size)})
    rng = np.random.default_rng(args.seed)
    records = []
    with TMOCClient(args.url, token=args.token) as tmoc:
        base = next(d for d in tmoc.domains() if d["name"] == args.domain).get("robot_base")
        start = robot.start_episode(rng)
        session = tmoc.session(domain=args.domain, robot=args.robot, particles=args.particles,
                               episodes=args.episodes, max_steps=args.max_steps, seed=args.seed,
                               observation={"configuration": start.configuration.to_dict()})
        for episode in range(args.episodes):
            if episode > 0:
                session.start_episode(robot.start_episode(rng).configuration.to_dict())
            while session.pending is not None:
                step = session.pending
                rows = np.array(step["trajectory"])
                goal = step.get("joint_trajectory")
                arm = None if goal is None else ArmMotion.from_goal(args.robot, tuple(base), goal, rows[0, 0])
                outcome = robot.execute(rows, step["action"], arm=arm)
                joints = None if outcome.joint_positions is None else outcome.joint_positions.tolist()
                reply = session.observe(outcome.configuration.to_dict(), joint_positions=joints)
                print(f"episode {episode} step {step['step']}: {step['action']:<24} "
                      f"{'ok' if reply['report']['success'] else 'FAILED'}  "
                      f"size {reply['posterior']['size_mean'] * 1000:.1f} mm", flush=True)
            records.append(reply["episode"])
        posterior = session.belief()["posterior"]
        session.close()
    robot.close()
    print(json.dumps({"session": session.id, "robot": args.robot, "utilities": [r["utility"] for r in records],
                      "posterior_size_mm": round(posterior["size_mean"] * 1000, 2),
                      "posterior_std_mm": round(posterior["size_std"] * 1000, 3),
                      "true_size_mm": args.true_size * 1000}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
