"""Where a block is in the floating gripper's hand, and how the hand turns to grasp a cube:
Y and Y^-1 of every block world read held blocks and grasp yaws with these."""
from __future__ import annotations

import numpy as np

from ..configuration import Configuration, level_axis_heading, quat_to_matrix, rotate_z


# The block domains' option ranges (``PhysicsDomain.option_ranges``): wide around the
# calibrated values, narrow enough that no request costs unbounded CPU (a step at most
# 1/60 s and at least 1/1000 s, at most 400 solver iterations, 5 s of settling, speeds at
# least 2 cm/s) or breaks the likelihood (a sensor sigma of at least 1 mN).
BLOCK_OPTION_RANGES: dict[str, tuple[float, float]] = {
    "time_step": (1.0 / 1000.0, 1.0 / 60.0), "solver_iterations": (10, 400), "settle_s": (0.0, 5.0),
    "move_speed": (0.02, 2.0), "approach_speed": (0.02, 2.0), "lift_speed": (0.02, 2.0),
    "push_speed": (0.02, 2.0), "finger_speed": (0.02, 2.0), "push_accel": (0.1, 50.0),
    "push_decel": (0.1, 50.0), "push_time_jitter": (0.0, 0.9), "weigh_s": (0.01, 2.0),
    "force_sigma": (1e-3, 100.0), "density": (1.0, 25000.0), "density_low": (1.0, 25000.0),
    "density_high": (1.0, 25000.0), "grip_force": (0.1, 200.0), "base_max_force": (1.0, 2000.0),
    "grip_depth": (0.0, 0.05), "grip_depth_ratio": (0.0, 0.9), "grasp_clearance": (0.0, 0.02),
}

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


def grip_depth(spec, size):
    """How far below a block's believed top Y puts the fingertips, for believed side(s)
    `size` (a float or an array): ``max(grip_depth, grip_depth_ratio * size)``.

    Why it scales with the size: carried, the block is held by a contact patch as tall as
    the grip depth d, and the carry's accelerations act at its centre of mass, (s - d) / 2
    below the patch's centre; the torque that turns it in the fingers grows with that lever
    arm and the patch resists it in proportion to its length, so what decides a pivot is
    (s - d) / (2 d). At the prior's smallest block (30 mm) a 10 mm grip gives 1, and no
    block that size ever pivots; a fixed 10 mm gives 2.4 at 58 mm, where a carried block
    pivots and stacks of four fail (0 of 8 held in the probes). d = s / 3 keeps the ratio at
    1 for every size (the ratio of 0 keeps the fixed depth of issue 40's report)."""
    s = np.asarray(size, dtype=np.float64)
    d = np.maximum(spec.grip_depth, spec.grip_depth_ratio * s)
    return float(d) if d.ndim == 0 else d


def grip_height(spec, size):
    """The fingertips' height above a gripped block's base, for believed side(s) `size`:
    the size less ``grip_depth`` (Y's grasp, release and held-block poses all stand on it)."""
    return size - grip_depth(spec, size)


UPRIGHT_COS = float(np.cos(np.radians(10.0)))  # a face within 10 degrees of up


def upright(quat: np.ndarray) -> bool:
    """A cube rests on a face: one body axis is within 10 degrees of vertical."""
    return bool(np.max(np.abs(quat_to_matrix(quat)[2, :])) > UPRIGHT_COS)


def grasp_yaw(quat: np.ndarray) -> float:
    """The hand's yaw for a grasp of a block turned by `quat`. A block resting on a face looks
    the same every quarter turn: its yaw folded into [-pi/4, pi/4). A block resting on an
    edge (leaning on another) has one pair of vertical faces only, those normal to its most
    horizontal body axis, so the fingers close along that axis (the hand's y at yaw 0), the
    yaw folded into [-pi/2, pi/2) (the hand is the same a half turn round). Folded a quarter
    turn instead, the fingers closed across the tilted faces of a block leaning 40-90 degrees
    on its neighbour and missed it in every world; along its level axis they hold it in
    every world (docs/RESULTS.md, "A block leaning on the one the plan picks")."""
    R = quat_to_matrix(quat)          # once: Y^-1 asks this of every block of every particle
    yaw = level_axis_heading(R)
    if np.max(np.abs(R[2, :])) > UPRIGHT_COS:         # upright(quat)
        return float((yaw + np.pi / 4) % (np.pi / 2) - np.pi / 4)
    return float(yaw % np.pi - np.pi / 2)


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


def quarter_turn(yaw: float) -> float:
    """The other face pair of a cube under the fingers: `yaw` (folded, [-pi/4, pi/4)) a
    quarter turn round, towards zero so that the hand turns at most pi/2."""
    return float(yaw + np.pi / 2 if yaw < 0 else yaw - np.pi / 2)


