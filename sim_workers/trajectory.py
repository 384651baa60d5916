"""Timed gripper trajectories: rows of (t, x, y, z, yaw, opening), t in seconds from 0."""
from __future__ import annotations

import numpy as np

COLUMNS = ("t", "x", "y", "z", "yaw", "opening")


def wrap_angle(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


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
    """Linear interpolation of every channel at `times` (held constant past the end)."""
    traj = np.asarray(traj, dtype=np.float64)
    return np.column_stack([np.interp(times, traj[:, 0], traj[:, k]) for k in range(1, 6)])


def validate(traj) -> np.ndarray:
    arr = np.asarray(traj, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 6 or len(arr) < 1:
        raise ValueError(f"trajectory: expected shape (M, 6) (t, x, y, z, yaw, opening), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError("trajectory: contains non-finite values")
    if np.any(np.diff(arr[:, 0]) < 0):
        raise ValueError("trajectory: times must not decrease")
    return arr
