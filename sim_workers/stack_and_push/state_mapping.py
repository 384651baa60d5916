"""Y and Y^-1 for the stack-and-push domain, in plain numpy.

Y^-1 (``symbolic_state``) reads where each block is from the configuration alone, never
from sizes: held, in the tower (the ``on`` chain rooted at the start site), delivered
(goal), in its supply slot (init), lying in the rail, or elsewhere on the table. Y
(``action_pose``) turns believed sizes, the observed configuration and an action into the
key pose (x, y, z, yaw, opening). ``place_for_sizes`` re-grounds an observation under one
hypothesis: the tower is restacked from the rail floor with the hypothesis' sizes.
"""
from __future__ import annotations

import numpy as np

from ..configuration import Configuration, quat_from_yaw
from ..blocks.hand import UPRIGHT_COS, upright  # noqa: F401  (used as state_mapping.*)
from ..blocks.hand import pickup_opening
from ..blocks.hand import grasp_yaw as _grasp_yaw, grip_height as _grip_height, in_hand as _in_hand
from ..blocks.terms import block_index, parse_action  # noqa: F401  (used as state_mapping.*)
from .spec import StackAndPushSpec

HELD, TOWER, GOAL, INIT, RAIL, TABLE = "held", "tower", "goal", "init", "rail", "table"
PICKUP_PLACES = (INIT, TABLE, RAIL)

# Y^-1 thresholds (metres), wide enough for any size validate_sizes accepts (0.01..0.10).
BOTTOM_MAX_Z = 0.055    # ... and resting on the floor (centre below half the largest size)
ON_DXY = 0.02           # B on B2: centres this close in the plane
ON_DZ = (0.005, 0.105)  # ... and B's centre this much higher (half sizes summed)
INIT_RADIUS = 0.02
FLOOR_Z = 0.055         # a block with its centre below this lies on the floor


def in_rail(spec: StackAndPushSpec, p: np.ndarray) -> bool:
    return abs(p[1]) < spec.rail_half_gap and spec.rail_x[0] < p[0] < spec.rail_x[1]


def in_goal_area(spec: StackAndPushSpec, p: np.ndarray) -> bool:
    return in_rail(spec, p) and spec.goal_x[0] <= p[0] <= spec.goal_x[1]


def site_reach(spec: StackAndPushSpec) -> float:
    """How far along the rail from the start site a block on the floor is the tower's base.

    A block of side s1 released at the site overlaps one of side s2 lying dx away when
    |dx| < (s1 + s2) / 2, at most the prior's largest side. A block that close is where the
    next stack lands whatever the sizes, so it is the tower's base: stacks go onto it and
    the push starts behind it. A narrower window called a block 33 mm off the site
    "rail", and with a second one 45 mm behind it every 60 mm stack at the site landed
    across the two, failed and was tried again until `max_steps` (60 failed actions)."""
    return float(spec.prior_high)


def tower_chain(spec: StackAndPushSpec, config: Configuration, held: set[int] | frozenset = frozenset()) -> list[int]:
    """Block indices of the tower, bottom first: the ``on`` chain rooted at the start site
    (its base a floor block within ``site_reach`` of the site)."""
    obj = config.objects
    free = [i for i in range(spec.n_blocks) if i not in held and upright(obj[i, 3:])]
    reach = site_reach(spec)

    def on(i: int, j: int) -> bool:
        return (np.linalg.norm(obj[i, :2] - obj[j, :2]) < ON_DXY
                and ON_DZ[0] < obj[i, 2] - obj[j, 2] < ON_DZ[1])

    bottoms = [i for i in free if in_rail(spec, obj[i, :3]) and abs(obj[i, 0] - spec.start_x) < reach
               and obj[i, 2] < BOTTOM_MAX_Z and not any(on(i, j) for j in free if j != i)]
    # The tallest tower standing in the window, the nearest to the site among equals: after
    # a topple a tower may stand on a block beside a lone one nearer the site, and calling
    # the lone one the base would make the standing tower's blocks "rail" blocks to pick off
    # it. Not the lowest: heights differ only by the sizes and the readings' noise.
    bottoms.sort(key=lambda i: (abs(obj[i, 0] - spec.start_x), obj[i, 2], i))
    best: list[int] = []
    for bottom in bottoms:
        chain = [bottom]
        while True:
            above = [i for i in free if i not in chain and on(i, chain[-1])]
            if not above:
                break
            chain.append(min(above, key=lambda i: (obj[i, 2], i)))   # nothing between
        if len(chain) > len(best):
            best = chain
    return best


