"""An arm's motion in its joint space: OMPL RRT* over the joint box, and the time a path
takes within the joints' velocity and acceleration limits (toppra).

A joint configuration is a float64 array of shape (n,) in radians; the planners see only
arrays and ``is_valid(q) -> bool`` (the arm's links against the believed scene, built by the
caller), like the floating gripper's planners. Joints are bounded intervals, never wrapping:
a UR joint turns +-360 degrees, and which turn it is on matters to its cables.

Determinism: as :func:`planner.motion.plan_rrtstar` (OMPL's RNG reseeded per call, RRT* stopped
after an iteration count); toppra is deterministic (a grid and a linear program per stage).
"""
from __future__ import annotations

import math
import operator
import time
from dataclasses import dataclass

import numpy as np
from ompl import base as ob
from ompl import geometric as og

from .geometry import IsValid, MotionPlanningError, _first_invalid, _fmt, _positive
from .rrtstar import _OMPL_LOCK, _seed_ompl

__all__ = ["JointPath", "densify_joints", "plan_joint_rrtstar", "time_joint_path"]


def _as_joints(name: str, q: object, n: int) -> np.ndarray:
    a = np.asarray(q, dtype=np.float64).reshape(-1)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise MotionPlanningError(f"{name} must be {n} finite joint values, got {np.asarray(q).tolist()}")
    return a


def densify_joints(points: np.ndarray, step: float) -> np.ndarray:
    """Waypoints every at most `step` rad on the largest joint move, ends kept exactly."""
    points = np.asarray(points, dtype=np.float64)
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:]):
        k = max(1, math.ceil(float(np.max(np.abs(b - a))) / step))
        f = np.arange(1, k + 1)[:, None] / k
        out.append(a + f * (b - a))
    dense = np.concatenate(out)
    dense[-1] = points[-1]
    return dense


def plan_joint_rrtstar(start: np.ndarray, goal: np.ndarray, is_valid: IsValid, low: np.ndarray,
                       high: np.ndarray, *, seed: int, iterations: int = 300,
                       max_iterations: int | None = None, time_limit_s: float = 5.0,
                       resolution: float = 0.02, validity_resolution: float = 0.01) -> np.ndarray:
    """A collision-free joint path from `start` to `goal` inside [`low`, `high`], (M, n), M >= 2.

    The straight joint segment is tried first (checked every `validity_resolution` rad);
    otherwise RRT* runs `iterations` iterations and on until it has a solution or
    `max_iterations` (default 10x), its path is simplified by OMPL and densified to
    `resolution` rad, and every returned waypoint is checked. Raises MotionPlanningError
    for malformed input, an end out of the limits or invalid, or no path in the budget.
    """
    low = np.asarray(low, dtype=np.float64).reshape(-1)
    high = np.asarray(high, dtype=np.float64).reshape(-1)
    n = low.size
    if high.shape != (n,) or not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))) or np.any(low >= high):
        raise MotionPlanningError("joint limits must be finite with low < high for every joint")
    start, goal = _as_joints("start", start, n), _as_joints("goal", goal, n)
    resolution = _positive("resolution", resolution)
    validity_resolution = _positive("validity_resolution", validity_resolution)
    iterations = operator.index(iterations)
    max_iterations = 10 * iterations if max_iterations is None else operator.index(max_iterations)
    if iterations < 1 or max_iterations < iterations:
        raise MotionPlanningError(f"iterations ({iterations}) must be >= 1 and <= max_iterations")
    for name, q in (("start", start), ("goal", goal)):
        if np.any(q < low - 1e-9) or np.any(q > high + 1e-9):
            raise MotionPlanningError(f"{name} ({_fmt(q)}) is outside the joint limits")
        if not is_valid(q):
            raise MotionPlanningError(f"{name} ({_fmt(q)}) is in collision")
    straight = densify_joints(np.stack([start, goal]), validity_resolution)
    if _first_invalid(straight[1:-1], is_valid) is None:
        return densify_joints(np.stack([start, goal]), resolution)
    with _OMPL_LOCK:
        raw, simplified, exact = _solve(start, goal, is_valid, low, high, seed=operator.index(seed),
                                        iterations=iterations, max_iterations=max_iterations,
                                        time_limit_s=_positive("time_limit_s", time_limit_s),
                                        validity_resolution=validity_resolution)
    if not exact:
        raise MotionPlanningError(f"no collision-free joint path from ({_fmt(start)}) to ({_fmt(goal)}) "
                                  f"within {max_iterations} RRT* iterations")
    for candidate in (simplified, raw):
        pts = candidate.copy()
        pts[0], pts[-1] = start, goal
        dense = densify_joints(pts, min(resolution, validity_resolution))
        if _first_invalid(dense[1:-1], is_valid) is None:
            return densify_joints(pts, resolution)
    raise MotionPlanningError("RRT* found a joint path but a densified waypoint is in collision; "
                              "decrease validity_resolution")


