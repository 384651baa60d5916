"""The container domain's action skeletons: key pose (from Y) -> timed trajectory."""
from __future__ import annotations

import numpy as np

from .. import trajectory as tr
from ..configuration import Configuration
from .spec import ContainerSpec
from .state_mapping import parse_action, push_end_x

CLOSED = 0.0  # commanded opening when gripping: the fingers stop on the object at grip_force


def default_transit(spec: ContainerSpec, start: np.ndarray, pre: np.ndarray) -> np.ndarray:
    """Up to carry height, across, down: collision-free above any pile. (M, 5) waypoints."""
    z = max(spec.carry_height, start[2], pre[2])
    return np.array([start, [*start[:2], z, *start[3:]], [*pre[:2], z, *pre[3:]], pre])


def pre_pose(spec: ContainerSpec, action: str, key: np.ndarray, holding: bool) -> np.ndarray:
    """The pose above the key pose where the transit ends and the approach starts."""
    name, _ = parse_action(action)
    pre = key.copy()
    pre[2] = key[2] + (spec.PUSH_PRE_HEIGHT if name == "push" else spec.approach_height)
    if name == "stack" or holding:
        pre[4] = CLOSED
    return pre


def action_trajectory(spec: ContainerSpec, config: Configuration, action: str, key: np.ndarray,
                      transit: np.ndarray | None = None) -> np.ndarray:
    """The whole timed trajectory (t, x, y, z, yaw, opening) of one action.

    `transit` is the (M, 4 or 5) collision-free path to the pre-pose (the motion planner's);
    without one the default up-across-down path is used. `transit_end_time` says when the
    free-space transit ends (where particle worlds may start).
    """
    return _action_trajectory(spec, config, action, key, transit)[0]


def transit_end_time(spec: ContainerSpec, config: Configuration, action: str, key: np.ndarray,
                     transit: np.ndarray | None = None) -> float:
    return _action_trajectory(spec, config, action, key, transit)[1]


def _action_trajectory(spec, config, action, key, transit):
    name, _ = parse_action(action)
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
        grip = np.vstack([grip, [grip[-1, 0] + spec.GRIP_DWELL_S, *closed]])  # dwell: let the grip settle
        lift = tr.time_parameterize(np.array([closed, lifted]), spec.lift_speed)
        return tr.concatenate(move, tail, grip, lift), t_pre
    if name == "stack":
        down = key.copy()
        down[4] = CLOSED
        up = key.copy()
        up[2] = max(spec.carry_height, key[2] + spec.STACK_LEAVE_CLEARANCE)
        tail = tr.time_parameterize(np.array([pre, down]), spec.approach_speed)
        release = tr.time_parameterize(np.array([down, key]), 1.0, finger_speed=spec.finger_speed)
        release = np.vstack([release, [release[-1, 0] + spec.RELEASE_DWELL_S, *key]])
        leave = tr.time_parameterize(np.array([key, up]), spec.lift_speed)
        return tr.concatenate(move, tail, release, leave), t_pre
    # push: descend behind the container, stroke to the target, back off and rise.
    end = key.copy()
    end[0] = push_end_x(spec, config, action, key)
    d = np.sign(end[0] - key[0]) or 1.0
    back = end.copy()
    back[0] -= d * spec.PUSH_BACK_OFF
    up = back.copy()
    up[2] = spec.carry_height
    descend = tr.time_parameterize(np.array([pre, key]), 2 * spec.approach_speed)
    stroke = tr.trapezoid_stroke(key, end, spec.push_speed, spec.push_accel, 0.0)
    retreat = tr.time_parameterize(np.array([end, back, up]), spec.lift_speed)
    # Up and clear, the fingers open wide: a block that a failed push wedged between them
    # drops instead of being carried off (issue 24: at 58 mm a tipped block rode up in the
    # fingers with the container at goal, a state no plan leaves).
    wide = up.copy()
    wide[4] = spec.max_opening
    release = tr.time_parameterize(np.array([up, wide]), 1.0, finger_speed=spec.finger_speed)
    return tr.concatenate(move, descend, stroke, retreat, release), t_pre
