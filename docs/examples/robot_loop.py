"""Drive a TMOC robot session over HTTP, start to finish, with the Python client.

The "robot" here is a simulated one (a pybullet world holding a hidden block size that
the service does not know); a real integrator replaces `robot.execute` with their
driver (the trajectory's columns are t, x, y, z, yaw, opening of the gripper's tool
point) and `robot.start_episode` with the robot's observed scene.

    tmoc serve --port 8000 &
    python docs/examples/robot_loop.py --url http://127.0.0.1:8000 --episodes 2

With TMOC_API_TOKEN set on the server, pass --token (or set TMOC_API_TOKEN here too).
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

from api.client import TMOCClient
from coordinator.loop.reality import SimulatedReality


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default="http://127.0.0.1:8000")
    ap.add_argument("--token", default=os.environ.get("TMOC_API_TOKEN"))
    ap.add_argument("--episodes", type=int, default=2)
    ap.add_argument("--particles", type=int, default=16)
    ap.add_argument("--max-steps", type=int, default=30)
    ap.add_argument("--true-size", type=float, default=0.050, help="the robot's hidden block size (m)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    robot = SimulatedReality("container", {"n_blocks": 8}, {"block_sizes": np.full(8, args.true_size)})
    rng = np.random.default_rng(args.seed)
    records = []
    with TMOCClient(args.url, token=args.token) as tmoc:
        start = robot.start_episode(rng)
        session = tmoc.session(particles=args.particles, episodes=args.episodes,
                               max_steps=args.max_steps, seed=args.seed,
                               observation={"configuration": start.configuration.to_dict()})
        for episode in range(args.episodes):
            if episode > 0:
                session.start_episode(robot.start_episode(rng).configuration.to_dict())
            while session.pending is not None:
                step = session.pending
                outcome = robot.execute(np.array(step["trajectory"]), step["action"])
                reply = session.observe(outcome.configuration.to_dict())
                print(f"episode {episode} step {step['step']}: {step['action']:<24} "
                      f"{'ok' if reply['report']['success'] else 'FAILED'}  "
                      f"size {reply['posterior']['size_mean'] * 1000:.1f} mm", flush=True)
            records.append(reply["episode"])
        posterior = session.belief()["posterior"]
        session.close()
    robot.close()
    print(json.dumps({"session": session.id, "utilities": [r["utility"] for r in records],
                      "posterior_size_mm": round(posterior["size_mean"] * 1000, 2),
                      "true_size_mm": args.true_size * 1000}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
