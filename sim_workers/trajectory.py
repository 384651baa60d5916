"""Timed gripper trajectories: rows of (t, x, y, z, yaw, opening), t in seconds from 0.

A trajectory may carry two more columns, the efforts a domain chose from the believed
mass (issue 14): ``grip_force`` (N per finger) and ``force_limit`` (N, the most the
wrist may exert beyond carrying the gripper's own weight). Without them the world uses
the scene's fixed grip force and wrist limit.
"""
from __future__ import annotations

import numpy as np

COLUMNS = ("t", "x", "y", "z", "yaw", "opening")
EFFORT_COLUMNS = ("grip_force", "force_limit")


def time_parameterize(waypoints: np.ndarray, speed: float, yaw_rate: float = 2.0,
                      finger_speed: float = 0.1, t0: float = 0.0, min_dt: float = 0.05) -> np.ndarray:
    """Give each (x, y, z, yaw, opening) waypoint the time the slowest channel needs.

    Yaw is unwrapped so the gripper turns the short way.
    """
    w = np.asarray(waypoints, dtype=np.float64).reshape(-1, 5).copy()
    w[:, 3] = np.unwrap(w[:, 3])
    dt = np.maximum.reduce([
        np.linalg.norm(np.diff(w[:, :3], axis=0), axis=1) / speed,
        np.abs(np.diff(w[:, 3])) / yaw_rate,
        np.abs(np.diff(w[:, 4])) / finger_speed,
        np.full(len(w) - 1, min_dt),
    ]) if len(w) > 1 else np.zeros(0)
    t = t0 + np.concatenate([[0.0], np.cumsum(dt)])
    return np.column_stack([t, w])


def trapezoid_stroke(start: np.ndarray, end: np.ndarray, speed: float, accel: float,
                     t0: float, dt: float = 0.05) -> np.ndarray:
    """A straight stroke with a trapezoidal velocity profile, sampled every `dt` seconds."""
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    dist = float(np.linalg.norm(end[:3] - start[:3]))
    t_acc = speed / accel
    if 2 * (0.5 * accel * t_acc ** 2) > dist:      # never reaches full speed
        t_acc = np.sqrt(dist / accel)
        speed = accel * t_acc
    t_flat = (dist - accel * t_acc ** 2) / speed
    total = 2 * t_acc + t_flat
    ts = np.append(np.arange(0.0, total, dt), total)

    def s_of(t):
        if t < t_acc:
            return 0.5 * accel * t * t
        if t < t_acc + t_flat:
            return 0.5 * accel * t_acc ** 2 + speed * (t - t_acc)
        tr = total - t
        return dist - 0.5 * accel * tr * tr

    frac = np.array([s_of(t) / dist if dist > 0 else 1.0 for t in ts])
    rows = start[None, :] + frac[:, None] * (end - start)[None, :]
    return np.column_stack([t0 + ts, rows])


def concatenate(*parts: np.ndarray) -> np.ndarray:
    """Join timed pieces; each later piece is shifted to start where the previous ended."""
    out = [np.asarray(parts[0], dtype=np.float64)]
    for part in parts[1:]:
        part = np.asarray(part, dtype=np.float64).copy()
        part[:, 0] += out[-1][-1, 0] - part[0, 0]
        out.append(part[1:])
    return np.vstack(out)


def sample(traj: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Every channel at `times` (held constant past the end): the pose and opening
    interpolated linearly, the efforts held from the last row at or before t (they are
    commands that switch, not quantities that move)."""
    traj = np.asarray(traj, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    cols = [np.interp(times, traj[:, 0], traj[:, k]) for k in range(1, len(COLUMNS))]
    if traj.shape[1] > len(COLUMNS):
        row = np.clip(np.searchsorted(traj[:, 0], times, side="right") - 1, 0, len(traj) - 1)
        cols += [traj[row, k] for k in range(len(COLUMNS), traj.shape[1])]
    return np.column_stack(cols)


def with_efforts(traj: np.ndarray, grip_force, force_limit) -> np.ndarray:
    """`traj` with the two effort columns (scalars or one value per row) appended."""
    traj = np.asarray(traj, dtype=np.float64)
    n = len(traj)
    return np.column_stack([traj, np.broadcast_to(grip_force, (n,)), np.broadcast_to(force_limit, (n,))])


def columns_of(traj: np.ndarray) -> tuple[str, ...]:
    """The column names of a validated trajectory."""
    return COLUMNS if np.asarray(traj).shape[-1] == len(COLUMNS) else COLUMNS + EFFORT_COLUMNS


def validate(traj) -> np.ndarray:
    arr = np.asarray(traj, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] not in (6, 8) or len(arr) < 1:
        raise ValueError(f"trajectory: expected shape (M, 6) (t, x, y, z, yaw, opening) or (M, 8) "
                         f"(... grip_force, force_limit), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError("trajectory: contains non-finite values")
    if np.any(np.diff(arr[:, 0]) < 0):
        raise ValueError("trajectory: times must not decrease")
    if arr.shape[1] == 8 and np.any(arr[:, 6:] <= 0):
        raise ValueError("trajectory: grip_force and force_limit must be positive")
    return arr
