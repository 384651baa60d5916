"""OMPL RRT* motion planning for the floating gripper.

A configuration is ``q = (x, y, z, yaw)`` in metres / radians, a float64 array of shape (4,).
The planners see only callables and arrays: the caller supplies ``is_valid(q) -> bool`` (the
world's own collision query, or :func:`box_checker` in unit tests), so this module never
imports pybullet, ``sim_workers`` or ``coordinator``.

Conventions (documented once here, relied on everywhere below):

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
  wall-clock safety cap: if it is hit, the result depends on CPU speed (the report says
  so in ``time_cap_hit`` and a warning is logged).
"""
from __future__ import annotations

import logging
import math
import operator
import threading
import time
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

__all__ = [
    "Bounds",
    "MotionPlanningError",
    "TransitReport",
    "YAW_WEIGHT",
    "box_checker",
    "interpolate_config",
    "plan_action",
    "plan_approach",
    "plan_transit",
    "unwrap_yaw",
]

_LOG = logging.getLogger(__name__)

YAW_WEIGHT = 0.1
"""Default metres of travel that one radian of yaw is worth in the planning metric."""

_COORDS = ("x", "y", "z", "yaw")
_TWO_PI = 2.0 * math.pi

# OMPL prints an Info line per solve and per simplification; a planner called once per
# action and particle would drown the service's logs. Warnings and errors still show.
ou.setLogLevel(ou.LogLevel.LOG_WARN)

# OMPL's seed is process-wide: two plans seeding and building RNGs at the same time in
# one process would interleave their seeds. Serialising plans keeps each deterministic.
_OMPL_LOCK = threading.Lock()

IsValid = Callable[[np.ndarray], bool]


class MotionPlanningError(ValueError):
    """A motion could not be planned; the message names the configuration and the reason."""


@dataclass(frozen=True, eq=False)
class Bounds:
    """Axis-aligned bounds of the configuration (x, y, z, yaw).

    Yaw bounds that span at least a full turn (typically ``[-pi, pi]``) mean "any angle":
    yaw then wraps and is never out of bounds. Narrower yaw bounds are enforced as a
    bounded interval without wrapping.
    """

    low: np.ndarray
    high: np.ndarray

    def __post_init__(self) -> None:
        low = np.array(self.low, dtype=np.float64)
        high = np.array(self.high, dtype=np.float64)
        if low.shape != (4,) or high.shape != (4,):
            raise MotionPlanningError(
                f"bounds must have shape (4,), got low {low.shape} and high {high.shape}")
        if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high))):
            raise MotionPlanningError("bounds must be finite")
        for i, name in enumerate(_COORDS):
            if not low[i] < high[i]:
                raise MotionPlanningError(
                    f"bounds on {name} are empty: low {low[i]} is not below high {high[i]}")
        low.setflags(write=False)
        high.setflags(write=False)
        # Frozen dataclass: store the validated read-only copies.
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def yaw_wraps(self) -> bool:
        """True when the yaw bounds cover a full turn, so yaw is a wrapping angle."""
        return bool(self.high[3] - self.low[3] >= _TWO_PI - 1e-9)

    def violations(self, q: np.ndarray) -> list[str]:
        """Names of the coordinates of ``q`` outside the bounds, with their values."""
        out = []
        last = 3 if self.yaw_wraps else 4
        for i in range(last):
            if q[i] < self.low[i] or q[i] > self.high[i]:
                out.append(f"{_COORDS[i]} ({_COORDS[i]}={q[i]:.6g} not in "
                           f"[{self.low[i]:.6g}, {self.high[i]:.6g}])")
        return out


@dataclass(frozen=True)
class TransitReport:
    """What one :func:`plan_transit` call did; passed to its ``on_report`` hook.

    ``method`` is ``"straight"`` when the straight segment was valid and RRT* was skipped,
    ``"rrtstar"`` otherwise. ``time_cap_hit`` means the result may not be reproducible.
    ``validity_calls`` counts every call of the caller's ``is_valid`` made by the call.
    """

    method: str
    seed: int
    iterations: int
    exact: bool
    time_cap_hit: bool
    plan_time_s: float
    simplify_time_s: float
    validity_calls: int
    n_waypoints: int
    path_length: float
    simplified: bool


