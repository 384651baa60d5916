"""OMPL RRT* for the gripper's free-space motion: the search, its simplification and the
glue between OMPL's states and ``(x, y, z, yaw)`` arrays.

Determinism (see the package doc): each call reseeds OMPL's global RNG and builds a fresh
space, planner and simplifier, and RRT* stops after an iteration count, not a time budget.
This module is the package's one user of OMPL.
"""
from __future__ import annotations

import logging
import math
import operator
import threading
import time

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from .geometry import (YAW_WEIGHT, Bounds, IsValid, MotionPlanningError, _as_config, _check_endpoint,
                       _densify, _first_invalid, _fmt, _positive, _wrap)

_LOG = logging.getLogger(__name__)

# OMPL prints an Info line per solve and per simplification; a planner called once per
# action and particle would drown the service's logs. Warnings and errors still show.
ou.setLogLevel(ou.LogLevel.LOG_WARN)

# OMPL's seed is process-wide: two plans seeding and building RNGs at the same time in
# one process would interleave their seeds. Serialising plans keeps each deterministic.
_OMPL_LOCK = threading.Lock()


def plan_rrtstar(start: np.ndarray, goal: np.ndarray, is_valid: IsValid, bounds: Bounds, *,
                 seed: int,
                 iterations: int = 500,
                 max_iterations: int | None = None,
                 time_limit_s: float = 5.0,
                 resolution: float = 0.01,
                 validity_resolution: float = 0.005,
                 yaw_weight: float = YAW_WEIGHT,
                 max_edge: float | None = None) -> np.ndarray:
    """A collision-free path from ``start`` to ``goal`` found by RRT*, as an (M, 4) array of
    waypoints, M >= 2.

    RRT* runs ``iterations`` iterations (it keeps improving the path after the first
    solution); if it has no exact solution by then it goes on until one is found or
    ``max_iterations`` (default ``10 * iterations``) is reached. ``time_limit_s`` is a
    wall-clock safety cap on solving plus simplification (see the package doc on
    determinism). The solution is simplified with OMPL's PathSimplifier, then interpolated
    to ``resolution``; every waypoint is checked with ``is_valid`` (falling back to the
    unsimplified path if a simplified waypoint fails). ``max_edge`` is RRT*'s range (None:
    OMPL's default, 0.2 of the space's extent). The search always runs: trying cheaper
    paths first is :func:`planner.motion.plan_transit`'s job.

    Raises MotionPlanningError for malformed input, a start or goal out of bounds or in
    collision, or no path within the budget; an exception raised by ``is_valid`` propagates.
    """
    start = _as_config("start", start)
    goal = _as_config("goal", goal)
    if not isinstance(bounds, Bounds):
        raise MotionPlanningError(f"bounds must be a Bounds, got {type(bounds).__name__}")
    resolution = _positive("resolution", resolution)
    validity_resolution = _positive("validity_resolution", validity_resolution)
    yaw_weight = _positive("yaw_weight", yaw_weight)
    time_limit_s = _positive("time_limit_s", time_limit_s)
    iterations = operator.index(iterations)
    if iterations < 1:
        raise MotionPlanningError(f"iterations must be >= 1, got {iterations}")
    max_iterations = 10 * iterations if max_iterations is None else operator.index(max_iterations)
    if max_iterations < iterations:
        raise MotionPlanningError(
            f"max_iterations ({max_iterations}) must be >= iterations ({iterations})")
    if max_edge is not None:
        max_edge = _positive("max_edge", max_edge)
    seed = operator.index(seed)
    wraps = bounds.yaw_wraps

    _check_endpoint("start", start, is_valid, bounds)
    _check_endpoint("goal", goal, is_valid, bounds)

    with _OMPL_LOCK:
        raw, simplified, n_iter, exact, cap_hit, checker = _rrtstar(
            start, goal, is_valid, bounds, seed=seed, iterations=iterations,
            max_iterations=max_iterations, time_limit_s=time_limit_s,
            validity_resolution=validity_resolution, yaw_weight=yaw_weight, max_edge=max_edge)
    if checker.error is not None:
        raise checker.error
    if cap_hit:
        _LOG.warning("RRT* hit its %.3g s safety cap after %d iterations: the path is "
                     "valid but not reproducible from the seed", time_limit_s, n_iter)
    if not exact:
        why = (f"{time_limit_s:g} s safety cap" if cap_hit
               else f"{max_iterations} RRT* iterations")
        raise MotionPlanningError(
            f"no collision-free path from start ({_fmt(start)}) to goal ({_fmt(goal)}) "
            f"found within {why}")
    for candidate in (simplified, raw):
        if candidate is None:
            continue
        pts = candidate.copy()
        pts[0], pts[-1] = start, goal
        dense = _densify(pts, resolution, yaw_weight, wraps)
        if _first_invalid(dense[1:-1], is_valid) is None:
            return dense
    raise MotionPlanningError(
        f"RRT* found a path from start ({_fmt(start)}) to goal ({_fmt(goal)}) but a "
        f"waypoint interpolated at resolution {resolution:g} is in collision; "
        f"decrease validity_resolution")


