"""What the motion planner's check moves and avoids, as boxes.

The loop checks a transit with ``planner.motion.box_checker``: the gripper is one box
turned by its yaw (:func:`hand_box`), every obstacle a box (centre, half extents,
rotation). A domain's ``obstacles`` and ``gripper_box`` build those boxes from an observed configuration and
believed sizes with the helpers here. Each box is the body itself as observed, turned or
tipped as it lies (a box around it, wider than the body, would put real free space out of
reach: a push's pre-pose 3 mm behind a tower, a stack's block beside a leaning one).
"""
from __future__ import annotations

import numpy as np

from .configuration import quat_to_matrix

# Room added around the gripper's fingers and a held block: the tightest boxes touch what
# they stand for, and touching counts as collision.
GRIPPER_MARGIN = 0.001      # m

Box = tuple[np.ndarray, np.ndarray, np.ndarray]


def body_box(pose: np.ndarray, half, offset=(0.0, 0.0, 0.0)) -> Box:
    """(centre, half extents, rotation) of a box of `half` extents whose centre sits at
    `offset` in the frame of a body at `pose` (x, y, z, quaternion x, y, z, w)."""
    pose = np.asarray(pose, dtype=np.float64)
    rot = quat_to_matrix(pose[3:7])
    return pose[:3] + rot @ np.asarray(offset, dtype=np.float64), np.array(half, dtype=np.float64), rot


def cube_box(pose: np.ndarray, size: float) -> Box:
    """The box of a cube of side `size` at `pose`."""
    return body_box(pose, np.full(3, 0.5 * float(size)))


def hand_box(palm_half, finger_half, palm_offset: float, max_opening: float,
                held_size: float = 0.0, grip_depth: float = 0.0) -> tuple[np.ndarray, float]:
    """(half extents, z of its centre above the fingertips) of one box around the gripper:
    fingers at their widest and the palm, and a held block of side `held_size` (0: none)
    between the fingers, its top `grip_depth` above the fingertips (Y's grasp), as wide
    across them as it is."""
    fx, fy, _ = finger_half
    top = palm_offset + palm_half[2]
    below = max(held_size - grip_depth, 0.0) + (GRIPPER_MARGIN if held_size > 0 else 0.0)
    across = max(fx, 0.5 * held_size) + GRIPPER_MARGIN     # the block is gripped square
    half = np.array([across, max_opening / 2 + 2 * fy, (top + below) / 2])
    return half, (top - below) / 2


def per_block(size, n_blocks: int) -> np.ndarray:
    """Believed sizes, one per block: `size` as given (n_blocks,) or one for all."""
    return np.broadcast_to(np.asarray(size, dtype=np.float64), (n_blocks,))
