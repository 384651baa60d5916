"""Stack-and-push action skeletons: key pose (from Y) -> timed trajectory.

Pickup and stack are the container's skills (approach, close or open, dwell, leave);
the push is a stroke along the rail with separate speed-up and slow-down rates.
"""
from __future__ import annotations

import numpy as np

from .. import trajectory as tr
from ..configuration import Configuration
from .efforts import add_efforts
from .spec import StackAndPushSpec
from .state_mapping import parse_action, push_end_x, tower_top

CLOSED = 0.0  # commanded opening when gripping: the fingers stop on the object at grip_force


def default_transit(spec: StackAndPushSpec, start: np.ndarray, pre: np.ndarray) -> np.ndarray:
    """Up, across at a safe height, down: (M, 5) waypoints.

    The height is the highest of the carry height and both ends: every pre-pose above a
    tower is already above its top plus a held block, and the gripper leaves a stack
    straight up, so the straight segments between them clear the tower.
    """
    z = max(spec.carry_height, start[2], pre[2])
    return np.array([start, [*start[:2], z, *start[3:]], [*pre[:2], z, *pre[3:]], pre])


def pre_pose(spec: StackAndPushSpec, action: str, key: np.ndarray, holding: bool) -> np.ndarray:
    """The pose above the key pose where the transit ends and the approach starts."""
    name, _ = parse_action(action)
    pre = np.asarray(key, dtype=np.float64)[:5].copy()    # a pose: Y's effort entry is not one
    pre[2] = pre[2] + (0.12 if name == "push" else spec.approach_height)
    if name == "stack" or holding or (name == "push" and not spec.push_open):
        pre[4] = CLOSED
    return pre


def push_stroke(start: np.ndarray, end: np.ndarray, speed: float, accel: float, decel: float,
                dt: float = 0.02) -> np.ndarray:
    """A straight stroke: speed up at `accel`, cruise at `speed`, slow down at `decel`;
    rows (t, x, y, z, yaw, opening) sampled every `dt` seconds from t = 0."""
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    dist = float(np.linalg.norm(end[:3] - start[:3]))
    d_up, d_down = speed ** 2 / (2 * accel), speed ** 2 / (2 * decel)
    if d_up + d_down > dist:      # never reaches full speed: peak where the two ramps meet
        speed = float(np.sqrt(2 * dist * accel * decel / (accel + decel)))
        d_up, d_down = speed ** 2 / (2 * accel), speed ** 2 / (2 * decel)
    t_up, t_down = speed / accel, speed / decel
    t_flat = (dist - d_up - d_down) / speed if speed > 0 else 0.0
    total = t_up + t_flat + t_down
    ts = np.append(np.arange(0.0, total, dt), total)

    def s_of(t: float) -> float:
        if t < t_up:
            return 0.5 * accel * t * t
        if t < t_up + t_flat:
            return d_up + speed * (t - t_up)
        r = total - t
        return dist - 0.5 * decel * r * r

    frac = np.array([s_of(t) / dist if dist > 0 else 1.0 for t in ts])
    rows = start[None, :] + frac[:, None] * (end - start)[None, :]
    return np.column_stack([ts, rows])


def action_trajectory(spec: StackAndPushSpec, config: Configuration, action: str, key: np.ndarray,
                      transit: np.ndarray | None = None) -> np.ndarray:
    """The whole timed trajectory (t, x, y, z, yaw, opening) of one action; with a sixth
    key entry (Y's effort, when mass is in Y) also (grip_force, force_limit).

    `transit` is the (M, 4 or 5) collision-free path to the pre-pose (the motion planner's);
    without one the default up-across-down path is used."""
    return _action_trajectory(spec, config, action, key, transit)[0]


def transit_end_time(spec: StackAndPushSpec, config: Configuration, action: str, key: np.ndarray,
                     transit: np.ndarray | None = None) -> float:
    """When the free-space transit ends (where particle worlds may start)."""
    return _action_trajectory(spec, config, action, key, transit)[1]


def _action_trajectory(spec: StackAndPushSpec, config: Configuration, action: str, key: np.ndarray,
                       transit: np.ndarray | None) -> tuple[np.ndarray, float]:
    name, _ = parse_action(action)
    key = np.asarray(key, dtype=np.float64)
    effort = float(key[5]) if len(key) > 5 else None
    key = key[:5]
    start = config.robot.copy()
    holding = name == "stack"
    if holding:
        start[4] = CLOSED
    pre = pre_pose(spec, action, key, holding)
    if transit is None:
        path = default_transit(spec, start, pre)
    else:
        path = np.asarray(transit, dtype=np.float64)
        if path.shape[1] == 4:   # the planner moves the base; the fingers keep their command
            path = np.column_stack([path, np.full(len(path), pre[4])])
        path = np.vstack([start, path, pre])
    move = tr.time_parameterize(path, spec.move_speed)
    t_pre = float(move[-1, 0])
    if name == "pickup":
        closed = key.copy()
        closed[4] = CLOSED
        lifted = closed.copy()
        lifted[2] = spec.carry_height
        tail = tr.time_parameterize(np.array([pre, key]), spec.approach_speed)
        grip = tr.time_parameterize(np.array([key, closed]), 1.0, finger_speed=spec.finger_speed)
        grip = np.vstack([grip, [grip[-1, 0] + 0.3, *closed]])  # dwell: let the grip settle
        lift = tr.time_parameterize(np.array([closed, lifted]), spec.lift_speed)
        return _efforts(spec, tr.concatenate(move, tail, grip, lift), name, effort), t_pre
    if name == "stack":
        down = key.copy()
        down[4] = CLOSED
        # Leave straight up, above the new top plus a carried block of any prior size.
        up = key.copy()
        up[2] = max(spec.carry_height, key[2] + spec.prior_high + spec.carry_margin)
        tail = tr.time_parameterize(np.array([pre, down]), spec.approach_speed)
        release = tr.time_parameterize(np.array([down, key]), 1.0, finger_speed=spec.finger_speed)
        release = np.vstack([release, [release[-1, 0] + 0.3, *key]])  # let the block settle
        leave = tr.time_parameterize(np.array([key, up]), spec.lift_speed)
        return _efforts(spec, tr.concatenate(move, tail, release, leave), name, effort), t_pre
    # push: descend behind the tower, stroke to the goal, back off and rise past its top.
    end = key.copy()
    end[0] = push_end_x(spec, config, action, key)
    back = end.copy()
    back[0] -= 0.03
    up = back.copy()
    up[2] = max(spec.carry_height, tower_top(spec, config) + spec.carry_margin)
    descend = tr.time_parameterize(np.array([pre, key]), 2 * spec.approach_speed)
    # Force-limited (mass in Y): the reference speeds up fast and the limit sets the pace.
    accel = spec.push_accel if effort is None else spec.push_accel_ref
    stroke = push_stroke(key, end, spec.push_speed, accel, spec.push_decel)
    retreat = tr.time_parameterize(np.array([end, back, up]), spec.lift_speed)
    traj = tr.concatenate(move, descend, stroke, retreat)
    limited = (t_pre, t_pre + float(descend[-1, 0]) + float(stroke[-1, 0]))
    return _efforts(spec, traj, name, effort, limited), t_pre


def _efforts(spec: StackAndPushSpec, traj: np.ndarray, name: str, effort: float | None,
             limited: tuple[float, float] | None = None) -> np.ndarray:
    return traj if effort is None else add_efforts(spec, traj, name, effort, limited)
