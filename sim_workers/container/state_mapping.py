"""Y and Y^-1 for the container domain, in plain numpy.

Y (``action_pose``) maps believed properties L, the observed configuration and a symbolic
action to the action's key pose (x, y, z, yaw, opening). Y^-1 (``symbolic_state``) maps a
configuration to ground atoms. The same code serves the real world and every particle, so
their outcomes are comparable. ``place_for_sizes`` re-grounds an observed configuration
under one hypothesis L_i (heights follow from each particle's own sizes, since the
observation fixes only where things are, not how big they are). Where blocks pile in the
tray, one column or two, is ``columns``' layout: the rule's for an empty tray, the one the
tray has for a tray that holds blocks.
"""
from __future__ import annotations

import math

import numpy as np

from ..configuration import Configuration, quat_from_yaw, rotate_z, yaw_of
from ..blocks.hand import closing_axis, pickup_opening
from ..blocks.hand import grasp_yaw as _grasp_yaw, grip_height as _grip_height, in_hand as _in_hand
from ..blocks.terms import block_index, parse_action  # noqa: F401  (used as state_mapping.*)
from .columns import LEFT, column_of, column_x, side_of, tallest_pile, tray_layout
from .spec import ContainerSpec

# Labels of where a block is; Y^-1 turns them into atoms.
HELD, CONTAINER, GOAL, INIT, TABLE = "held", "container", "goal", "init", "table"


def container_location(spec: ContainerSpec, config: Configuration) -> str:
    cxy = config.objects[0, :2]
    d_init = np.linalg.norm(cxy - spec.location_xy("init"))
    d_goal = np.linalg.norm(cxy - spec.location_xy("goal"))
    return "goal" if d_goal < d_init else "init"


def _in_container(spec: ContainerSpec, config: Configuration, p: np.ndarray) -> bool:
    c = config.objects[0]
    local = rotate_z(p[:2] - c[:2], -yaw_of(c[3:]))
    ix, iy = spec.inner_half
    # Nothing above the tallest pile Y can build (every block of the largest prior size, in
    # the columns that size gets) is in the container, e.g. a block carried over it. Y^-1
    # knows no hypothesis, so the cap covers them all.
    top = c[2] + spec.floor_top + tallest_pile(spec) + spec.CONTAINER_TOP_MARGIN
    margin = spec.CONTAINER_XY_MARGIN
    return abs(local[0]) < ix + margin and abs(local[1]) < iy + margin and c[2] < p[2] < top


def block_labels(spec: ContainerSpec, config: Configuration) -> list[str]:
    """Where each block is: held, container, goal, init (its start slot) or table."""
    labels = []
    for i in range(spec.n_blocks):
        p = config.objects[1 + i, :3]
        if _in_hand(spec, config, p):
            labels.append(HELD)
        elif _in_container(spec, config, p):
            labels.append(CONTAINER)
        elif p[0] > spec.delivered_x - spec.GOAL_BAND:
            labels.append(GOAL)
        elif np.linalg.norm(p[:2] - spec.init_slot(i)) < spec.INIT_RADIUS:
            labels.append(INIT)
        else:
            labels.append(TABLE)
    held = [i for i, label in enumerate(labels) if label == HELD]
    held.sort(key=lambda i: float(np.linalg.norm(config.objects[1 + i, :3] - config.robot[:3])))
    for i in held[1:]:                       # one hand holds one block; the nearest wins
        labels[i] = TABLE
    return labels


def in_tray(labels: list[str]) -> list[int]:
    """The blocks (0-based) a configuration's labels put in the container."""
    return [i for i, label in enumerate(labels) if label == CONTAINER]


def symbolic_state(spec: ContainerSpec, config: Configuration) -> frozenset[str]:
    """Y^-1: the ground atoms that hold in a configuration."""
    atoms = {f"is_in(c,{container_location(spec, config)})"}
    labels = block_labels(spec, config)
    for name, label in zip(spec.block_names, labels):
        if label == HELD:
            atoms.add(f"is_holding(r,{name})")
        elif label == CONTAINER:
            atoms.add(f"at_container({name},c)")
        else:
            atoms.add(f"is_in({name},{label})")
    if HELD not in labels:
        atoms.add("hand_empty(r)")
    return frozenset(atoms)


