"""A position-controlled arm in MuJoCo (issue 41): what a real arm's joint controller does
with a joint trajectory, so that a simulated reality follows it with a realistic error
instead of exactly.

The arm is built from its declaration alone: one body per Denavit-Hartenberg frame, a hinge
about each frame's z axis, the link capsules as its geoms carrying the declared link masses
(``Arm.link_masses``) and the gripper's mass on the flange. Each joint is driven as an
industrial controller drives it: model-based gravity compensation (MuJoCo's ``gravcomp``)
and a PD loop on the reference with velocity feed-forward,
``tau = kp (q_ref - q) + kv (qd_ref - qd)``, its torque capped at the joint's published
limit (``Arm.joint_torques``). The gains put each joint's closed loop at ``BANDWIDTH_HZ``,
critically damped, at the arm's home posture: ``kp = m w^2``, ``kv = 2 m w`` with m the
joint's inertia there. The reference is sampled every ``CONTROL_DT`` (a UR e-series
controller's 500 Hz cycle) and held between.

The tracking error this gives is a lagging second-order loop's, one control cycle behind
the reference: measured on a toppra-timed move at the UR5e's limits (1.17 rad/s, 1.4
rad/s^2, the tool at 0.9 m/s), 1.3 mm at the peak at 10 Hz (2.6 mm at 5 Hz, 0.7 mm at
20 Hz: it scales as 1 / bandwidth), and the arm stands on the final point to 3 um after
``SETTLE_S`` (tests/sim_workers/test_arm_worlds.py). A user whose arm tracks worse sets a
lower bandwidth.
"""
from __future__ import annotations

import math
from functools import lru_cache

import mujoco
import numpy as np

from ..trajectory import sample
from .base import Arm, robot
from .motion import ArmMotion, capsule_frame, frames_batch

__all__ = ["BANDWIDTH_HZ", "CONTROL_DT", "ServoArm"]

BANDWIDTH_HZ = 10.0     # each joint's closed-loop natural frequency (see the module's doc)
CONTROL_DT = 0.002      # s: the controller's cycle, and the simulation's step
SETTLE_S = 0.3          # s the arm is held on the final point (three periods at 10 Hz)


def _arm_spec(arm: Arm, payload: float) -> mujoco.MjSpec:
    """The arm as an MjSpec: DH frames as nested bodies, hinges about their z axes."""
    spec = mujoco.MjSpec()
    spec.option.timestep = CONTROL_DT
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.gravity = [0.0, 0.0, -9.81]
    dh = arm.dh
    masses = list(arm.link_masses) or [1.0] * 6
    torques = list(arm.joint_torques) or [None] * 6
    parent = spec.worldbody
    for i in range(6):
        body = parent.add_body()
        body.name = f"link{i + 1}"
        body.gravcomp = 1.0
        j = body.add_joint()
        j.name = arm.joints[i].name
        j.type = mujoco.mjtJoint.mjJNT_HINGE
        j.axis = [0.0, 0.0, 1.0]
        if torques[i] is not None:
            j.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
            j.actfrcrange = [-torques[i], torques[i]]
        # this body is the frame after the joint's rotation and before the link's fixed
        # part; its child carries that part (Tz(d) Tx(a) Rx(alpha)) and is DH frame i+1
        frame = body.add_body()
        frame.name = f"frame{i + 1}"
        frame.gravcomp = 1.0
        frame.pos = [float(dh.a[i]), 0.0, float(dh.d[i])]
        half = float(dh.alpha[i]) / 2.0
        frame.quat = [math.cos(half), math.sin(half), 0.0, 0.0]
        caps = [c for c in arm.links if c.frame == i + 1]
        mass = masses[i] + (payload if i == 5 else 0.0)
        for c in caps:
            centre, rot, h = capsule_frame(c)
            g = frame.add_geom()
            g.type = mujoco.mjtGeom.mjGEOM_CAPSULE
            g.size = [float(c.radius), max(h, 1e-6), 0.0]
            g.pos = centre.tolist()
            q = np.zeros(4)
            mujoco.mju_mat2Quat(q, rot.reshape(-1))
            g.quat = q.tolist()
            g.mass = mass / len(caps)
            g.contype = g.conaffinity = 0
        if not caps:
            frame.mass = mass
            frame.inertia = [mass * 1e-3] * 3
            frame.explicitinertial = True
        parent = frame
    return spec