def _held(spec: StackAndPushSpec, config: Configuration) -> int | None:
    """The block in the hand (the nearest, if several pass the in-hand test)."""
    cands = [i for i in range(spec.n_blocks) if _in_hand(spec, config, config.objects[i, :3])]
    if not cands:
        return None
    return min(cands, key=lambda i: float(np.linalg.norm(config.objects[i, :3] - config.robot[:3])))


def block_labels(spec: StackAndPushSpec, config: Configuration) -> tuple[list[str], list[int]]:
    """(label per block, tower chain bottom first)."""
    h = _held(spec, config)
    held = frozenset() if h is None else frozenset({h})
    chain = tower_chain(spec, config, held)
    labels = []
    for i in range(spec.n_blocks):
        p = config.objects[i, :3]
        if i in held:
            labels.append(HELD)
        elif i in chain:
            labels.append(TOWER)
        elif p[0] > spec.delivered_x - 0.05:
            labels.append(GOAL)
        elif np.linalg.norm(p[:2] - spec.init_slot(i)) < INIT_RADIUS:
            labels.append(INIT)
        elif in_rail(spec, p):
            labels.append(RAIL)
        else:
            labels.append(TABLE)
    return labels, chain


def symbolic_state(spec: StackAndPushSpec, config: Configuration) -> frozenset[str]:
    """Y^-1: the ground atoms that hold in a configuration."""
    labels, chain = block_labels(spec, config)
    names = spec.block_names
    atoms = set()
    for name, label in zip(names, labels):
        if label == HELD:
            atoms.add(f"is_holding(r,{name})")
        elif label != TOWER:
            atoms.add(f"is_in({name},{label})")
    for k, i in enumerate(chain):
        atoms.add(f"on({names[i]},{'start' if k == 0 else names[chain[k - 1]]})")
    if HELD not in labels:
        atoms.add("hand_empty(r)")
    return frozenset(atoms)


# The release opening over the believed side: a cube that turned in the fingers while
# carried spans up to sqrt(2) = 1.414 sides between them; 1.5 clears that by 2.6-5 mm over
# the prior (the pads' give, a slight tilt).
RELEASE_RATIO = 1.5


def lying_on_blocks(spec: StackAndPushSpec, objects: np.ndarray) -> np.ndarray:
    """(n_blocks,) whether each block lies on another: one whose centre is within the
    prior's largest side of its own in the plane (a block left across two counts) and
    lower by more than (low + high) / 4 of the prior (22.5 mm), up to ``ON_DZ``'s top. Two
    blocks on the floor differ by at most (high - low) / 2 (15 mm), one on another by at
    least low (30 mm): the bound is midway, 2.7 sigma of two 2 mm readings' difference
    from either. One pass over the pairs, as a particle's re-grounding asks of every block."""
    p = objects[:spec.n_blocks]
    near = np.linalg.norm(p[:, None, :2] - p[None, :, :2], axis=-1) < spec.prior_high
    dz = p[:, None, 2] - p[None, :, 2]
    on = near & (dz > 0.25 * (spec.prior_low + spec.prior_high)) & (dz < ON_DZ[1])
    np.fill_diagonal(on, False)
    return on.any(axis=1)


def rests_on_a_block(spec: StackAndPushSpec, objects: np.ndarray, i: int) -> bool:
    """Whether block i lies on another (``lying_on_blocks``)."""
    return bool(lying_on_blocks(spec, objects)[i])


def _support(spec: StackAndPushSpec, objects: np.ndarray, i: int, s):
    """What block i's grasp stands on, for believed side(s) `s`: if it lies on another
    block, its believed bottom (its observed centre less half its believed side: a block a
    failed stack or a topple left there is grasped where it is, where a grasp at the
    floor's height only knocked it off, planned again every time); else the floor. Not for
    any block seen above the floor: one caught on the outside of the fingers rides along
    with a grasp aimed where it is seen, and was chased 29 times in a row; a grasp at the
    floor's height drags it off."""
    if rests_on_a_block(spec, objects, i):
        return objects[i, 2] - 0.5 * (np.asarray(s, dtype=np.float64) if np.ndim(s) else s)
    return 0.0 if np.ndim(s) == 0 else np.zeros(np.shape(s))