def _pickup_opening(spec: ContainerSpec, config: Configuration, i: int, s):
    """The grasp's opening for block i at believed side(s) `s` (``blocks.hand.grasp_opening``):
    the other blocks and the tray (its outer half diagonal) bound the room. Another block
    reaches as far as its footprint at the believed side extends along the fingers'
    closing axis, at its perceived yaw (s / 2 (|cos phi| + |sin phi|), phi its yaw to the
    axis: the camera perceives yaw, its error is in the position), plus the grasp
    clearance: the camera's error budget (3 sigma) for where it was perceived. (Counting
    every block at the prior's largest half diagonal, 42 mm, left the supply row's 75 mm
    pitch 20.6 mm of room, less than the 1.15 sides: no clearance anywhere in the row.)"""
    if float(spec.grasp_clearance) <= 0.0:
        return pickup_opening(spec, config, 1 + i, s, {})       # the 1.15 sides; no room needed
    axis = closing_axis(config.objects[1 + i, 3:])
    theta = float(np.arctan2(axis[1], axis[0]))
    side = np.asarray(s, dtype=np.float64)
    others = {}
    for j in range(spec.n_blocks):
        phi = yaw_of(config.objects[1 + j, 3:]) - theta
        others[1 + j] = 0.5 * (abs(np.cos(phi)) + abs(np.sin(phi))) * side + float(spec.grasp_clearance)
    others[0] = float(np.hypot(*spec.outer_half))
    return pickup_opening(spec, config, 1 + i, s, others)


def action_pose(spec: ContainerSpec, sizes: np.ndarray, config: Configuration, action: str) -> np.ndarray:
    """Y(L, s, a): the key pose (x, y, z, yaw, opening) of `action` under believed sizes."""
    name, args = parse_action(action)
    if name == "pickup":
        i = block_index(spec, args[1])
        p = config.objects[1 + i]
        s = sizes[i]
        z = max(_grip_height(spec, s), spec.MIN_GRASP_Z)
        return np.array([p[0], p[1], z, _grasp_yaw(p[3:]), _pickup_opening(spec, config, i, s)])
    if name == "stack":
        i = block_index(spec, args[1])
        c = config.objects[0]
        cyaw = yaw_of(c[3:])
        labels = block_labels(spec, config)
        two = tray_layout(spec, config, sizes, in_tray(labels))
        heights = [spec.floor_top, spec.floor_top]
        for j, label in enumerate(labels):
            if label == CONTAINER:
                heights[column_of(config, config.objects[1 + j, :3], two)] += sizes[j]
        col = int(np.argmin(heights)) if two else LEFT   # the lower column; ties go left
        s = sizes[i]
        lx = column_x(spec, s, col, two)
        xy = c[:2] + rotate_z(np.array([lx, 0.0]), cyaw)
        z = heights[col] + spec.release_clearance + _grip_height(spec, s)
        return np.array([xy[0], xy[1], z, cyaw, spec.open_ratio * s])
    # push(R, C, L1, L2): behind the container, fingers low, moving towards L2.
    c = config.objects[0]
    target = spec.location_xy(args[3])
    d = 1.0 if target[0] >= c[0] else -1.0
    if spec.push_open:              # the open front finger's outer face pushes
        x = c[0] - d * (spec.outer_half[0] + spec.max_opening / 2 + 2 * spec.finger_half[1] + spec.PUSH_CLEARANCE)
        return np.array([x, c[1], spec.push_tip_z, 0.5 * math.pi, spec.max_opening])
    x = c[0] - d * (spec.outer_half[0] + spec.finger_half[0] + spec.PUSH_CLEARANCE)
    return np.array([x, c[1], spec.push_tip_z, 0.0, spec.push_opening])


def action_poses(spec: ContainerSpec, sizes: np.ndarray, config: Configuration, action: str) -> np.ndarray:
    """Y for many hypotheses at once: (N, n_blocks) sizes -> (N, 5) key poses, row i equal
    bit for bit to ``action_pose(spec, sizes[i], config, action)`` (the same operations in
    the same order, over arrays). The coordinator computes Y for every particle before each
    action; one call instead of N keeps its serial time from growing with N."""
    sizes = np.asarray(sizes, dtype=np.float64)
    n = len(sizes)
    name, args = parse_action(action)
    if name == "pickup":
        i = block_index(spec, args[1])
        p = config.objects[1 + i]
        s = sizes[:, i]
        out = np.empty((n, 5))
        out[:, 0], out[:, 1], out[:, 3] = p[0], p[1], _grasp_yaw(p[3:])
        out[:, 2] = np.maximum(_grip_height(spec, s), spec.MIN_GRASP_Z)
        out[:, 4] = _pickup_opening(spec, config, i, s)
        return out
    if name == "stack":
        i = block_index(spec, args[1])
        c = config.objects[0]
        cyaw = yaw_of(c[3:])
        labels = block_labels(spec, config)
        two = tray_layout(spec, config, sizes, in_tray(labels))   # (n,): each hypothesis its layout
        rows = np.arange(n)
        heights = np.full((n, 2), spec.floor_top)
        for j, label in enumerate(labels):
            if label == CONTAINER:
                side = side_of(config, config.objects[1 + j, :3])
                heights[rows, np.where(two, side, LEFT)] += sizes[:, j]
        col = np.where(two, np.argmin(heights, axis=1), LEFT)   # the lower column; ties go left
        s = sizes[:, i]
        lx = column_x(spec, s, col, two)
        cos, sin = np.cos(cyaw), np.sin(cyaw)
        out = np.empty((n, 5))
        out[:, 0] = c[0] + (cos * lx - sin * 0.0)
        out[:, 1] = c[1] + (sin * lx + cos * 0.0)
        out[:, 2] = heights[rows, col] + spec.release_clearance + _grip_height(spec, s)
        out[:, 3] = cyaw
        out[:, 4] = spec.open_ratio * s
        return out
    return np.tile(action_pose(spec, sizes[0], config, action), (n, 1))


