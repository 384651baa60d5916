"""The particle worlds meet what the robot perceived as the real gripper does: off by the
perception error.

A robot perceives the planar position of each movable object with noise of a declared std
(``RunConfig.perception_sigma``, per axis; the simulated reality adds exactly that), and
computes the action's pose from what it perceived. In the real world the gripper then
meets its target off by the perception error. A particle world replaying the trajectory
from the perceived configuration meets the target exactly where the plan aimed: it
predicts a grasp with a few millimetres of clearance to succeed every time, and when the
real one fails for the misalignment, the failure is charged to L (the large-block runs
of issue 37: one such failure moved the belief from the truth, 57.9 mm, to 34 mm, and
eight failed pickups followed).

So each particle world replays the trajectory the robot would have planned had it
perceived the objects elsewhere: the planar positions drawn N(perceived, sigma^2) per
axis (the true positions given the perceived ones, under a flat prior and Gaussian
perception), the action's key pose recomputed by Y from that draw, and the trajectory
shifted in the plane by the key pose's move. Relative to the world (the perceived
configuration, as before), the gripper is then off by exactly what perception does to the
real one, for the objects the pose depends on and no others: a pickup's block moves the
grasp, the container's tray (a fixture, perceived exactly) moves nothing, and a tower's
blocks stay as they stand, where drawing every object's start afresh would misalign them
(which made stacks and pushes fail in the worlds that do not fail in reality: at 45 mm
the plans fell back to four trips of two). Each world's outcome is a one-sample estimate
of the outcome marginalised over perception, so the likelihood of a real outcome under a
row is the action's success probability at that L given what the robot saw (a
pseudo-marginal likelihood; resampling averages its noise over steps). The draws come
from the session's seeded generator, before the fan-out: shards and machines change
nothing.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from sim_workers.configuration import Configuration
from sim_workers.reality_gap import perceived_planar

__all__ = ["perceived_trajectories", "world_starts"]

_XY = slice(1, 3)          # a trajectory's x and y columns (sim_workers.trajectory.COLUMNS)


def pose_offsets(domain, props: dict, config: Configuration, action: str, n: int, objects: Sequence[int],
                 sigma: float, rng: np.random.Generator) -> np.ndarray | None:
    """(n, 2): how far Y moves the action's key pose in the plane when the `objects` are
    perceived N(their perceived position, sigma^2) per axis, one draw per world; None
    with sigma 0 or no objects (no draw)."""
    rows = list(objects)
    if sigma <= 0 or not rows or n <= 0:
        return None
    base = np.asarray(domain.action_pose(props, config, action), dtype=np.float64)[:2]
    out = np.empty((n, 2), dtype=np.float64)
    for i in range(n):
        drawn = Configuration(config.robot, perceived_planar(rng, config.objects, rows, sigma))
        out[i] = np.asarray(domain.action_pose(props, drawn, action), dtype=np.float64)[:2] - base
    return out


def perceived_trajectories(domain, props: dict, start: np.ndarray, action: str, trajectory: np.ndarray,
                           n: int, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """The `n` worlds' trajectories: `trajectory` ((T, C) shared, or (n, T, C) one each)
    shifted in the plane by each world's ``pose_offsets`` under the believed `props`, as
    (n, T, C); `trajectory` itself with sigma 0 (no draw)."""
    config = Configuration.from_array(np.asarray(start, dtype=np.float64))
    offsets = pose_offsets(domain, props, config, action, n, domain.jittered_objects, sigma, rng)
    if offsets is None:
        return trajectory
    traj = np.asarray(trajectory, dtype=np.float64)
    out = np.array(np.broadcast_to(traj, (n, *traj.shape[-2:])), dtype=np.float64, copy=True)
    out[:, :, _XY] += offsets[:, None, :]
    return out


def world_starts(start: np.ndarray, n: int, objects: Sequence[int], sigma: float,
                 rng: np.random.Generator) -> np.ndarray:
    """`n` starting configurations (n, D) with the planar position of each of `objects`
    drawn N(perceived, sigma^2) per axis, one draw per world; with sigma 0 (or no objects)
    `start` itself (D,), no draw. (A shard takes a start per world: for a driver that
    knows its worlds' true configurations differ; the session shifts trajectories instead.)"""
    start = np.asarray(start, dtype=np.float64)
    rows = list(objects)
    if sigma <= 0 or not rows or n <= 0:
        return start
    config = Configuration.from_array(start)
    out = np.empty((n, start.size), dtype=np.float64)
    for i in range(n):
        out[i] = Configuration(config.robot, perceived_planar(rng, config.objects, rows, sigma)).to_array()
    return out