# --------------------------------------------------------------------------- geometry


def _wrap(a: float) -> float:
    """Angle normalised to [-pi, pi)."""
    return (a + math.pi) % _TWO_PI - math.pi


def _yaw_delta(y0: float, y1: float, wraps: bool) -> float:
    """Signed yaw change from y0 to y1; the short way round when yaw wraps.

    Follows OMPL's SO2 interpolation rule (ties at exactly pi go the positive way from
    normalised angles), so the states checked here lie on the motions OMPL checked.
    """
    if not wraps:
        return y1 - y0
    d = _wrap(y1) - _wrap(y0)
    if d > math.pi:
        d -= _TWO_PI
    elif d < -math.pi:
        d += _TWO_PI
    return d


def interpolate_config(q0: np.ndarray, q1: np.ndarray, t: float, *,
                       wraps: bool = True) -> np.ndarray:
    """Configuration a fraction ``t`` of the way from q0 to q1 (yaw the short way if it wraps)."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    out = q0 + t * (q1 - q0)
    yaw = q0[3] + t * _yaw_delta(float(q0[3]), float(q1[3]), wraps)
    out[3] = _wrap(yaw) if wraps else yaw
    return out


def _densify(points: np.ndarray, step: float, yaw_weight: float, wraps: bool) -> np.ndarray:
    """Waypoints through ``points`` with position steps <= step and yaw steps <= step/yaw_weight.

    The first and last rows are copied bit-for-bit from ``points``; zero-length segments are
    dropped; interior yaws are normalised when yaw wraps.
    """
    rows = [points[0]]
    for a, b in zip(points[:-1], points[1:]):
        dyaw = _yaw_delta(float(a[3]), float(b[3]), wraps)
        dpos = float(np.linalg.norm(b[:3] - a[:3]))
        n = math.ceil(max(dpos / step, abs(dyaw) * yaw_weight / step) - 1e-12)
        if n <= 0:
            continue  # duplicate state: nothing to move
        t = np.arange(1, n + 1, dtype=np.float64)[:, None] / n
        seg = a + t * (b - a)
        yaw = a[3] + t[:, 0] * dyaw
        seg[:, 3] = (yaw + math.pi) % _TWO_PI - math.pi if wraps else yaw
        rows.extend(seg)
    if len(rows) == 1:
        rows.append(points[-1])
    out = np.array(rows, dtype=np.float64)
    out[0] = points[0]
    out[-1] = points[-1]  # exact endpoints, whatever rounding or yaw normalisation did
    return out


def _path_length(path: np.ndarray, yaw_weight: float, wraps: bool) -> float:
    """Length of a waypoint path in the planning metric |dp| + yaw_weight * |dyaw|."""
    total = 0.0
    for a, b in zip(path[:-1], path[1:]):
        total += float(np.linalg.norm(b[:3] - a[:3]))
        total += yaw_weight * abs(_yaw_delta(float(a[3]), float(b[3]), wraps))
    return total


def unwrap_yaw(path: np.ndarray) -> np.ndarray:
    """A copy of ``path`` whose yaw column is continuous (no 2*pi jumps), from the first yaw."""
    out = np.array(path, dtype=np.float64, copy=True)
    out[:, 3] = np.unwrap(out[:, 3])
    return out


def _fmt(q: np.ndarray) -> str:
    return ", ".join(f"{n}={v:.4f}" for n, v in zip(_COORDS, q))


def _as_config(name: str, q: object) -> np.ndarray:
    """``q`` as a fresh finite float64 array of shape (4,), or a MotionPlanningError naming it."""
    try:
        arr = np.array(q, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MotionPlanningError(f"{name} must be a finite array of shape (4,): {exc}") from None
    if arr.shape != (4,):
        raise MotionPlanningError(f"{name} must be a finite array of shape (4,), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise MotionPlanningError(f"{name} must be finite, got ({_fmt(arr)})")
    return arr


def _positive(name: str, v: float) -> float:
    v = float(v)
    if not (math.isfinite(v) and v > 0):
        raise MotionPlanningError(f"{name} must be a positive finite number, got {v}")
    return v


def _check_endpoint(name: str, q: np.ndarray, is_valid: IsValid, bounds: Bounds | None) -> None:
    if bounds is not None:
        bad = bounds.violations(q)
        if bad:
            raise MotionPlanningError(f"{name} ({_fmt(q)}) is out of bounds on " + ", ".join(bad))
    if not is_valid(q.copy()):
        raise MotionPlanningError(f"{name} ({_fmt(q)}) is in collision")


def _first_invalid(points: np.ndarray, is_valid: IsValid, skip_first: bool = False) -> int | None:
    """Index of the first row of ``points`` that ``is_valid`` rejects, or None."""
    for i in range(1 if skip_first else 0, len(points)):
        if not is_valid(points[i].copy()):  # copy: the callable may keep what it is given
            return i
    return None


# --------------------------------------------------------------------------- box checker


def box_checker(obstacles: Sequence[tuple[Sequence[float], Sequence[float]]],
                gripper_half_extents: Sequence[float] = (0.02, 0.085, 0.05), *,
                gripper_radius: float | None = None,
                margin: float = 0.0) -> Callable[[np.ndarray], bool]:
    """A pure-geometry validity checker: axis-aligned boxes against the gripper.

    ``obstacles`` are ``(center (3,), half_extents (3,))`` pairs. The gripper is a box of
    ``gripper_half_extents`` (along its own x, its own y = finger-opening direction, and z)
    centred at ``q[:3]`` and turned by ``q[3]`` about z, so yaw matters; or, when
    ``gripper_radius`` is given, a sphere of that radius (yaw then does not matter).
    Obstacles are inflated by ``margin``. Touching counts as collision; non-finite q is invalid.
    """
    boxes: list[tuple[float, float, float, float, float, float]] = []
    for k, (c, h) in enumerate(obstacles):
        c = np.asarray(c, dtype=np.float64)
        h = np.asarray(h, dtype=np.float64)
        if c.shape != (3,) or h.shape != (3,) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(h))):
            raise ValueError(f"obstacle {k} must be (center (3,), half_extents (3,)), finite")
        if np.any(h < 0):
            raise ValueError(f"obstacle {k} has negative half extents {h.tolist()}")
        boxes.append(tuple(float(v) for v in (*c, *(h + margin))))  # type: ignore[arg-type]

    # Pure-Python arithmetic on floats: called tens of thousands of times per RRT* run,
    # where per-call numpy overhead would dominate for a handful of boxes.
    if gripper_radius is not None:
        r = float(gripper_radius)
        if not (math.isfinite(r) and r >= 0):
            raise ValueError(f"gripper_radius must be a non-negative finite number, got {r}")
        r2 = r * r

        def sphere_valid(q: np.ndarray) -> bool:
            x, y, z = float(q[0]), float(q[1]), float(q[2])
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
                return False
            for cx, cy, cz, hx, hy, hz in boxes:
                dx = max(abs(x - cx) - hx, 0.0)
                dy = max(abs(y - cy) - hy, 0.0)
                dz = max(abs(z - cz) - hz, 0.0)
                if dx * dx + dy * dy + dz * dz <= r2:
                    return False
            return True

        return sphere_valid

    g = np.asarray(gripper_half_extents, dtype=np.float64)
    if g.shape != (3,) or not np.all(np.isfinite(g)) or np.any(g < 0):
        raise ValueError(f"gripper_half_extents must be 3 non-negative numbers, got {gripper_half_extents!r}")
    ga, gb, gz = (float(v) for v in g)

    def box_valid(q: np.ndarray) -> bool:
        x, y, z, yaw = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(yaw)):
            return False
        c, s = math.cos(yaw), math.sin(yaw)
        ac, as_ = abs(c), abs(s)
        # The gripper's footprint projected on the world axes (its xy bounding box).
        fx = ga * ac + gb * as_
        fy = ga * as_ + gb * ac
        for cx, cy, cz, hx, hy, hz in boxes:
            dz = z - cz
            if abs(dz) > hz + gz:
                continue
            dx, dy = x - cx, y - cy
            if abs(dx) > hx + fx or abs(dy) > hy + fy:
                continue
            # Separating-axis test on the gripper's own axes (the other two are done above).
            if abs(dx * c + dy * s) > ga + hx * ac + hy * as_:
                continue
            if abs(-dx * s + dy * c) > gb + hx * as_ + hy * ac:
                continue
            return False
        return True

    return box_valid


# --------------------------------------------------------------------------- OMPL glue


class _OmplChecker:
    """Adapts ``is_valid(np.ndarray)`` to OMPL states; counts calls and keeps the first error.

    An exception must not unwind through OMPL's C++ loop, so it is stored, the state is
    called invalid, the planner is told to stop, and the error is re-raised afterwards.
    Holds no OMPL objects, so no reference cycle (and no nanobind leak report) forms.
    """

    __slots__ = ("fn", "wraps", "calls", "error")

    def __init__(self, fn: IsValid, wraps: bool) -> None:
        self.fn = fn
        self.wraps = wraps
        self.calls = 0
        self.error: BaseException | None = None

    def __call__(self, state: object) -> bool:
        if self.error is not None:
            return False
        self.calls += 1
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


# --------------------------------------------------------------------------- planners


def plan_transit(start: np.ndarray, goal: np.ndarray, is_valid: IsValid, bounds: Bounds, *,
                 seed: int,
                 iterations: int = 500,
                 max_iterations: int | None = None,
                 time_limit_s: float = 5.0,
                 resolution: float = 0.01,
                 validity_resolution: float = 0.005,
                 yaw_weight: float = YAW_WEIGHT,
                 max_edge: float | None = None,
                 shortcut: bool = True,
                 on_report: Callable[[TransitReport], None] | None = None) -> np.ndarray:
    """A collision-free path from ``start`` to ``goal`` as an (M, 4) array of waypoints, M >= 2.

    RRT* runs ``iterations`` iterations (it keeps improving the path after the first
    solution); if it has no exact solution by then it goes on until one is found or
    ``max_iterations`` (default ``10 * iterations``) is reached. ``time_limit_s`` is a
    wall-clock safety cap on solving plus simplification (see the module docstring on
    determinism). The solution is simplified with OMPL's PathSimplifier, then interpolated
    to ``resolution``; every waypoint is checked with ``is_valid`` (falling back to the
    unsimplified path if a simplified waypoint fails).

    If ``shortcut`` and the straight segment start -> goal is valid (checked at
    ``validity_resolution``), it is returned without running RRT* (the optimum of the
    metric anyway). ``max_edge`` is RRT*'s range (None: OMPL's default, 0.2 of the space's
    extent). ``on_report`` receives a :class:`TransitReport` once per call.

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

    t0 = time.perf_counter()
    calls = 2  # the endpoint checks above
    if shortcut:
        fine = _densify(np.stack([start, goal]), validity_resolution, yaw_weight, wraps)
        bad = _first_invalid(fine[1:-1], is_valid)
        calls += len(fine) - 2 if bad is None else bad + 1
        if bad is None:
            path = _densify(np.stack([start, goal]), resolution, yaw_weight, wraps)
            bad = _first_invalid(path[1:-1], is_valid)
            calls += len(path) - 2 if bad is None else bad + 1
            if bad is None:
                if on_report is not None:
                    on_report(TransitReport(
                        method="straight", seed=seed, iterations=0, exact=True,
                        time_cap_hit=False, plan_time_s=time.perf_counter() - t0,
                        simplify_time_s=0.0, validity_calls=calls, n_waypoints=len(path),
                        path_length=_path_length(path, yaw_weight, wraps), simplified=False))
                return path

    with _OMPL_LOCK:
        result = _rrtstar(start, goal, is_valid, bounds, seed=seed, iterations=iterations,
                          max_iterations=max_iterations, time_limit_s=time_limit_s,
                          validity_resolution=validity_resolution, yaw_weight=yaw_weight,
                          max_edge=max_edge)
    raw, simplified, n_iter, exact, cap_hit, t_plan, t_simp, checker = result
    checker.calls += calls
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

    path = None
    used_simplified = False
    for candidate, is_simplified in ((simplified, True), (raw, False)):
        if candidate is None:
            continue
        pts = candidate.copy()
        pts[0], pts[-1] = start, goal
        dense = _densify(pts, resolution, yaw_weight, wraps)
        bad = _first_invalid(dense[1:-1], is_valid)
        checker.calls += len(dense) - 2 if bad is None else bad + 1
        if bad is None:
            path, used_simplified = dense, is_simplified
            break
    if path is None:
        raise MotionPlanningError(
            f"RRT* found a path from start ({_fmt(start)}) to goal ({_fmt(goal)}) but a "
            f"waypoint interpolated at resolution {resolution:g} is in collision; "
            f"decrease validity_resolution")
    if on_report is not None:
        on_report(TransitReport(
            method="rrtstar", seed=seed, iterations=n_iter, exact=exact, time_cap_hit=cap_hit,
            plan_time_s=t_plan, simplify_time_s=t_simp, validity_calls=checker.calls,
            n_waypoints=len(path), path_length=_path_length(path, yaw_weight, wraps),
            simplified=used_simplified))
    return path


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
    t1 = time.perf_counter()
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
    t2 = time.perf_counter()
    # No space.freeState(): the Python wrappers of allocState() own their states.
    return raw, simplified, n_iter, exact, cap[0], t1 - t0, t2 - t1, checker


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


