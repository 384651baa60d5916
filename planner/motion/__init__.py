"""Motion planning for the floating gripper: transit (straight, candidates, OMPL RRT*)
and checked straight approaches.

A configuration is ``q = (x, y, z, yaw)`` in metres / radians, a float64 array of shape (4,).
The planners see only callables and arrays: the caller supplies ``is_valid(q) -> bool`` (the
world's own collision query, or :func:`box_checker` in unit tests), so this package never
imports pybullet, ``sim_workers`` or ``coordinator``.

Modules: ``geometry`` (configurations, bounds, segments), ``collision`` (the box checker),
``rrtstar`` (OMPL glue and the RRT* search), ``transit`` (the transit strategy and the
approach).

Conventions (documented once here, relied on everywhere in the package):

* **State space.** ``R^3 x SO(2)`` (an OMPL compound space): yaw wraps, so the planner turns
  the short way round. The metric is ``|dp| + yaw_weight * |dyaw|`` with ``yaw_weight = 0.1``
  m/rad by default: a radian of yaw costs as much as 0.1 m of travel, roughly the
  displacement of a finger tip 0.1 m from the gripper's axis when it turns by a radian.
  If the yaw bounds span less than a full turn the yaw factor is a bounded real line
  instead (no wrapping: a restricted wrist cannot go the "short way" through the gap).
* **Yaw values.** Returned paths start and end *exactly* at the requested configurations;
  interior yaws are normalised to [-pi, pi], so consecutive yaws may differ by ~2*pi where
  the path crosses +-pi. Treat yaw as an angle, or call :func:`unwrap_yaw`.
* **Resolution.** ``resolution`` bounds the step between consecutive returned waypoints:
  at most ``resolution`` metres of Cartesian position *and* at most
  ``resolution / yaw_weight`` radians of yaw (0.01 m and 0.1 rad at the defaults).
  ``validity_resolution`` bounds, in the same way, the spacing of the states checked along
  every motion, both inside OMPL (its per-subspace longest valid segment is set from it)
  and along the straight segments checked here. Every returned waypoint is also checked.
* **Determinism.** Each call reseeds OMPL's global RNG (``ompl.util.RNG.setSeed``) and then
  builds a fresh space, planner and simplifier, so all RNGs they draw are seeded in a fixed
  order; RRT* stops after a fixed *iteration count*, not after a time budget, so the same
  seed gives the same path bit-for-bit on any machine. ``time_limit_s`` is only a
  wall-clock safety cap: if it is hit, the result depends on CPU speed (a warning is
  logged).
"""
from __future__ import annotations

from .collision import box_checker
from .geometry import YAW_WEIGHT, Bounds, MotionPlanningError, interpolate_config, path_length, unwrap_yaw
from .rrtstar import plan_rrtstar
from .transit import Transit, check_waypoints, plan_approach, plan_transit

__all__ = [
    "Bounds",
    "MotionPlanningError",
    "Transit",
    "YAW_WEIGHT",
    "box_checker",
    "check_waypoints",
    "interpolate_config",
    "path_length",
    "plan_approach",
    "plan_rrtstar",
    "plan_transit",
    "unwrap_yaw",
]
