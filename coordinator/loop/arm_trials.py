"""An arm in probe trials (issue 41): `tmoc probe --robot` and T* probed with the robot the
runs have, so that an arm's runs are judged against what that arm can do.

``ArmForTrials`` is what ``sim_workers.robots.acting`` hands each action of a trial to:
the session's arm step (``plan_arm_step``: inverse kinematics, joint-space search,
toppra timing) at the trial's point belief, from the joints the trial's last action left
the arm at, then tracked as the simulated arm reality tracks it (``servo.follow``: a
position-controlled arm's error), so a trial is an action as the arm reality does it.
"""
from __future__ import annotations

import zlib
from functools import partial

import numpy as np

from planner.motion import MotionPlanningError
from sim_workers.robots import Unreachable, robot
from sim_workers.robots.acting import ArmRefused, arm_moves
from sim_workers.robots.base import Arm
from sim_workers.robots.motion import ArmMotion
from sim_workers.robots.servo import follow

from .arm_motion import contact_time, plan_arm_step, robot_of, start_joints
from .transit import transit_checker

__all__ = ["ArmForTrials", "TrialRobot", "is_arm", "with_robot"]


def is_arm(name: str | None) -> bool:
    """Whether robot `name` is an arm (the floating gripper, and None, are not)."""
    return name is not None and isinstance(robot(name), Arm)


class ArmForTrials:
    """One trial's arm: plans each action the trial acts and tracks it (see the module);
    `used` counts the actions it planned, over the trials of a ``with_robot`` block."""

    def __init__(self, name: str, used: "TrialRobot | None" = None) -> None:
        self.name = name
        self.used = used
        self._joints: np.ndarray | None = None       # where the last action left the arm

    def plan(self, domain, config, believed: dict, action: str, rows: np.ndarray, start: float,
             key: np.ndarray) -> tuple[np.ndarray, float, ArmMotion]:
        """The session's arm step for the action at the point belief `believed`."""
        if self.used is not None:
            self.used.actions += 1
        arm = robot_of(self.name, domain)
        sizes = np.asarray(domain.object_sizes(believed), dtype=np.float64)
        obstacles = domain.obstacles(config, sizes)
        held = self._held(domain, config, sizes)
        try:
            q0 = self._start(arm, config.robot, obstacles)
            plan = plan_arm_step(arm, rows, obstacles, start=q0, seed=_seed(config, action),
                                 transit_end=start or None,
                                 tool_valid=transit_checker(domain, config, sizes, held, float(np.max(rows[:, 5]))),
                                 contact_from=contact_time(rows, key, start), held=held)
        except (MotionPlanningError, Unreachable) as exc:
            raise ArmRefused(f"{self.name} cannot {action}: {exc}"[:300]) from None
        start = plan.time_of(start) if start else 0.0
        return plan.rows, start, ArmMotion(self.name, domain.robot_base, plan.path.t, plan.path.q)

    def track(self, domain, believed: dict, rows: np.ndarray, motion: ArmMotion) -> tuple[np.ndarray, ArmMotion]:
        """The position-controlled arm's tracking of the plan, from where it stands, with the
        gripper's mass on its flange (as the simulated arm reality does it)."""
        gripper = domain.scene_description(domain.properties(believed)).gripper
        tool, actual = follow(rows, motion, self._joints, gripper.palm_mass + 2 * gripper.finger_mass)
        self._joints = actual.joints[-1].copy()
        return tool, actual

    def _start(self, arm: Arm, pose: np.ndarray, obstacles: list) -> np.ndarray:
        """The joints the action starts from, as the session picks them: where the last
        action left the arm, moved to the tool's pose if it is elsewhere; the first action's
        from the elbow-up branch at the tool's pose."""
        if self._joints is None:
            return start_joints(arm, pose, obstacles)
        if np.abs(arm.tool(self._joints)[:3, 3] - pose[:3]).max() > 1e-3:
            return arm.joints_for(*pose[:4], self._joints)
        return self._joints

    @staticmethod
    def _held(domain, config, sizes: np.ndarray) -> float:
        names = list(domain.learned_objects)
        held = domain.held_object(domain.symbolic_state(config))
        return float(sizes[names.index(held)]) if held in names else 0.0


def _seed(config, action: str) -> int:
    """The action's search seed from what the trial shows it (its own generator drew the
    scene): the same trial plans the same path."""
    return zlib.crc32(np.ascontiguousarray(config.objects, dtype=np.float64).tobytes() + action.encode())


class TrialRobot:
    """``with_robot``'s context: probe trials inside it are done by robot `name`; `actions`
    counts the actions its arm planned (0 after trials that ran: the domain's probe does not
    act through ``grounded_world.act``, so no arm could do them: ``check_used``)."""

    def __init__(self, name: str | None) -> None:
        self.name = name
        self.actions = 0
        self._context = arm_moves(partial(ArmForTrials, name, self) if is_arm(name) else None)

    def __enter__(self) -> "TrialRobot":
        self._context.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._context.__exit__(*exc)

    def check_used(self, domain: str) -> None:
        """ValueError when an arm was asked for and the domain's probe never let it act."""
        if is_arm(self.name) and self.actions == 0:
            raise ValueError(f"robot: the {domain} domain's probe does not run its actions through "
                             "sim_workers.grounded_world.act, so the arm cannot do them")


def with_robot(name: str | None) -> TrialRobot:
    """The context in which probe trials are done by robot `name` (``arm_moves``); the
    floating gripper (or None) leaves them as they are."""
    return TrialRobot(name)
