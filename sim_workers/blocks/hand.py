"""Where a block is in the floating gripper's hand, and how the hand turns to grasp a cube:
Y and Y^-1 of every block world read held blocks and grasp yaws with these."""
from __future__ import annotations

import numpy as np

from ..configuration import Configuration, face_yaw, rotate_z


# The box around the fingertips where a block counts as held (metres).
HAND_OPEN_MARGIN = 0.01          # opening above max_opening minus this: nothing is gripped
HAND_X_MARGIN = 0.012            # beyond the finger's half thickness, across the fingers
HAND_HALF_Y = 0.045              # along the fingers (half the widest opening)
HAND_DZ = (-0.05, 0.035)         # block centre relative to the tool point
HAND_MIN_Z = 0.06                # a held block is lifted off the floor


def in_hand(spec, config: Configuration, p: np.ndarray) -> bool:
    """Whether a block centred at `p` sits between the fingers of the gripper in `config`
    (``spec``: ``max_opening``, ``finger_half``)."""
    g = config.robot
    if g[4] > spec.max_opening - HAND_OPEN_MARGIN:       # fingers wide open: nothing is gripped
        return False
    local = rotate_z(p[:2] - g[:2], -g[3])
    dz = p[2] - g[2]
    return (abs(local[0]) < spec.finger_half[0] + HAND_X_MARGIN and abs(local[1]) < HAND_HALF_Y
            and HAND_DZ[0] < dz < HAND_DZ[1] and p[2] > HAND_MIN_Z)


def grasp_yaw(quat: np.ndarray) -> float:
    """The block's yaw folded into [-pi/4, pi/4): a cube looks the same every quarter turn."""
    yaw = face_yaw(quat)
    return float((yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4)


def closing_axis(quat: np.ndarray) -> np.ndarray:
    """The unit planar axis along which the fingers close on a block of orientation `quat`
    (the hand's local y at the block's grasp yaw): a perception error along it puts a
    finger on the block, one across it slides along the finger pads (measured: a 57.9 mm
    block gripped at 0.45 mm clearance holds at +-3.5 mm across, fails beyond +-2 mm along)."""
    yaw = grasp_yaw(quat)
    return np.array([-np.sin(yaw), np.cos(yaw)])


def pickup_misalignment(spec, config: Configuration, action: str, first_block_row: int):
    """The block domains' ``misalignment``: a pickup is aimed at its block's perceived
    position (row ``first_block_row`` + its index), and an error along the fingers'
    closing axis decides whether they pass either side of it; other actions: None."""
    from .terms import block_index, parse_action

    name, args = parse_action(action)
    if name != "pickup":
        return None
    row = first_block_row + block_index(spec, args[1])
    return row, closing_axis(config.objects[row, 3:])