def release_opening(spec: StackAndPushSpec, s):
    """How wide the fingers open to let go of a stacked block of believed side(s) `s`:
    ``RELEASE_RATIO`` sides, at most ``max_opening``. The grasp's 1.15 sides left a 40 mm
    block that had turned in the fingers wedged there: the same stack failed six times in a
    row with the block still held. (Fully open, 90 mm, the fingers of a release onto a
    tower of two came near enough to the blocks a particle world leaves out that the
    world's outcome moved 0.25 mm from the full world's.)"""
    return np.minimum(spec.max_opening, RELEASE_RATIO * np.asarray(s, dtype=np.float64)) if np.ndim(s) \
        else min(spec.max_opening, RELEASE_RATIO * s)


def _pickup_opening(spec: StackAndPushSpec, config: Configuration, i: int, s):
    """The grasp's opening for block i at believed side(s) `s` (``blocks.hand.grasp_opening``):
    the other blocks, each reaching the prior's largest half diagonal, bound the room."""
    reach = float(np.sqrt(0.5) * spec.prior_high)
    return pickup_opening(spec, config, i, s, {j: reach for j in range(spec.n_blocks)})


def _rear_half(s: float, quat: np.ndarray) -> float:
    """How far a cube of side s, turned by its folded yaw, reaches behind its centre."""
    y = _grasp_yaw(quat)
    return 0.5 * s * (abs(np.cos(y)) + abs(np.sin(y)))


def action_pose(spec: StackAndPushSpec, sizes: np.ndarray, config: Configuration, action: str) -> np.ndarray:
    """Y(L, s, a): the key pose (x, y, z, yaw, opening) of `action` under believed sizes."""
    name, args = parse_action(action)
    obj = config.objects
    if name == "pickup":
        i = block_index(spec, args[1])
        s = sizes[i]
        z = max(_support(spec, obj, i, s) + _grip_height(spec, s), 0.003)
        return np.array([obj[i, 0], obj[i, 1], z, _grasp_yaw(obj[i, 3:]), _pickup_opening(spec, config, i, s)])
    _, chain = block_labels(spec, config)
    if name == "stack":
        i = block_index(spec, args[1])
        s = sizes[i]
        if chain:
            # Over the observed tower's base (its axis), faces aligned with the top block.
            # Releasing over the top block instead chases its offset: each block then lands
            # a little further out and the lean grows geometrically (1, 3, 6, 11 mm over
            # four stacks, then the tower falls; measured).
            top = obj[chain[-1]]
            xy, yaw = obj[chain[0], :2], _grasp_yaw(top[3:])
        else:
            xy, yaw = spec.start_xy(), 0.0
        # The release height is the believed tower height: its error grows as h * (s_b - s_t).
        z = float(sum(sizes[j] for j in chain)) + spec.release_clearance + _grip_height(spec, s)
        return np.array([xy[0], xy[1], z, yaw, release_opening(spec, s)])
    # push(r,tower,start,goal): closed fingers behind the tower's rearmost (believed) face.
    if chain:
        rear = min(obj[j, 0] - _rear_half(sizes[j], obj[j, 3:]) for j in chain)
        y = obj[chain[0], 1]
    else:
        rear, y = spec.start_x - 0.5 * float(np.max(sizes)), 0.0
    x = rear - spec.push_reach - spec.push_gap
    return np.array([x, y, spec.push_tip_z, spec.push_yaw, spec.max_opening if spec.push_open else 0.0])


