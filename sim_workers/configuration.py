"""A scene's continuous configuration as plain arrays: what a world is reset to and reports."""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np


class Workspace(NamedTuple):
    """Bounds (x, y, z, yaw) a domain's motions need, as plain arrays: the coordinator makes
    them the motion planner's ``planner.motion.Bounds`` (sim_workers never imports planner)."""

    low: np.ndarray
    high: np.ndarray


@dataclass(frozen=True)
class Configuration:
    """Robot and object poses.

    robot:   (5,)  gripper tool point x, y, z (m), yaw (rad), finger opening (m)
    objects: (M, 7) per object position (x, y, z) and quaternion (x, y, z, w), in the
             domain's object order (for the container domain: c, b1..bN)
    """

    robot: np.ndarray
    objects: np.ndarray

    def __post_init__(self) -> None:
        robot = np.asarray(self.robot, dtype=np.float64).reshape(5)
        objects = np.asarray(self.objects, dtype=np.float64)
        if objects.ndim != 2 or objects.shape[1] != 7:
            raise ValueError(f"objects: expected shape (M, 7), got {objects.shape}")
        if not (np.isfinite(robot).all() and np.isfinite(objects).all()):
            raise ValueError("configuration: poses must be finite")
        object.__setattr__(self, "robot", robot)
        object.__setattr__(self, "objects", objects)

    def to_array(self) -> np.ndarray:
        """Flat float64 vector (5 + 7M,): the wire format between coordinator and shards."""
        return np.concatenate([self.robot, self.objects.ravel()])

    @classmethod
    def from_array(cls, flat: np.ndarray) -> "Configuration":
        flat = np.asarray(flat, dtype=np.float64)
        if flat.ndim != 1 or (flat.size - 5) % 7:
            raise ValueError(f"configuration vector: bad length {flat.size}")
        return cls(flat[:5], flat[5:].reshape(-1, 7))

    def to_dict(self) -> dict:
        return {"robot": self.robot.tolist(), "objects": self.objects.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Configuration":
        return cls(np.asarray(d["robot"]), np.asarray(d["objects"]))

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Configuration) and np.array_equal(self.robot, other.robot)
                and np.array_equal(self.objects, other.objects))

    __hash__ = None  # type: ignore[assignment]


def yaw_of(quat: np.ndarray) -> float:
    """Rotation about z of a body's x axis, from a quaternion (x, y, z, w)."""
    x, y, z, w = quat
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (x, y, z, w); columns are the body axes in the world."""
    x, y, z, w = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def face_yaw(quat: np.ndarray) -> float:
    """Yaw of a box resting on any face: the heading of its most horizontal body axis.

    A block that fell on its side has its x axis vertical; the x axis' heading is then
    meaningless, but the axes lying flat still say how the faces are turned.
    """
    return level_axis_heading(quat_to_matrix(quat))


def level_axis_heading(R: np.ndarray) -> float:
    """``face_yaw`` of a rotation matrix already computed."""
    j = int(np.argmin(np.abs(R[2, :])))
    return float(np.arctan2(R[1, j], R[0, j]))


def quat_from_yaw(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(yaw / 2.0), np.cos(yaw / 2.0)])


def rotate_z(xy: np.ndarray, yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * xy[0] - s * xy[1], s * xy[0] + c * xy[1]])