def grasp_alternatives(spec, config: Configuration, action: str, pose: np.ndarray,
                       largest: float, first_block_row: int) -> list[np.ndarray]:
    """The block domains' ``pose_alternatives``: a pickup's grasp a quarter turn round (the
    cube's other pair of faces between the fingers), offered when another block stands
    within reach of the open fingers; other actions, or nothing within reach: none.

    Within reach: a block's centre closer to the target's than the open fingers' outer
    faces (half the opening plus a finger's thickness) plus the largest believed block's
    half diagonal, the farthest its footprint reaches in any direction. Beyond that no
    finger of either grasp can touch it and a cube's two grasps are the same grasp, so the
    worlds are not asked (a bound, not a tuned margin: blocks 71-80 mm apart in their slots
    are within reach from about 50 mm up)."""
    from .terms import block_index, parse_action

    name, args = parse_action(action)
    if name != "pickup":
        return []
    pose = np.asarray(pose, dtype=np.float64)
    n = len(spec.block_names)
    row = first_block_row + block_index(spec, args[1])
    others = [first_block_row + i for i in range(n) if first_block_row + i != row]
    if not others:
        return []
    reach = 0.5 * float(pose[4]) + 2.0 * spec.finger_half[1] + np.sqrt(0.5) * float(largest)
    d = np.linalg.norm(config.objects[others, :2] - config.objects[row, :2], axis=1)
    if not np.any(d < reach):
        return []
    alt = pose.copy()
    alt[3] = quarter_turn(float(pose[3]))
    return [alt]


# Between an open finger's outer face and the nearest reach of another object: a finger
# that grazes a neighbour on the way down moves it, and with it the grasp.
FINGER_GAP = 0.002


def finger_room(spec, config: Configuration, row: int, others: dict[int, float]) -> float:
    """Half the widest opening the scene leaves a grasp of the object in `row`: along the
    fingers' closing axis, the distance to the nearest reach of another object whose reach
    comes within a finger's width across it, less a finger's thickness and ``FINGER_GAP``
    (inf where nothing is in the way). `others`: row -> the farthest that object reaches
    from its centre in the plane (a cube's half diagonal at the largest believed side), a
    number or one per row of L (then the room is one per row)."""
    centre = config.objects[row, :2]
    axis = closing_axis(config.objects[row, 3:])
    across = np.array([-axis[1], axis[0]])
    room = np.inf
    for j, reach in others.items():
        if j == row:
            continue
        d = config.objects[j, :2] - centre
        reach = np.asarray(reach, dtype=np.float64)
        near = abs(float(d @ across)) < spec.finger_half[0] + reach
        room = np.minimum(room, np.where(near, abs(float(d @ axis)) - reach - 2.0 * spec.finger_half[1] - FINGER_GAP,
                                         np.inf))
    return room if np.ndim(room) else float(room)


def pickup_opening(spec, config: Configuration, row: int, s, others: dict[int, float]):
    """``grasp_opening`` for the object in `row`, its room from `others` (``finger_room``);
    ``open_ratio`` * s without a clearance, the room not computed."""
    if float(getattr(spec, "grasp_clearance", 0.0)) <= 0.0:
        return spec.open_ratio * s
    return grasp_opening(spec, s, finger_room(spec, config, row, others))


def grasp_opening(spec, s, room: float):
    """Y's pre-grasp opening for believed side(s) `s`: ``open_ratio`` sides, widened to
    s + 2 ``grasp_clearance`` where the scene leaves the fingers `room` (``finger_room``),
    never past the hand's gripping range. With ``grasp_clearance`` 0: ``open_ratio`` * s
    exactly, as before the option.

    Why widen: a pickup is aimed at the block's perceived position, and an error along the
    closing axis beyond the clearance plus about 1.5 mm puts a finger on the block (a
    45 mm block at 1.15 sides holds for errors up to 4 mm; at 57 mm open, up to 6 mm).
    Under the runs' 2 mm camera the 1.15 sides miss 1-5 % of pickups (the small end
    worst); a clearance of 3 sigma (6 mm) per side misses about 0.3 %."""
    base = spec.open_ratio * s
    clearance = float(getattr(spec, "grasp_clearance", 0.0))
    if clearance <= 0.0:
        return base
    wide = np.minimum(np.asarray(s, dtype=np.float64) + 2.0 * clearance,
                      np.minimum(2.0 * np.asarray(room, dtype=np.float64),
                                 spec.max_opening - HAND_OPEN_MARGIN - FINGER_GAP))
    out = np.maximum(base, wide)
    return out if np.ndim(s) else float(out)
