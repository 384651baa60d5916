"""The loop's transit to a pre-pose: the domain says what is in the way and which paths to
try, ``planner.motion.plan_transit`` tries them (straight, the domain's candidates, RRT*).

A domain's physics half supplies ``obstacles(config, sizes)`` (its bodies as boxes that lie
as observed) and ``gripper_boxes(held, opening)`` (the boxes the check moves: palm,
fingers, a held block), and its candidate paths: ``transit_candidates(robot, pre)`` ->
``[(name, waypoints (M, 4))]`` when it has one, else its ``default_transit`` (up, across
at a safe height, down) as the one candidate ``"up_across_down"``. One more candidate
comes from the scene itself, ``"over_the_top"``: up until the gripper's lowest part
clears the highest obstacle, across, down (a domain's safe height is a fixed rule, and a
held block carried across at the pre-pose's height can meet a pile that grew crooked).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from planner.motion import Bounds, Transit, box_checker, plan_transit
from sim_workers.base import DEFAULT_WORKSPACE
from sim_workers.configuration import Configuration

WORKSPACE = Bounds(DEFAULT_WORKSPACE.low, DEFAULT_WORKSPACE.high)    # a domain's default bounds
# 200 RRT* iterations, at most 600 to find a first path (~0.5 s); a coarse output path
# (the trajectory interpolates between waypoints anyway).
RRT_ITERATIONS, RRT_MAX_ITERATIONS, RRT_RESOLUTION = 200, 600, 0.05
OVER_THE_TOP = "over_the_top"
OVER_CLEARANCE = 0.01       # m between the gripper's lowest part and the highest obstacle


def workspace_of(physics) -> Bounds:
    """The motion planner's bounds for a physics half: its ``workspace`` (plain low/high
    arrays, ``sim_workers.configuration.Workspace``: a domain may need more room)."""
    own = physics.workspace
    return Bounds(np.asarray(own.low), np.asarray(own.high))


def transit_checker(domain, config: Configuration, size, held: float,
                    opening: float | None = None) -> Callable[[np.ndarray], bool]:
    """is_valid(q) for the gripper at q among the domain's obstacles in `config` (believed
    block sizes `size`, one or one per block), with a block of size `held` in the hand (0:
    none) and the fingers at most `opening` apart (None: their widest): each of the
    gripper's boxes must be free."""
    return _checker(domain.obstacles(config, size), domain.gripper_boxes(held, opening))


def _checker(obstacles: list, parts: list) -> Callable[[np.ndarray], bool]:
    """is_valid(q) for the gripper's boxes `parts` ((half extents, dz) each) among `obstacles`."""
    checks = [(box_checker(obstacles, gripper_half_extents=half), np.array([0.0, 0.0, dz, 0.0]))
              for half, dz in parts]
    # q is at the fingertips: each box sits dz above them, along the gripper's vertical axis.
    return lambda q: all(free(np.asarray(q) + offset) for free, offset in checks)


def over_the_top(robot: np.ndarray, pre: np.ndarray, obstacles: list, parts: list,
                 bounds: Bounds) -> list[tuple[str, np.ndarray]]:
    """Up until the lowest of the gripper's boxes `parts` is OVER_CLEARANCE above the
    highest of `obstacles`, across, down to `pre`: [(OVER_THE_TOP, (4, 4) waypoints)], or
    [] when that height is outside `bounds`."""
    tops = [float(o[0][2] + (np.abs(o[2]) @ o[1] if len(o) > 2 and o[2] is not None else o[1])[2])
            for o in obstacles]
    reach = max(float(half[2] - dz) for half, dz in parts)      # below the fingertips
    z = max(float(robot[2]), float(pre[2]), max(tops, default=0.0) + reach + OVER_CLEARANCE)
    if z > bounds.high[2]:
        return []
    return [(OVER_THE_TOP, np.array([robot[:4], [*robot[:2], z, robot[3]], [*pre[:2], z, pre[3]], pre[:4]],
                                    dtype=np.float64))]


def transit_candidates(domain, robot: np.ndarray, pre: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """The domain's candidate paths from `robot` to `pre`, (name, (M, 4) waypoints) each."""
    return [(str(name), np.asarray(w)[:, :4]) for name, w in domain.transit_candidates(robot, pre)]


def plan_pre_pose_transit(domain, config: Configuration, pre: np.ndarray, size, held: float,
                          seed: Callable[[], int]) -> Transit:
    """The transit from the robot in `config` to `pre` (see ``planner.motion.plan_transit``;
    `seed` is drawn only if RRT* runs). The fingers move from the robot's opening to the
    pre-pose's on the way (a held block stops them at its width): the check takes the
    wider of the two."""
    opening = max(float(config.robot[4]), float(pre[4]))
    obstacles, parts = domain.obstacles(config, size), domain.gripper_boxes(held, opening)
    bounds = workspace_of(domain)
    candidates = (transit_candidates(domain, config.robot, pre)
                  + over_the_top(config.robot, pre, obstacles, parts, bounds))
    return plan_transit(config.robot[:4], pre[:4], _checker(obstacles, parts), bounds, seed=seed,
                        candidates=candidates, iterations=RRT_ITERATIONS,
                        max_iterations=RRT_MAX_ITERATIONS, resolution=RRT_RESOLUTION)
