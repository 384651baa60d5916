"""The loop's transit to a pre-pose: the domain says what is in the way and which paths to
try, ``planner.motion.plan_transit`` tries them (straight, the domain's candidates, RRT*).

A domain's physics half supplies ``obstacles(config, sizes)`` (its bodies as boxes that lie
as observed) and ``gripper_boxes(held, opening)`` (the boxes the check moves: palm,
fingers, a held block), and its candidate paths: ``transit_candidates(robot, pre)`` ->
``[(name, waypoints (M, 4))]`` when it has one, else its ``default_transit`` (up, across
at a safe height, down) as the one candidate ``"up_across_down"``.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from planner.motion import Bounds, Transit, box_checker, plan_transit
from sim_workers.configuration import Configuration

WORKSPACE = Bounds(np.array([-0.5, -0.6, 0.0, -np.pi]), np.array([1.2, 0.6, 0.6, np.pi]))
# 200 RRT* iterations, at most 600 to find a first path (~0.5 s); a coarse output path
# (the trajectory interpolates between waypoints anyway).
RRT_ITERATIONS, RRT_MAX_ITERATIONS, RRT_RESOLUTION = 200, 600, 0.05


def workspace_of(physics) -> Bounds:
    """The motion planner's bounds for a physics half: its ``workspace`` (plain low/high
    arrays, ``sim_workers.configuration.Workspace``: a domain may need more room) or the
    default ``WORKSPACE``."""
    own = getattr(physics, "workspace", None)
    return WORKSPACE if own is None else Bounds(np.asarray(own.low), np.asarray(own.high))


def transit_checker(domain, config: Configuration, size, held: float,
                    opening: float | None = None) -> Callable[[np.ndarray], bool]:
    """is_valid(q) for the gripper at q among the domain's obstacles in `config` (believed
    block sizes `size`, one or one per block), with a block of size `held` in the hand (0:
    none) and the fingers at most `opening` apart (None: their widest): each of the
    gripper's boxes must be free."""
    obstacles = domain.obstacles(config, size)
    parts = [(box_checker(obstacles, gripper_half_extents=half), np.array([0.0, 0.0, dz, 0.0]))
             for half, dz in domain.gripper_boxes(held, opening)]
    # q is at the fingertips: each box sits dz above them, along the gripper's vertical axis.
    return lambda q: all(free(np.asarray(q) + offset) for free, offset in parts)


def transit_candidates(domain, robot: np.ndarray, pre: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The domain's candidate paths from `robot` to `pre`, (name, (M, 4) waypoints) each."""
    own = getattr(domain, "transit_candidates", None)
    if own is not None:
        return [(str(name), np.asarray(w)[:, :4]) for name, w in own(robot, pre)]
    return [("up_across_down", domain.default_transit(robot, pre)[:, :4])]


def plan_pre_pose_transit(domain, config: Configuration, pre: np.ndarray, size, held: float,
                          seed: Callable[[], int]) -> Transit:
    """The transit from the robot in `config` to `pre` (see ``planner.motion.plan_transit``;
    `seed` is drawn only if RRT* runs). The fingers move from the robot's opening to the
    pre-pose's on the way (a held block stops them at its width): the check takes the
    wider of the two."""
    opening = max(float(config.robot[4]), float(pre[4]))
    return plan_transit(config.robot[:4], pre[:4], transit_checker(domain, config, size, held, opening),
                        workspace_of(domain), seed=seed,
                        candidates=transit_candidates(domain, config.robot, pre),
                        iterations=RRT_ITERATIONS, max_iterations=RRT_MAX_ITERATIONS,
                        resolution=RRT_RESOLUTION)
