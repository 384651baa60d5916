"""The gripper's transit to a pre-pose, and its straight approach from there.

:func:`plan_transit` is the one transit planner: it tries the straight segment, then the
caller's candidate paths in order (a domain's up-across-down, say), each checked segment
by segment, and only then searches with RRT* (:func:`planner.motion.plan_rrtstar`). It
says which strategy gave the path, or, when none did, why (a *fallback*: the caller then
moves without a checked transit, and should say so).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .geometry import (YAW_WEIGHT, Bounds, IsValid, MotionPlanningError, _as_config, _check_endpoint,
                       _densify, _first_invalid, _fmt, _positive)
from .rrtstar import plan_rrtstar

STRAIGHT = "straight"
RRTSTAR = "rrtstar"
NONE = "none"


@dataclass(frozen=True)
class Transit:
    """What :func:`plan_transit` found.

    ``path``: (M, 4) waypoints from start to goal, or None when every strategy failed.
    ``strategy``: ``"straight"``, the name of the candidate used, ``"rrtstar"``, or
    ``"none"``. ``fallback``: why every strategy failed (None when one worked).
    """

    path: np.ndarray | None
    strategy: str
    fallback: str | None = None


def plan_approach(pre_pose: np.ndarray, pose: np.ndarray, is_valid: IsValid, *,
                  resolution: float = 0.01,
                  validity_resolution: float = 0.005,
                  yaw_weight: float = YAW_WEIGHT,
                  bounds: Bounds | None = None) -> np.ndarray:
    """The straight segment ``pre_pose -> pose`` as (M, 4) waypoints at ``resolution``.

    Every waypoint, and every state at ``validity_resolution`` along the segment, is checked
    with ``is_valid`` (which must allow the contact the approach is meant to make, e.g. the
    fingers around the target block). Raises MotionPlanningError naming the blocked
    configuration, or an endpoint out of ``bounds`` (when given).
    """
    pre_pose = _as_config("pre_pose", pre_pose)
    pose = _as_config("pose", pose)
    resolution = _positive("resolution", resolution)
    validity_resolution = _positive("validity_resolution", validity_resolution)
    yaw_weight = _positive("yaw_weight", yaw_weight)
    wraps = True if bounds is None else bounds.yaw_wraps
    _check_endpoint("pre_pose", pre_pose, is_valid, bounds)
    _check_endpoint("pose", pose, is_valid, bounds)
    ends = np.stack([pre_pose, pose])
    for step in (validity_resolution, resolution):
        pts = _densify(ends, step, yaw_weight, wraps)
        bad = _first_invalid(pts[1:-1], is_valid)
        if bad is not None:
            raise MotionPlanningError(
                f"approach from pre_pose ({_fmt(pre_pose)}) to pose ({_fmt(pose)}) is "
                f"blocked at ({_fmt(pts[bad + 1])})")
    return pts


def check_waypoints(waypoints: Sequence[np.ndarray] | np.ndarray, is_valid: IsValid, *,
                    validity_resolution: float = 0.005,
                    yaw_weight: float = YAW_WEIGHT) -> np.ndarray:
    """``waypoints`` as an (M, 4) float64 array if every straight segment between them is
    free (each checked as :func:`plan_approach` checks one, endpoints included); otherwise
    MotionPlanningError naming where a segment is blocked."""
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        plan_approach(a, b, is_valid, validity_resolution=validity_resolution, yaw_weight=yaw_weight)
    return np.array(waypoints, dtype=np.float64)


def plan_transit(start: np.ndarray, goal: np.ndarray, is_valid: IsValid, bounds: Bounds, *,
                 seed: int | Callable[[], int],
                 candidates: Sequence[tuple[str, np.ndarray]] = (),
                 straight: bool = True,
                 iterations: int = 500,
                 max_iterations: int | None = None,
                 time_limit_s: float = 5.0,
                 resolution: float = 0.01,
                 validity_resolution: float = 0.005,
                 yaw_weight: float = YAW_WEIGHT,
                 max_edge: float | None = None) -> Transit:
    """A collision-free transit from ``start`` to ``goal``, strategies tried in order.

    1. the straight segment ``[start, goal]`` (unless ``straight`` is False);
    2. each ``(name, waypoints)`` of ``candidates`` (paths from start to goal), e.g. a
       domain's up, across at a safe height and down;
    3. RRT* (:func:`planner.motion.plan_rrtstar` with ``seed`` and the keyword arguments).

    The straight segment and the candidates are checked segment by segment (see
    :func:`check_waypoints`) and returned as their waypoints; RRT*'s path comes at
    ``resolution``. ``seed`` may be a callable: it is called only when RRT* runs, so a
    caller's generator is drawn from only then. A MotionPlanningError of every strategy
    (blocked, start or goal in collision or out of bounds, no path within the budget) gives
    ``Transit(None, "none", fallback)``; an exception of ``is_valid`` propagates.
    """
    tried = ([(STRAIGHT, [start, goal])] if straight else []) + list(candidates)
    for name, waypoints in tried:
        try:
            return Transit(check_waypoints(waypoints, is_valid, validity_resolution=validity_resolution,
                                           yaw_weight=yaw_weight), name)
        except MotionPlanningError:
            continue
    try:
        rrt_seed = seed() if callable(seed) else seed
        path = plan_rrtstar(start, goal, is_valid, bounds, seed=rrt_seed, iterations=iterations,
                            max_iterations=max_iterations, time_limit_s=time_limit_s,
                            resolution=resolution, validity_resolution=validity_resolution,
                            yaw_weight=yaw_weight, max_edge=max_edge)
    except MotionPlanningError as exc:
        names = ", ".join([n for n, _ in tried] + [RRTSTAR])
        return Transit(None, NONE, f"{exc} (tried {names})")
    return Transit(path, RRTSTAR)