class _OmplChecker:
    """Adapts ``is_valid(np.ndarray)`` to OMPL states; keeps the first error.

    An exception must not unwind through OMPL's C++ loop, so it is stored, the state is
    called invalid, the planner is told to stop, and the error is re-raised afterwards.
    Holds no OMPL objects, so no reference cycle (and no nanobind leak report) forms.
    """

    __slots__ = ("fn", "wraps", "error")

    def __init__(self, fn: IsValid, wraps: bool) -> None:
        self.fn = fn
        self.wraps = wraps
        self.error: BaseException | None = None

    def __call__(self, state: object) -> bool:
        if self.error is not None:
            return False
        p = state[0]  # type: ignore[index]
        q = np.array((p[0], p[1], p[2], state[1].value if self.wraps else state[1][0]),  # type: ignore[index]
                     dtype=np.float64)
        # A kept traceback keeps this frame's locals: drop the views of OMPL-owned states.
        state = p = None
        try:
            return bool(self.fn(q))
        except BaseException as exc:  # noqa: BLE001 - re-raised after solve()
            self.error = exc
            return False


def _build_space(bounds: Bounds, yaw_weight: float) -> tuple[ob.CompoundStateSpace, list, float, float]:
    """R^3 x (SO2 | bounded R^1) with the documented weights.

    Also returns the factor spaces, which the caller must keep alive as long as the compound
    space: the bindings do not make the compound space own them (dropping them segfaults),
    and the factor extents.
    """
    space = ob.CompoundStateSpace()
    r3 = ob.RealVectorStateSpace(3)
    rb = ob.RealVectorBounds(3)
    for i in range(3):
        rb.setLow(i, float(bounds.low[i]))
        rb.setHigh(i, float(bounds.high[i]))
    r3.setBounds(rb)
    space.addSubspace(r3, 1.0)
    if bounds.yaw_wraps:
        yaw_space = ob.SO2StateSpace()
        yaw_extent = math.pi  # the largest SO2 distance
    else:
        yaw_space = ob.RealVectorStateSpace(1)
        yaw_space.setBounds(float(bounds.low[3]), float(bounds.high[3]))
        yaw_extent = float(bounds.high[3] - bounds.low[3])
    space.addSubspace(yaw_space, yaw_weight)
    pos_extent = float(np.linalg.norm(bounds.high[:3] - bounds.low[:3]))
    return space, [r3, yaw_space], pos_extent, yaw_extent


def _set_state(state: object, q: np.ndarray, wraps: bool) -> None:
    p = state[0]  # type: ignore[index]
    p[0], p[1], p[2] = float(q[0]), float(q[1]), float(q[2])
    if wraps:
        state[1].value = _wrap(float(q[3]))  # type: ignore[index]
    else:
        state[1][0] = float(q[3])  # type: ignore[index]


