"""Universal Robots' UR5e with the service's two-finger gripper on its flange.

Kinematics: Universal Robots' published Denavit-Hartenberg parameters of the UR5e (metres):
d1 0.1625, a2 -0.425, a3 -0.3922, d4 0.1333, d5 0.0997, d6 0.0996. Limits from its published
specification: every joint's working range is +-360 degrees and its speed 180 degrees/s; the
elbow is declared +-180 degrees, as in Universal Robots' own ROS description, since beyond
that the forearm meets the upper arm. The maker publishes no joint acceleration limit, so
none is declared (a time parameterisation must state the one it uses).
"""
from __future__ import annotations

import math

import numpy as np

from .base import Arm, Joint
from .collision import Capsule
from .kinematics import DH

TURN = 2.0 * math.pi
SPEED = math.pi                 # 180 degrees/s

# The gripper's fingertip centre beyond the flange, along its axis: the service's fingers
# (60 mm) and palm (20 mm), and 70 mm of coupling and actuator. A user with another gripper
# declares their own (a subclass with its own flange_to_tool).
TOOL_LENGTH = 0.15

# The links as capsules in the Denavit-Hartenberg frames (metres), sized from the UR5e's
# published drawings: the upper arm runs 138 mm out along the shoulder axis from the DH
# line, the forearm comes back 131 mm and the first wrist goes out 127 mm (so d4 = 133.3 mm
# net, rounded); housings 150 mm across at the base, 120 mm at the shoulder and the upper
# arm, 100 mm on the forearm, 90 mm at the wrists. The links end at the flange: below it the
# gripper is the domain's own gripper model (its palm and finger boxes), which every tool
# path is already checked with.
LINKS = (
    Capsule("base", 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.1625), 0.075, floor=False),
    Capsule("shoulder", 1, (0.0, 0.0, -0.065), (0.0, 0.0, 0.138), 0.06),
    Capsule("upper_arm", 2, (0.425, 0.0, 0.138), (0.0, 0.0, 0.138), 0.06),
    Capsule("elbow", 2, (0.0, 0.0, 0.138), (0.0, 0.0, 0.007), 0.05),
    Capsule("forearm", 3, (0.3922, 0.0, 0.007), (0.0, 0.0, 0.007), 0.05),
    Capsule("wrist_1", 3, (0.0, 0.0, 0.007), (0.0, 0.0, 0.1333), 0.045),
    Capsule("wrist_2", 4, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0997), 0.045),
    Capsule("wrist_3", 5, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0996), 0.045),
)


class UR5e(Arm):
    name = "ur5e"
    description = "Universal Robots UR5e (published DH parameters and limits), the two-finger gripper on its flange"
    dh = DH(0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996)
    joints = (Joint("shoulder_pan_joint", -TURN, TURN, SPEED),
              Joint("shoulder_lift_joint", -TURN, TURN, SPEED),
              Joint("elbow_joint", -math.pi, math.pi, SPEED),
              Joint("wrist_1_joint", -TURN, TURN, SPEED),
              Joint("wrist_2_joint", -TURN, TURN, SPEED),
              Joint("wrist_3_joint", -TURN, TURN, SPEED))
    flange_to_tool = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, TOOL_LENGTH],
                               [0.0, 0.0, 0.0, 1.0]])
    links = LINKS
    # Universal Robots publishes no joint acceleration limit; its controller's own default
    # for a joint move (URScript movej, a = 1.4 rad/s^2) is the one the service times with.
    acceleration = 1.4
    # Universal Robots' published link masses (its DH parameter table, kg) and joint torque
    # limits (size-3 joints at base, shoulder and elbow: 150 N m; size-1 wrists: 28 N m).
    link_masses = (3.761, 8.058, 2.846, 1.37, 1.3, 0.365)
    joint_torques = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)

    @property
    def home(self) -> np.ndarray:
        """Universal Robots' upright-forearm home, tool pointing down: shoulder lifted a
        quarter turn, elbow bent a quarter turn, wrist 1 a quarter turn back."""
        return np.array([0.0, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0])
