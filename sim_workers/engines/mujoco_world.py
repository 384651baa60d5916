"""The MuJoCo world: a ``GroundedWorld`` over one compiled model (``mujoco_engine``).

MuJoCo keeps every piece of simulation state in ``MjData`` (warm starts included) and
``mj_resetData`` clears all of it, so a reset is a fresh data on the model of the
hypothesis: bit-identical to a fresh process without rebuilding anything (checked in
tests/sim_workers/test_determinism.py). A new hypothesis that changes only blocks' boxes
and masses is written into the world's model in place (``mujoco_engine.patch``: the model
compiling it would give, bit for bit); anything else compiles its scene. The few model
fields a trajectory changes (the drives' force limits) are set by every reset's first
command.
"""
from __future__ import annotations

import mujoco
import numpy as np

from ..configuration import Configuration
from ..domains import Domain
from ..grounded_world import REST_ANGULAR, REST_LINEAR, GroundedWorld
from .mujoco_engine import MujocoScene, build_model, patch




def wxyz(q) -> np.ndarray:
    """A quaternion (x, y, z, w), as configurations carry it, in MuJoCo's (w, x, y, z)."""
    return np.array([q[3], q[0], q[1], q[2]], dtype=np.float64)


def xyzw(q) -> np.ndarray:
    return np.array([q[1], q[2], q[3], q[0]], dtype=np.float64)


class MujocoWorld(GroundedWorld):
    """One MuJoCo model and data holding one scene of `domain` (leaves nothing out: the
    contacts of far bodies cost MuJoCo little; ``leave_out`` is accepted and ignored)."""

    engine = "mujoco"

    def __init__(self, domain: Domain, *, leave_out: bool = False, engine: str | None = None) -> None:
        super().__init__(domain, leave_out=False)

    def _connect(self) -> None:
        self._desc = None                   # the scene description the model holds
        self.scene: MujocoScene | None = None
        self.model = self.data = None
        self._target = np.zeros(6)          # palm x, y, z, yaw, finger q, finger q
        self._sent: tuple | None = None
        self._tare = 0.0

    def close(self) -> None:
        self.scene = self.model = self.data = self._desc = None

    @property
    def time_step(self) -> float:
        return self.scene.time_step

    def _rebuild(self, props: dict) -> None:
        desc = self.domain.scene_description(props)
        if desc != self._desc and not (self.scene is not None and patch(self.scene, self._desc, desc, self.data)):
            self.scene = build_model(desc)
            self.model, self.data = self.scene.model, mujoco.MjData(self.scene.model)
        self._desc = desc
        mujoco.mj_resetData(self.model, self.data)
        self._sent = None

    def _apply(self, config: Configuration) -> None:
        s, d = self.scene, self.data
        for i, pose in enumerate(config.objects):
            adr, dof = s.object_qpos[i], s.object_dof[i]
            if adr < 0:
                continue                   # a fixture: it stays where the scene put it
            d.qpos[adr:adr + 3] = pose[:3]
            d.qpos[adr + 3:adr + 7] = wxyz(pose[3:7])
            d.qvel[dof:dof + 6] = 0.0
        self._set_gripper(config.robot, reset=True)
        mujoco.mj_forward(self.model, d)

    def _set_gripper(self, target: np.ndarray, reset: bool = False) -> None:
        """See ``GroundedWorld._set_gripper``: capped velocity drives toward the target."""
        s, d, m = self.scene, self.data, self.model
        q = float(target[4]) / 2.0 + s.finger_inner
        grip = float(target[5]) if len(target) > 5 else s.grip_force
        limit = float(target[6]) if len(target) > 6 else self.domain.base_max_force
        self._target[:] = (target[0], target[1], float(target[2]) + s.palm_offset, target[3], q, q)
        d.ctrl[list(s.palm_actuators) + list(s.finger_actuators)] = self._target
        if reset:
            p, v = s.palm_qpos, s.palm_dof
            d.qpos[p:p + 4] = self._target[:4]
            d.qvel[v:v + 4] = 0.0
            for a, b in zip(s.finger_qpos, s.finger_dof):
                d.qpos[a] = q
                d.qvel[b] = 0.0
        if (limit, grip) != self._sent:
            for a in s.palm_actuators:
                m.actuator_forcerange[a] = (-limit, limit)
            for a in s.finger_actuators:
                m.actuator_forcerange[a] = (-grip, grip)
            self._sent = (limit, grip)
            # The sensor adds the weight the arm carries outside a guarded move (see
            # mujoco_engine: the gripper is gravity-compensated throughout).
            guarded = limit < self.domain.base_max_force
            self._tare = 0.0 if guarded else s.gripper_mass * -float(m.opt.gravity[2])

    def _step(self) -> None:
        mujoco.mj_step(self.model, self.data)

    def observe(self) -> Configuration:
        s, d = self.scene, self.data
        p = s.palm_qpos
        x, y, z, yaw = (float(v) for v in d.qpos[p:p + 4])
        yaw = float(np.arctan2(np.sin(yaw), np.cos(yaw)))
        opening = 2.0 * (float(np.mean(d.qpos[list(s.finger_qpos)])) - s.finger_inner)
        robot = np.array([x, y, z - s.palm_offset, yaw, opening])
        objects = np.empty((len(s.objects), 7))
        for i, body in enumerate(s.objects):
            adr = s.object_qpos[i]
            if adr < 0:
                objects[i, :3] = d.xpos[body]
                objects[i, 3:] = xyzw(d.xquat[body])
            else:
                objects[i, :3] = d.qpos[adr:adr + 3]
                objects[i, 3:] = xyzw(d.qpos[adr + 3:adr + 7])
        return Configuration(robot, objects)

    def at_rest(self) -> bool:
        s, d = self.scene, self.data
        for dof in s.object_dof:
            if dof < 0:
                continue
            v = d.qvel[dof:dof + 6]
            if np.max(np.abs(v[:3])) > REST_LINEAR or np.max(np.abs(v[3:])) > REST_ANGULAR:
                return False
        return True

    def _wrist_force(self):
        f = self.data.actuator_force
        a = self.scene.palm_actuators
        return (float(f[a[0]]), float(f[a[1]]), float(f[a[2]]) + self._tare)

    def _opening(self) -> float:
        s = self.scene
        return 2.0 * (float(np.mean(self.data.qpos[list(s.finger_qpos)])) - s.finger_inner)

    def _tool_position(self) -> np.ndarray:
        s = self.scene
        pos = self.data.qpos[s.palm_qpos:s.palm_qpos + 3].copy()
        pos[2] -= s.palm_offset
        return pos

    def _commanded_tool(self) -> np.ndarray:
        out = self._target[:3].copy()
        out[2] -= self.scene.palm_offset
        return out