def _path_array(path: og.PathGeometric, wraps: bool) -> np.ndarray:
    rows = []
    for s in path.getStates():
        p = s[0]
        rows.append((p[0], p[1], p[2], s[1].value if wraps else s[1][0]))
    return np.array(rows, dtype=np.float64).reshape(-1, 4)


def _seed_ompl(seed: int) -> int:
    """Reseed OMPL's RNG seed generator; returns the seed actually used (OMPL rejects 0)."""
    ompl_seed = 1 + operator.index(seed) % (2**32 - 1)
    # OMPL logs an *error* when reseeding after any RNG exists ("will not lead to
    # deterministic sampling"). It is harmless here: everything that samples is built after
    # the reseed, in a fixed order (the determinism tests check this), so mute it.
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LogLevel.LOG_NONE)
    try:
        ou.RNG.setSeed(ompl_seed)
    finally:
        ou.setLogLevel(level)
    return ompl_seed


def _rrtstar(start: np.ndarray, goal: np.ndarray, is_valid: IsValid, bounds: Bounds, *,
             seed: int, iterations: int, max_iterations: int, time_limit_s: float,
             validity_resolution: float, yaw_weight: float, max_edge: float | None):
    """One seeded RRT* solve plus simplification; OMPL objects never leave this function."""
    wraps = bounds.yaw_wraps
    _seed_ompl(seed)  # before anything that owns an RNG is built
    space, factors, pos_extent, yaw_extent = _build_space(bounds, yaw_weight)
    ss = og.SimpleSetup(space)
    checker = _OmplChecker(is_valid, wraps)
    ss.setStateValidityChecker(checker)
    si = ss.getSpaceInformation()
    # OMPL splits a motion into max over subspaces of (subspace distance / (fraction *
    # subspace extent)) pieces; this fraction makes position pieces <= validity_resolution m
    # and yaw pieces <= validity_resolution / yaw_weight rad, as documented.
    fraction = min(validity_resolution / pos_extent,
                   (validity_resolution / yaw_weight) / yaw_extent, 1.0)
    si.setStateValidityCheckingResolution(fraction)
    s_start, s_goal = space.allocState(), space.allocState()
    _set_state(s_start, start, wraps)
    _set_state(s_goal, goal, wraps)
    ss.setStartAndGoalStates(s_start, s_goal)
    planner = og.RRTstar(si)
    if max_edge is not None:
        planner.setRange(max_edge)
    ss.setPlanner(planner)
    ss.setup()

    t0 = time.perf_counter()
    deadline = t0 + time_limit_s
    cap = [False]

    def stop() -> bool:
        # Called by RRT* once per iteration: iteration counts keep runs reproducible.
        n = planner.numIterations()
        if checker.error is not None or n >= max_iterations:
            return True
        # RRT* hands its solution to the problem definition only when solve() returns, so
        # "solved yet" is read from its best cost (infinite until a goal is reached).
        if n >= iterations and math.isfinite(planner.bestCost().value()):
            return True
        if time.perf_counter() > deadline:
            cap[0] = True
            return True
        return False

    ss.solve(ob.PlannerTerminationCondition(stop))
    n_iter = planner.numIterations()
    exact = bool(ss.haveExactSolutionPath()) and checker.error is None
    raw = simplified = None
    if exact:
        raw = _path_array(ss.getSolutionPath(), wraps)

        def stop_simplify() -> bool:
            # Simplification converges on its own; only the safety cap may cut it short.
            if time.perf_counter() > deadline:
                cap[0] = True
                return True
            return checker.error is not None

        ss.simplifySolution(ob.PlannerTerminationCondition(stop_simplify))
        simplified = _path_array(ss.getSolutionPath(), wraps)
    # No space.freeState(): the Python wrappers of allocState() own their states.
    return raw, simplified, n_iter, exact, cap[0], checker
