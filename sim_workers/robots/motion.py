"""An arm's executed joint trajectory, as a grounded world follows it (issue 41): the
joints over time, and from them the world poses of the arm's link capsules at any time.

``ArmMotion`` is what a step hands the particle worlds and the simulated reality beside its
tool rows: the robot's name and base (so a world in another process builds the same arm
from the registry) and the joints at the trajectory's points. A world moves the links as
kinematic bodies along it (``GroundedWorld.execute``'s ``arm``): a position-controlled arm
of several kilograms is not pushed back by the blocks it meets, so the links push and the
blocks give. Between points the joints are interpolated linearly, as the tool rows are.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .base import Arm, robot
from .collision import Capsule

__all__ = ["ArmMotion", "capsule_frame", "frames_batch", "link_boxes", "link_poses"]


def frames_batch(dh, q: np.ndarray) -> np.ndarray:
    """Every link frame 1..6 in the arm's base frame for each row of `q` (S, 6): (S, 6, 4, 4);
    ``kinematics.frames`` for many joint vectors at once."""
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    s = len(q)
    out = np.empty((s, 6, 4, 4))
    t = np.broadcast_to(np.eye(4), (s, 4, 4)).copy()
    for i, (d, a, alpha) in enumerate(zip(dh.d, dh.a, dh.alpha)):
        ct, st = np.cos(q[:, i]), np.sin(q[:, i])
        ca, sa = math.cos(alpha), math.sin(alpha)
        link = np.zeros((s, 4, 4))
        link[:, 0, 0], link[:, 0, 1], link[:, 0, 2], link[:, 0, 3] = ct, -st * ca, st * sa, a * ct
        link[:, 1, 0], link[:, 1, 1], link[:, 1, 2], link[:, 1, 3] = st, ct * ca, -ct * sa, a * st
        link[:, 2, 1], link[:, 2, 2], link[:, 2, 3] = sa, ca, d
        link[:, 3, 3] = 1.0
        t = t @ link
        out[:, i] = t
    return out


@lru_cache(maxsize=256)
def capsule_frame(c: Capsule) -> tuple[np.ndarray, np.ndarray, float]:
    """A capsule's centre and rotation (its z axis along a -> b) in its link frame, and its
    half length between the cap centres."""
    a, b = np.asarray(c.a, dtype=np.float64), np.asarray(c.b, dtype=np.float64)
    axis = b - a
    length = float(np.linalg.norm(axis))
    z = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return 0.5 * (a + b), np.column_stack([x, np.cross(z, x), z]), 0.5 * length


def _quaternions(r: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) as unit quaternions (..., 4) in (x, y, z, w) order."""
    m = r.reshape(-1, 3, 3)
    w = np.sqrt(np.maximum(0.0, 1.0 + m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2])) / 2
    x = np.sqrt(np.maximum(0.0, 1.0 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2])) / 2
    y = np.sqrt(np.maximum(0.0, 1.0 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2])) / 2
    z = np.sqrt(np.maximum(0.0, 1.0 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2])) / 2
    x = np.copysign(x, m[:, 2, 1] - m[:, 1, 2])
    y = np.copysign(y, m[:, 0, 2] - m[:, 2, 0])
    z = np.copysign(z, m[:, 1, 0] - m[:, 0, 1])
    q = np.stack([x, y, z, w], axis=-1)
    return (q / np.linalg.norm(q, axis=-1, keepdims=True)).reshape(r.shape[:-2] + (4,))


@dataclass(frozen=True, eq=False)
class ArmMotion:
    """An arm's joints over a step's trajectory: `robot` (a registered arm's name), `base`
    (x, y, z, yaw in the world: the domain's ``robot_base``), `times` (K,) on the step's
    clock and `joints` (K, n) there."""

    robot: str
    base: tuple[float, float, float, float] | None
    times: np.ndarray
    joints: np.ndarray

    def __post_init__(self) -> None:
        times = np.asarray(self.times, dtype=np.float64).reshape(-1)
        joints = np.asarray(self.joints, dtype=np.float64)
        if joints.ndim != 2 or len(joints) != len(times) or not len(times):
            raise ValueError(f"arm: {len(times)} times for joints of shape {joints.shape}")
        if np.any(np.diff(times) < 0) or not np.all(np.isfinite(joints)):
            raise ValueError("arm: times must not decrease and joints must be finite")
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "joints", joints)

    @classmethod
    def from_goal(cls, robot_name: str, base, goal: dict, t0: float = 0.0) -> "ArmMotion":
        """From a FollowJointTrajectory goal's JSON (``JointPath.goal``, a session step's
        ``joint_trajectory``), its ``time_from_start`` counted from `t0` on the step's rows'
        clock (their first time)."""
        points = goal["points"]
        return cls(robot_name, None if base is None else tuple(float(v) for v in base),
                   float(t0) + np.array([float(p["time_from_start"]) for p in points]),
                   np.array([[float(v) for v in p["positions"]] for p in points]))

    def arm(self) -> Arm:
        """The arm, placed at `base`."""
        bot = robot(self.robot)
        if not isinstance(bot, Arm):
            raise ValueError(f"arm: robot {self.robot!r} is not an arm")
        return bot.placed(self.base)

    def at(self, t: np.ndarray) -> np.ndarray:
        """The joints at times `t` (S,): linear between points, held past either end."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        return np.column_stack([np.interp(t, self.times, self.joints[:, k]) for k in range(self.joints.shape[1])])


def link_poses(arm: Arm, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The world poses of `arm`'s link capsules at joint rows `q` (S, n): centres (S, L, 3)
    and quaternions (S, L, 4; x, y, z, w)."""
    fs = frames_batch(arm.dh, q)
    s = len(fs)
    pos = np.empty((s, len(arm.links), 3))
    rot = np.empty((s, len(arm.links), 3, 3))
    for k, c in enumerate(arm.links):
        centre, r_local, _ = capsule_frame(c)
        t = np.broadcast_to(arm.base, (s, 4, 4)) if c.frame == 0 else arm.base @ fs[:, c.frame - 1]
        pos[:, k] = t[:, :3, :3] @ centre + t[:, :3, 3]
        rot[:, k] = t[:, :3, :3] @ r_local
    return pos, _quaternions(rot)


def link_boxes(arm: Arm, positions: np.ndarray, quaternions: np.ndarray) -> np.ndarray:
    """World boxes (lo xyz, hi xyz) of each link capsule at each of its poses (centres
    (S, L, 3), quaternions (S, L, 4), as ``link_poses`` gives them): its axis segment's box
    grown by its radius; (S * L, 6)."""
    x, y, z, w = (quaternions[..., k] for k in range(4))
    axis = np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    half = np.array([capsule_frame(c)[2] for c in arm.links])[None, :, None]
    radius = np.array([c.radius for c in arm.links])[None, :, None]
    extent = np.abs(axis) * half + radius
    return np.concatenate([positions - extent, positions + extent], axis=-1).reshape(-1, 6)
