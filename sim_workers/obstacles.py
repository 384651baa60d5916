"""What the motion planner's check moves and avoids, as axis-aligned boxes.

The loop checks a transit with ``planner.motion.box_checker``: the gripper is one box
turned by its yaw, every obstacle an axis-aligned box (centre, half extents). A domain's
``obstacles`` and ``gripper_box`` build those boxes from an observed configuration and
believed sizes with the helpers here. Each box is the tightest one around its body (the
check is only as good as its model: a box wider than the body it stands for puts real
free space, such as a push's pre-pose behind a tower, out of reach).
"""
from __future__ import annotations

import numpy as np

from .configuration import quat_to_matrix

# Room added around the gripper's fingers and a held block: the tightest boxes touch what
# they stand for, and touching counts as collision.
GRIPPER_MARGIN = 0.001      # m


def body_box(pose: np.ndarray, half: np.ndarray, offset=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half extents) of the axis-aligned box around a box of `half` extents whose
    centre sits at `offset` in the frame of a body at `pose` (x, y, z, quaternion x, y, z,
    w): the exact bounds at the body's observed orientation."""
    pose = np.asarray(pose, dtype=np.float64)
    rot = quat_to_matrix(pose[3:7])
    return pose[:3] + rot @ np.asarray(offset, dtype=np.float64), np.abs(rot) @ np.asarray(half, dtype=np.float64)


def cube_box(pose: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """The box around a cube of side `size` at `pose`: s/2 each way upright and square to
    the axes, s/sqrt(2) across turned by 45 degrees, up to s * sqrt(3)/2 on a corner."""
    return body_box(pose, np.full(3, 0.5 * float(size)))


def gripper_box(palm_half, finger_half, palm_offset: float, max_opening: float,
                held_size: float = 0.0) -> tuple[np.ndarray, float]:
    """(half extents, z of its centre above the fingertips) of one box around the gripper:
    fingers at their widest and the palm, and a held block of side `held_size` (0: none)
    hanging below the fingertips between the fingers, as wide across them as it is."""
    fx, fy, _ = finger_half
    top = palm_offset + palm_half[2]
    across = max(fx, 0.5 * held_size) + GRIPPER_MARGIN     # the block is gripped square
    half = np.array([across, max_opening / 2 + 2 * fy, (top + held_size) / 2])
    return half, (top - held_size) / 2


def per_block(size, n_blocks: int) -> np.ndarray:
    """Believed sizes, one per block: `size` as given (n_blocks,) or one for all."""
    return np.broadcast_to(np.asarray(size, dtype=np.float64), (n_blocks,))
