"""What the motion planner's check moves and avoids, as boxes.

The loop checks a transit with ``planner.motion.box_checker``: the gripper is a few boxes
turned by its yaw (:func:`hand_boxes`: palm, fingers, held block), every obstacle a box
(centre, half extents, rotation). A domain's ``obstacles`` and ``gripper_boxes`` build
them from an observed configuration and believed sizes with the helpers here. Each box is
the body itself as observed, turned or tipped as it lies: a box around it, wider than
the body, would put real free space out of reach (a push's pre-pose 3 mm behind a tower,
a held block beside a leaning one).
"""
from __future__ import annotations

import numpy as np

from .configuration import quat_to_matrix

# Room added around the gripper's parts and a held block: the tightest boxes touch what
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


def hand_boxes(palm_half, finger_half, palm_offset: float, opening: float,
               held_size: float = 0.0, grip_depth: float = 0.0) -> list[tuple[np.ndarray, float]]:
    """The gripper as the boxes the check moves, (half extents in its own frame, z of the
    centre above the fingertips) each: the palm (wide along the fingers' opening, thin
    across), the fingers `opening` apart, and a held block of side `held_size` (0: none)
    between them, its top `grip_depth` above the fingertips (Y's grasp), gripped square."""
    m = GRIPPER_MARGIN
    fx, fy, fz = finger_half
    palm = (np.array(palm_half, dtype=np.float64) + m, palm_offset)
    # One box for both fingers and the space between them: a transit that passed a block
    # between the open fingers (a millimetre or two from its faces, at the believed size)
    # would be a grasp the particle worlds never simulate, not free space.
    fingers = (np.array([fx + m, opening / 2 + 2 * fy + m, fz + m / 2]), fz - m / 2)
    if held_size <= 0:
        return [palm, fingers]
    hang = held_size - grip_depth + m                 # how far the block reaches below the tips
    block = (np.array([held_size / 2 + m, held_size / 2 + m, (grip_depth + hang) / 2]), (grip_depth - hang) / 2)
    return [palm, fingers, block]


def per_block(size, n_blocks: int) -> np.ndarray:
    """Believed sizes, one per block: `size` as given (n_blocks,) or one for all."""
    return np.broadcast_to(np.asarray(size, dtype=np.float64), (n_blocks,))