def action_poses(spec: StackAndPushSpec, sizes: np.ndarray, config: Configuration, action: str) -> np.ndarray:
    """Y for many hypotheses at once: (N, n_blocks) sizes -> (N, 5) key poses, row i equal
    bit for bit to ``action_pose(spec, sizes[i], config, action)`` (the same operations in
    the same order, over arrays), so the coordinator's serial work per action does not
    grow with the particle count."""
    sizes = np.asarray(sizes, dtype=np.float64)
    n = len(sizes)
    name, args = parse_action(action)
    obj = config.objects
    out = np.zeros((n, 5))
    if name == "pickup":
        i = block_index(spec, args[1])
        s = sizes[:, i]
        out[:, 0], out[:, 1], out[:, 3] = obj[i, 0], obj[i, 1], _grasp_yaw(obj[i, 3:])
        out[:, 2] = np.maximum(_support(spec, obj, i, s) + _grip_height(spec, s), 0.003)
        out[:, 4] = _pickup_opening(spec, config, i, s)
        return out
    _, chain = block_labels(spec, config)
    if name == "stack":
        i = block_index(spec, args[1])
        s = sizes[:, i]
        if chain:
            top = obj[chain[-1]]
            xy, yaw = obj[chain[0], :2], _grasp_yaw(top[3:])
        else:
            xy, yaw = spec.start_xy(), 0.0
        height = np.zeros(n)
        for j in chain:                 # left to right, as Python's sum() in action_pose
            height = height + sizes[:, j]
        out[:, 0], out[:, 1], out[:, 3] = xy[0], xy[1], yaw
        out[:, 2] = height + spec.release_clearance + _grip_height(spec, s)
        out[:, 4] = release_opening(spec, s)
        return out
    if chain:
        rear = None
        for j in chain:
            y = _grasp_yaw(obj[j, 3:])
            r = obj[j, 0] - 0.5 * sizes[:, j] * (abs(np.cos(y)) + abs(np.sin(y)))
            rear = r if rear is None else np.minimum(rear, r)
        y_pos = obj[chain[0], 1]
    else:
        rear, y_pos = spec.start_x - 0.5 * np.max(sizes, axis=1), 0.0
    out[:, 0] = rear - spec.push_reach - spec.push_gap
    out[:, 1], out[:, 2] = y_pos, spec.push_tip_z
    if spec.push_open:
        out[:, 3], out[:, 4] = spec.push_yaw, spec.max_opening
    return out


def push_end_x(spec: StackAndPushSpec, config: Configuration, action: str, key: np.ndarray) -> float:
    """Where the stroke ends: the tool point when the tower's base reaches the goal centre."""
    _, chain = block_labels(spec, config)
    base_x = config.objects[chain[0], 0] if chain else spec.start_x
    return float(key[0] + (spec.goal_centre_x - base_x))


def tower_top(spec: StackAndPushSpec, config: Configuration) -> float:
    """Observed top of the tower (z of the top block's centre plus its largest half size)."""
    _, chain = block_labels(spec, config)
    if not chain:
        return 0.0
    return float(config.objects[chain[-1], 2] + spec.prior_high / 2)


def place_for_sizes(spec: StackAndPushSpec, config: Configuration, sizes: np.ndarray) -> Configuration:
    """Re-ground an observed configuration under one hypothesis of the block sizes.

    Planar poses come from the observation, heights from the hypothesis: the tower is
    restacked from the floor in its observed order, a block lying on the floor rests on
    it, a delivered block sits in its slot, a held block stays where it was seen and the
    fingers close on its width. A block neither lying flat nor in the tower (leaning,
    resting on another) keeps its observed pose: its geometry says nothing about L.
    """
    labels, chain = block_labels(spec, config)
    on_blocks = lying_on_blocks(spec, config.objects)
    objects = config.objects.copy()
    robot = config.robot.copy()
    z = 0.0
    for j in chain:
        p = config.objects[j]
        s = sizes[j]
        objects[j] = np.concatenate([[p[0], p[1], z + s / 2], quat_from_yaw(_grasp_yaw(p[3:]))])
        z += s
    for i, label in enumerate(labels):
        p = config.objects[i]
        s = sizes[i]
        if label == HELD:
            objects[i] = np.concatenate([p[:3], quat_from_yaw(robot[3])])
            robot[4] = s
        elif label == GOAL:
            xy = spec.delivered_slot(i)
            objects[i] = [xy[0], xy[1], s / 2, 0, 0, 0, 1]
        elif label != TOWER and upright(p[3:]) and p[2] < FLOOR_Z and not on_blocks[i]:
            objects[i] = np.concatenate([[p[0], p[1], s / 2], quat_from_yaw(_grasp_yaw(p[3:]))])
    return Configuration(robot, objects)


def initial_configuration(spec: StackAndPushSpec, sizes: np.ndarray) -> Configuration:
    """Every block in its supply slot, the gripper up and open above the start site."""
    objects = np.zeros((spec.n_blocks, 7))
    for i in range(spec.n_blocks):
        xy = spec.init_slot(i)
        objects[i] = [xy[0], xy[1], sizes[i] / 2, 0, 0, 0, 1]
    robot = np.array([spec.start_x, 0.0, spec.carry_height, 0.0, spec.max_opening - 0.005])
    return Configuration(robot, objects)
