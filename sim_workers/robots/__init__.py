"""Robots as declarations (issue 41): what moves the tool, registered by name beside the
domains and the engines.

``gripper`` is the service's floating two-finger gripper: the tool point (x, y, z, yaw) is
commanded directly, as every session step's rows are. ``ur5e`` is Universal Robots' UR5e
with that gripper on its flange: its kinematics from the published Denavit-Hartenberg
parameters, its joint limits from the published specification, and the closed-form inverse
kinematics of the UR geometry (``sim_workers.robots.kinematics``). Other packages add robots
through the ``tmoc.robots`` entry point group (a ``Robot`` subclass or instance).
"""
from __future__ import annotations

from .base import Arm, FloatingGripper, Joint, Robot, RobotError, broken, describe, names, register, robot  # noqa: F401
from .kinematics import DH, Unreachable  # noqa: F401
from .ur5e import UR5e

register(FloatingGripper)
register(UR5e)