def _solve(start, goal, is_valid, low, high, *, seed, iterations, max_iterations, time_limit_s,
           validity_resolution):
    """One seeded RRT* solve and simplification; OMPL objects never leave this function."""
    n = low.size
    _seed_ompl(seed)
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(low[i]))
        bounds.setHigh(i, float(high[i]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    error: list[BaseException] = []

    def check(state) -> bool:
        if error:
            return False
        try:
            return bool(is_valid(np.array([state[i] for i in range(n)], dtype=np.float64)))
        except BaseException as exc:  # noqa: BLE001 - re-raised after solve()
            error.append(exc)
            return False

    ss.setStateValidityChecker(check)
    si = ss.getSpaceInformation()
    # OMPL checks a motion every fraction x the space's extent (its largest distance):
    # this fraction makes that at most validity_resolution rad of joint space.
    si.setStateValidityCheckingResolution(min(validity_resolution / space.getMaximumExtent(), 1.0))
    s0, s1 = space.allocState(), space.allocState()
    for i in range(n):
        s0[i], s1[i] = float(start[i]), float(goal[i])
    ss.setStartAndGoalStates(s0, s1)
    planner = og.RRTstar(si)
    ss.setPlanner(planner)
    ss.setup()
    deadline = time.perf_counter() + time_limit_s

    def stop() -> bool:
        k = planner.numIterations()
        if error or k >= max_iterations or time.perf_counter() > deadline:
            return True
        return k >= iterations and math.isfinite(planner.bestCost().value())

    ss.solve(ob.PlannerTerminationCondition(stop))
    if error:
        raise error[0]
    if not ss.haveExactSolutionPath():
        return None, None, False

    def path() -> np.ndarray:
        return np.array([[s[i] for i in range(n)] for s in ss.getSolutionPath().getStates()])

    raw = path()
    ss.simplifySolution(ob.PlannerTerminationCondition(lambda: time.perf_counter() > deadline or bool(error)))
    if error:
        raise error[0]
    return raw, path(), True


@dataclass
class JointPath:
    """A timed joint trajectory: times (M,), positions, velocities, accelerations (M, n)."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray

    def goal(self, joint_names: list[str]) -> dict:
        """As a ``control_msgs/FollowJointTrajectory`` goal's trajectory (JSON-ready)."""
        return {"joint_names": list(joint_names),
                "points": [{"positions": q.tolist(), "velocities": v.tolist(), "accelerations": a.tolist(),
                            "time_from_start": float(t)}
                           for t, q, v, a in zip(self.t, self.q, self.qd, self.qdd)]}


# Where the joint path turns by more than this angle the arm stops there (a run of toppra
# ends): a cubic through waypoints h apart rounds a corner of angle theta by about
# h x theta / 8, and the densified waypoints are at most 0.02 rad apart (~16 mm of tool at
# the UR5e's 0.8 m reach), so 0.15 rad (8.6 degrees) keeps the rounding under 0.3 mm, a
# third of the 1 mm the tool path is followed to.
CORNER = 0.15


def _runs(w: np.ndarray) -> list[tuple[int, int]]:
    """Index ranges [a, b] of the moving runs: split at stationary waypoints and corners."""
    d = np.diff(w, axis=0)
    moving = np.max(np.abs(d), axis=1) > 1e-9
    runs, a = [], None
    for i in range(len(d)):
        if not moving[i]:
            if a is not None:
                runs.append((a, i))
                a = None
            continue
        if a is None:
            a = i
        elif moving[i - 1]:
            u, v = d[i - 1], d[i]
            cos = float(u @ v) / float(np.linalg.norm(u) * np.linalg.norm(v))
            if math.acos(max(-1.0, min(1.0, cos))) > CORNER:
                runs.append((a, i))
                a = i
    if a is not None:
        runs.append((a, len(d)))
    return runs


def _time_run(w: np.ndarray, vmax: np.ndarray, amax: np.ndarray, dt: np.ndarray | None):
    """toppra on one moving run (rest to rest): (t, qd, qdd) at its waypoints."""
    import toppra as ta
    import toppra.algorithm as algo
    import toppra.constraint as constraint

    s = np.concatenate([[0.0], np.cumsum(np.max(np.abs(np.diff(w, axis=0)), axis=1))])
    path = ta.SplineInterpolator(s, w, bc_type="natural")
    cons = [constraint.JointVelocityConstraint(np.column_stack([-vmax, vmax])),
            constraint.JointAccelerationConstraint(np.column_stack([-amax, amax]))]
    if dt is not None:
        sdot_max = np.diff(s) / np.maximum(dt, 1e-6)        # the path speed of the nominal timing

        def vlim(x: float) -> np.ndarray:
            i = min(max(int(np.searchsorted(s, x, side="right")) - 1, 0), len(sdot_max) - 1)
            v = np.minimum(np.abs(path(x, 1)) * sdot_max[i] + 1e-9, vmax)
            return np.column_stack([-v, v])
        cons.append(constraint.JointVelocityConstraintVarying(vlim))
    grid = np.unique(np.concatenate([s, np.linspace(0.0, s[-1], max(50, 2 * len(s)))]))
    algorithm = algo.TOPPRA(cons, path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
    sdd_grid, sd_grid, _ = algorithm.compute_parameterization(0.0, 0.0)
    if sd_grid is None or not np.all(np.isfinite(sd_grid)):
        raise MotionPlanningError("no timing of the joint path within the joint limits")
    sd_grid = np.maximum(np.asarray(sd_grid, dtype=np.float64), 0.0)
    sdd_grid = np.asarray(sdd_grid, dtype=np.float64)
    t_grid = np.concatenate([[0.0], np.cumsum(2.0 * np.diff(grid) / np.maximum(sd_grid[:-1] + sd_grid[1:], 1e-12))])
    idx = np.searchsorted(grid, s)
    sd, sdd = sd_grid[idx], np.concatenate([sdd_grid, [0.0]])[idx]
    qs, qss = path(s, 1), path(s, 2)
    return t_grid[idx], qs * sd[:, None], qs * sdd[:, None] + qss * (sd ** 2)[:, None]


def time_joint_path(waypoints: np.ndarray, max_velocity: np.ndarray, max_acceleration: np.ndarray,
                    nominal_dt: np.ndarray | None = None) -> JointPath:
    """The time-optimal timing of the joint path through `waypoints` (M, n) within the joint
    velocity and acceleration limits, never faster than `nominal_dt` (M-1,) seconds per gap
    where given (a domain's own timing of the tool: a push keeps its speed, and the fingers
    get the time they take where the arm stands still). Each moving run (split where the arm
    stands or turns by more than ``CORNER``) is timed rest to rest by toppra (Pham and Pham
    2018) on a cubic spline through its waypoints; every returned point is a waypoint."""
    w = np.asarray(waypoints, dtype=np.float64)
    if w.ndim != 2 or len(w) < 1 or not np.all(np.isfinite(w)):
        raise MotionPlanningError("a joint path needs finite waypoints (M, n)")
    vmax, amax = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (max_velocity, max_acceleration))
    if vmax.shape != (w.shape[1],) or amax.shape != vmax.shape or np.any(vmax <= 0) or np.any(amax <= 0):
        raise MotionPlanningError("joint velocity and acceleration limits must be positive, one per joint")
    m, n = w.shape
    nominal = np.zeros(max(m - 1, 0)) if nominal_dt is None else np.asarray(nominal_dt, dtype=np.float64)
    gap = nominal.copy()                     # the seconds each gap takes (stationary: nominal)
    qd, qdd = np.zeros((m, n)), np.zeros((m, n))
    for a, b in _runs(w):
        t, v, acc = _time_run(w[a:b + 1], vmax, amax, None if nominal_dt is None else nominal[a:b])
        gap[a:b] = np.diff(t)
        qd[a:b + 1], qdd[a:b + 1] = v, acc
        qd[[a, b]] = 0.0                     # rest to rest
    return JointPath(np.concatenate([[0.0], np.cumsum(gap)]), w.copy(), qd, qdd)