def plan_action(start: np.ndarray, pre_pose: np.ndarray, particle_poses: np.ndarray,
                is_valid: IsValid, bounds: Bounds, *, seed: int,
                iterations: int = 500,
                max_iterations: int | None = None,
                time_limit_s: float = 5.0,
                resolution: float = 0.01,
                validity_resolution: float = 0.005,
                yaw_weight: float = YAW_WEIGHT,
                max_edge: float | None = None,
                shortcut: bool = True,
                on_report: Callable[[TransitReport], None] | None = None,
                ) -> tuple[np.ndarray, list[np.ndarray | None]]:
    """The motion of one action, shared between particles.

    The transit ``start -> pre_pose`` is planned once (:func:`plan_transit`, same keyword
    arguments; ``on_report`` fires once); each particle's approach ``pre_pose -> x_i`` is a
    short checked straight segment (:func:`plan_approach`), ``None`` where it is blocked or
    leaves ``bounds``. Raises MotionPlanningError if the transit itself fails (the pre-pose
    is shared, so no particle could use it).
    """
    poses = np.array(particle_poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 4:
        raise MotionPlanningError(f"particle_poses must have shape (N, 4), got {poses.shape}")
    finite = np.all(np.isfinite(poses), axis=1)
    if not np.all(finite):
        raise MotionPlanningError(
            f"particle_poses must be finite; row {int(np.argmin(finite))} is not")
    transit = plan_transit(start, pre_pose, is_valid, bounds, seed=seed, iterations=iterations,
                           max_iterations=max_iterations, time_limit_s=time_limit_s,
                           resolution=resolution, validity_resolution=validity_resolution,
                           yaw_weight=yaw_weight, max_edge=max_edge, shortcut=shortcut,
                           on_report=on_report)
    approaches: list[np.ndarray | None] = []
    for i, x_i in enumerate(poses):
        try:
            approaches.append(plan_approach(transit[-1], x_i, is_valid, resolution=resolution,
                                            validity_resolution=validity_resolution,
                                            yaw_weight=yaw_weight, bounds=bounds))
        except MotionPlanningError as exc:
            _LOG.debug("particle %d approach unavailable: %s", i, exc)
            approaches.append(None)
    return transit, approaches