class ServoArm:
    """`arm` (placed) with `payload` kg on its flange, tracking joint trajectories."""

    def __init__(self, arm: Arm, payload: float = 0.0, bandwidth_hz: float = BANDWIDTH_HZ) -> None:
        self.arm = arm
        spec = _arm_spec(arm, payload)
        for jt in arm.joints:
            for kind in ("position", "velocity"):
                a = spec.add_actuator()
                a.name = f"{kind}_{jt.name}"
                a.target = jt.name
                a.trntype = mujoco.mjtTrn.mjTRN_JOINT
                a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
                a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        w = 2.0 * math.pi * bandwidth_hz
        self.data.qpos[:] = arm.home
        mujoco.mj_forward(self.model, self.data)
        full = np.zeros((self.model.nv, self.model.nv))
        mujoco.mj_fullM(self.model, self.data, full)
        m = np.diag(full).copy()
        for i in range(6):
            kp, kv = m[i] * w * w, 2.0 * m[i] * w
            p, v = 2 * i, 2 * i + 1
            self.model.actuator_gainprm[p, 0], self.model.actuator_biasprm[p, :3] = kp, (0.0, -kp, 0.0)
            self.model.actuator_gainprm[v, 0], self.model.actuator_biasprm[v, :3] = kv, (0.0, 0.0, -kv)

    def track(self, motion: ArmMotion, start: np.ndarray | None = None) -> ArmMotion:
        """The joints the arm goes through following `motion`'s joints, from `start` at rest
        (default: the reference's first point), sampled every ``CONTROL_DT`` until
        ``SETTLE_S`` after the reference ends."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[:] = motion.joints[0] if start is None else np.asarray(start, dtype=np.float64)
        t0, t1 = float(motion.times[0]), float(motion.times[-1]) + SETTLE_S
        times = t0 + CONTROL_DT * np.arange(int(math.ceil((t1 - t0) / CONTROL_DT)) + 1)
        ref = motion.at(times)
        vel = np.gradient(ref, CONTROL_DT, axis=0) if len(times) > 1 else np.zeros_like(ref)
        vel[times >= motion.times[-1]] = 0.0
        out = np.empty_like(ref)
        out[0] = d.qpos
        for k in range(1, len(times)):
            d.ctrl[0::2], d.ctrl[1::2] = ref[k - 1], vel[k - 1]
            mujoco.mj_step(m, d)
            out[k] = d.qpos
        return ArmMotion(motion.robot, motion.base, times, out)


@lru_cache(maxsize=8)
def servo_for(robot_name: str, base: tuple | None, payload: float) -> ServoArm:
    """One ``ServoArm`` per (robot, base, payload) in a process (compiling costs ~ms)."""
    return ServoArm(robot(robot_name).placed(base), payload)


def tool_rows(rows: np.ndarray, motion: ArmMotion) -> np.ndarray:
    """The step's `rows` (t, x, y, z, yaw, opening, ...) as the arm of `motion` draws them:
    at `motion`'s times, the tool pose from the forward kinematics of its joints (the yaw on
    the rows' turn, so a drive is never asked to spin round), the opening and efforts as
    the rows command them then."""
    arm = motion.arm()
    tool = arm.base @ frames_batch(arm.dh, motion.joints)[:, 5] @ arm.flange_to_tool
    out = np.column_stack([motion.times, sample(rows, motion.times)])
    yaw = np.arctan2(tool[:, 1, 0], tool[:, 0, 0])
    out[:, 1:4] = tool[:, :3, 3]
    out[:, 4] = yaw + 2.0 * np.pi * np.round((out[:, 4] - yaw) / (2.0 * np.pi))
    return out


def follow(rows: np.ndarray, motion: ArmMotion, start: np.ndarray | None, payload: float) -> tuple[np.ndarray, ArmMotion]:
    """What a position-controlled arm does with a step: the joints it goes through tracking
    `motion` from `start` (``ServoArm.track``) and the tool rows they draw (``tool_rows``)."""
    actual = servo_for(motion.robot, motion.base, float(payload)).track(motion, start)
    return tool_rows(rows, actual), actual
