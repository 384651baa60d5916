"""Configurations, bounds and straight segments of the floating gripper's motion.

A configuration is ``q = (x, y, z, yaw)`` in metres / radians, a float64 array of shape
(4,). The conventions (yaw wrapping, resolution, the metric) are in the package's doc.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

YAW_WEIGHT = 0.1
"""Default metres of travel that one radian of yaw is worth in the planning metric."""

_COORDS = ("x", "y", "z", "yaw")
_TWO_PI = 2.0 * math.pi

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


def path_length(path: np.ndarray, yaw_weight: float = YAW_WEIGHT, wraps: bool = True) -> float:
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
