"""The pybullet world: a ``GroundedWorld`` in one pybullet DIRECT client (the default engine).

``reset`` rebuilds the scene in the client from scratch (``resetSimulation``, ~2 ms): the
only way found to make a result depend on nothing but (configuration, properties,
trajectory), since ``restoreState`` and pose resets leave contact caches and broadphase
history behind. ``resetSimulation`` frees every shape, so memory stays flat over any
number of resets. Every call passes ``physicsClientId``: the world owns its client.
"""
from __future__ import annotations

import numpy as np
import pybullet as pb

from .. import reach
from ..configuration import Configuration, quat_from_yaw, yaw_of
from ..domains import Domain
from ..grounded_world import REST_ANGULAR, REST_LINEAR, GroundedWorld
from ..robots.motion import capsule_frame
from .pybullet_engine import build_scene


class PybulletWorld(GroundedWorld):
    """One pybullet DIRECT client holding one scene of `domain`."""

    engine = "pybullet"

    def __init__(self, domain: Domain, *, leave_out: bool = False, engine: str | None = None) -> None:
        self.client = None
        self.handles = None
        self._sent_pose = self._sent_q = None
        self._weight: float | None = None
        self._links: tuple = ()              # the arm's capsules the scene holds, and their bodies
        self._link_bodies: list[int] = []
        super().__init__(domain, leave_out=leave_out)

    def _connect(self) -> None:
        self.client = pb.connect(pb.DIRECT)

    def close(self) -> None:
        if self.client is not None and pb.isConnected(physicsClientId=self.client):
            pb.disconnect(physicsClientId=self.client)
        self.client = None

    @property
    def time_step(self) -> float:
        return self.handles.time_step

    def _rebuild(self, props: dict) -> None:
        pb.resetSimulation(physicsClientId=self.client)
        own = getattr(self.domain, "build", None)       # a domain's own pybullet build (before issue 39)
        self.handles = (own(self.client, props) if own is not None else
                        build_scene(self.client, self.domain.scene_description(self.domain.properties(props))))
        self._weight = None
        self._links, self._link_bodies = (), []

    def _apply(self, config: Configuration) -> None:
        h, c = self.handles, self.client
        for i, (body, pose) in enumerate(zip(h.objects, config.objects)):
            if i in self._absent:
                self._absent[i] = np.array(pose, dtype=np.float64)
                continue
            pb.resetBasePositionAndOrientation(body, self._to_centre(i, pose[:3], pose[3:]), pose[3:],
                                              physicsClientId=c)
            pb.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=c)
        self._set_gripper(config.robot, reset=True)

    def _to_centre(self, i: int, position, orientation):
        """Object i's frame position as Bullet's base (centre of mass) position."""
        com = self.handles.object_com[i] if self.handles.object_com else None
        if com is None:
            return position
        rot = np.array(pb.getMatrixFromQuaternion(orientation)).reshape(3, 3)
        return np.asarray(position, dtype=np.float64) + rot @ com

    def _frame_pose(self, i: int, body: int) -> np.ndarray:
        """Object i's pose (frame position, quaternion) from Bullet's base pose."""
        pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        com = self.handles.object_com[i] if self.handles.object_com else None
        if com is not None:
            pos = np.asarray(pos) - np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3) @ com
        return np.concatenate([pos, orn])

    def _set_gripper(self, target: np.ndarray, reset: bool = False) -> None:
        """See ``GroundedWorld._set_gripper``: a fixed constraint capped at the limit."""
        h, c = self.handles, self.client
        # Called before every step: one conversion of the row to Python floats (the same
        # values float() gives one by one, at a third of the cost).
        row = target.tolist() if isinstance(target, np.ndarray) else [float(v) for v in target]
        base_max = self.domain.base_max_force
        pose = tuple(row[:4])
        q = row[4] / 2.0 + h.finger_inner
        grip = row[5] if len(row) > 5 else h.grip_force
        limit = row[6] if len(row) > 6 else base_max
        if reset:
            self._sent_pose = self._sent_q = None
            pos = [pose[0], pose[1], pose[2] + h.palm_offset]
            pb.resetBasePositionAndOrientation(h.gripper, pos, quat_from_yaw(pose[3]), physicsClientId=c)
            pb.resetBaseVelocity(h.gripper, [0, 0, 0], [0, 0, 0], physicsClientId=c)
            for j in h.fingers:
                pb.resetJointState(h.gripper, j, q, 0.0, physicsClientId=c)
        # Commands are sent only when they change: they hold until replaced, and two
        # pybullet calls per step are a fifth of a step's cost.
        if (pose, limit) != self._sent_pose:
            pb.changeConstraint(h.base_constraint, jointChildPivot=[pose[0], pose[1], pose[2] + h.palm_offset],
                                jointChildFrameOrientation=quat_from_yaw(pose[3]),
                                maxForce=limit, physicsClientId=c)
            self._sent_pose = (pose, limit)
        if (q, grip) != self._sent_q:
            pb.setJointMotorControlArray(h.gripper, list(h.fingers), pb.POSITION_CONTROL,
                                         targetPositions=[q, q], forces=[grip] * 2,
                                         physicsClientId=c)
            self._sent_q = (q, grip)
        if limit < base_max:
            # External forces last one step: applied anew before every step.
            pb.applyExternalForce(h.gripper, -1, [0.0, 0.0, self._gripper_weight()], [0.0, 0.0, 0.0],
                                  pb.LINK_FRAME, physicsClientId=c)

    def _with_links(self, links: tuple) -> None:
        """See ``GroundedWorld._with_links``: static (mass 0) capsule bodies moved by pose
        resets, at the fingers' friction; Bullet makes no contact between two static bodies,
        so the table and the fixtures are left alone, and the gripper is filtered out."""
        if links == self._links:
            return
        h, c = self.handles, self.client
        for b in self._link_bodies:
            pb.removeBody(b, physicsClientId=c)
        self._links, self._link_bodies = tuple(links), []
        friction = pb.getDynamicsInfo(h.gripper, h.fingers[0], physicsClientId=c)[1]
        for k, cap in enumerate(self._links):
            _, _, half = capsule_frame(cap)
            shape = pb.createCollisionShape(pb.GEOM_CAPSULE, radius=float(cap.radius), height=2.0 * half,
                                            physicsClientId=c)
            body = pb.createMultiBody(0.0, shape, -1, [0.0, 0.0, -10.0 - k], useMaximalCoordinates=True,
                                      physicsClientId=c)
            pb.changeDynamics(body, -1, lateralFriction=friction, physicsClientId=c)
            for link in (-1, *h.fingers):
                pb.setCollisionFilterPair(body, h.gripper, -1, link, 0, physicsClientId=c)
            self._link_bodies.append(body)

    def _place_links(self, positions: np.ndarray, quaternions: np.ndarray) -> None:
        c = self.client
        for body, p, q in zip(self._link_bodies, positions.tolist(), quaternions.tolist()):
            pb.resetBasePositionAndOrientation(body, p, q, physicsClientId=c)

    def _gripper_weight(self) -> float:
        """The gripper's weight (N): palm and fingers, read from the built bodies."""
        if self._weight is None:
            h, c = self.handles, self.client
            mass = sum(pb.getDynamicsInfo(h.gripper, link, physicsClientId=c)[0] for link in (-1, *h.fingers))
            self._weight = mass * -pb.getPhysicsEngineParameters(physicsClientId=c)["gravityAccelerationZ"]
        return self._weight

    def observe(self) -> Configuration:
        """The current configuration (gripper tool point, opening, object poses)."""
        h, c = self.handles, self.client
        pos, orn = pb.getBasePositionAndOrientation(h.gripper, physicsClientId=c)
        q = [s[0] for s in pb.getJointStates(h.gripper, list(h.fingers), physicsClientId=c)]
        opening = 2.0 * (np.mean(q) - h.finger_inner)
        robot = np.array([pos[0], pos[1], pos[2] - h.palm_offset, yaw_of(np.array(orn)), opening])
        objects = np.array([self._absent[i] if i in self._absent else self._frame_pose(i, b)
                            for i, b in enumerate(h.objects)])
        return Configuration(robot, objects)

    def at_rest(self) -> bool:
        c = self.client
        for i, b in enumerate(self.handles.objects):
            if i in self._absent:
                continue
            lin, ang = pb.getBaseVelocity(b, physicsClientId=c)
            if max(map(abs, lin)) > REST_LINEAR or max(map(abs, ang)) > REST_ANGULAR:
                return False
        return True

    # -- acting -------------------------------------------------------------------------
    def _step(self) -> None:
        pb.stepSimulation(physicsClientId=self.client)

    def _wrist_force(self):
        return pb.getConstraintState(self.handles.base_constraint, physicsClientId=self.client)[:3]

    def _tool_position(self) -> np.ndarray:
        pos, _ = pb.getBasePositionAndOrientation(self.handles.gripper, physicsClientId=self.client)
        return np.array([pos[0], pos[1], pos[2] - self.handles.palm_offset])

    def _commanded_tool(self) -> np.ndarray:
        return np.array(self._sent_pose[0][:3])

    def _leave_out(self, targets: np.ndarray, link_boxes: np.ndarray | None = None) -> reach.Guard | None:
        """Remove the objects the action cannot reach, nor an arm's links at any step (their
        boxes `link_boxes`) (``sim_workers.reach``); None when every object is within reach."""
        h, c = self.handles, self.client
        boxes = np.array([reach.body_box(b, c) for b in h.objects])
        tool = np.array(self._sent_pose[0][:3])
        opening = float(self._sent_q[0] - h.finger_inner) * 2.0
        keep = reach.kept_objects(boxes, reach.body_box(h.gripper, c), tool, targets[:, :3],
                                  widening=float(targets[:, 4].max()) - opening, link_boxes=link_boxes)
        if keep.all():
            return None
        kept = [int(i) for i in np.flatnonzero(keep)]
        for i in np.flatnonzero(~keep):
            self._absent[int(i)] = self._frame_pose(int(i), h.objects[i])
            pb.removeBody(h.objects[i], physicsClientId=c)
        bodies = [h.objects[i] for i in kept]
        start = np.array([pb.getBasePositionAndOrientation(b, physicsClientId=c)[0] for b in bodies]).reshape(-1, 3)
        return reach.Guard(c, h.gripper, bodies, reach.radii(start, boxes[kept]), boxes[~keep])

    def _opening(self) -> float:
        h = self.handles
        q = [s[0] for s in pb.getJointStates(h.gripper, list(h.fingers), physicsClientId=self.client)]
        return 2.0 * (float(np.mean(q)) - h.finger_inner)