def push_end_x(spec: ContainerSpec, config: Configuration, action: str, key: np.ndarray) -> float:
    """Where the push stroke ends: the tool point when the container reaches L2."""
    _, args = parse_action(action)
    target = spec.location_xy(args[3])
    c = config.objects[0]
    return float(key[0] + (target[0] - c[0]))


def _x_in_column(spec: ContainerSpec, local_x: float, s: float, col: int, two: bool) -> float:
    """An observed tray-frame x re-grounded in a column, inside the walls: on the column's
    side of the centre line with two columns; as seen (the pile's offsets are part of the
    observation) with one."""
    ix = spec.inner_half[0]
    if not two:
        half = max(ix - s / 2, 0.0)
        return np.clip(local_x, -half, half)
    lx = np.clip(abs(local_x), s / 2, max(ix - s / 2, s / 2))
    return lx if col else -lx


def place_for_sizes(spec: ContainerSpec, config: Configuration, sizes: np.ndarray) -> Configuration:
    """Re-ground an observed configuration under one hypothesis of the block sizes.

    Planar poses (x, y, yaw) come from the observation; heights come from the hypothesis:
    a block on the table rests on it, a block in the container rests on the ones below it
    in its column of the tray's layout under the hypothesis (``columns.tray_layout``: the
    layout the pile has, where the hypothesis' blocks can lie that way; order by observed
    height), a held block stays where it was seen and the fingers close on its
    hypothesised width. Blocks are set upright (cubes at rest).
    """
    labels = block_labels(spec, config)
    objects = config.objects.copy()
    robot = config.robot.copy()
    c = objects[0]
    cyaw = yaw_of(c[3:])
    objects[0] = np.concatenate([[c[0], c[1], 0.0], quat_from_yaw(cyaw)])
    iy = spec.inner_half[1]
    two = tray_layout(spec, config, sizes, in_tray(labels))
    columns: dict[int, list[int]] = {0: [], 1: []}
    for i, label in enumerate(labels):
        p = config.objects[1 + i]
        s = sizes[i]
        if label == CONTAINER:
            columns[column_of(config, p[:3], two)].append(i)
        elif label == HELD:
            objects[1 + i] = np.concatenate([p[:3], quat_from_yaw(robot[3])])
            robot[4] = s
        elif label == GOAL:
            xy = spec.delivered_slot(i)
            objects[1 + i] = [xy[0], xy[1], s / 2, 0, 0, 0, 1]
        else:
            objects[1 + i] = np.concatenate([[p[0], p[1], s / 2], quat_from_yaw(_grasp_yaw(p[3:]))])
    for col, members in columns.items():
        members.sort(key=lambda j: config.objects[1 + j, 2])
        z = spec.floor_top
        for j in members:
            s = sizes[j]
            local = rotate_z(config.objects[1 + j, :2] - c[:2], -cyaw)
            lx = _x_in_column(spec, local[0], s, col, two)
            ly = np.clip(local[1], -max(iy - s / 2, 0.0), max(iy - s / 2, 0.0))
            xy = c[:2] + rotate_z(np.array([lx, ly]), cyaw)
            objects[1 + j] = np.concatenate([[xy[0], xy[1], z + s / 2], quat_from_yaw(cyaw)])
            z += s
    return Configuration(robot, objects)


def initial_configuration(spec: ContainerSpec, sizes: np.ndarray) -> Configuration:
    """All blocks in their start row, the container at init, the gripper up and open."""
    objects = np.zeros((1 + spec.n_blocks, 7))
    x, y = spec.container_init
    objects[0] = [x, y, 0.0, 0, 0, 0, 1]
    for i in range(spec.n_blocks):
        xy = spec.init_slot(i)
        objects[1 + i] = [xy[0], xy[1], sizes[i] / 2, 0, 0, 0, 1]
    robot = np.array([x, y, spec.carry_height, 0.0, spec.max_opening - spec.START_OPENING_MARGIN])
    return Configuration(robot, objects)
