"""The pybullet backend: a ``SceneDescription`` built in one pybullet client.

Every call passes ``physicsClientId``: the world owns its client, never the global one.
The calls and their order are those the built-in domains made before the engine seam
(issue 26), so every result stays bit for bit what it was: a single box is a box shape,
several are one compound shape; friction anchors are set once every body exists, before
the gripper is built.
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from ..scene import Body, BoxShape, CylinderShape, Gripper, MeshShape, SceneDescription, engines_derive_alike, inertial

# The fingers' coupling (as pybullet's Panda example does): two independent position servos
# squeezing one object drift sideways together and carry it off centre.
GEAR_ERP, GEAR_MAX_FORCE = 0.1, 50.0


@dataclass(frozen=True)
class SceneHandles:
    """Body ids of one built scene (valid only inside the client that built it)."""

    client: int
    bodies: dict                 # body name -> id, every body of the description
    objects: tuple[int, ...]     # the domain's objects, in Configuration.objects order
    gripper: int
    fingers: tuple[int, int]     # joint indices of the two prismatic fingers
    base_constraint: int
    palm_offset: float           # palm centre above the fingertip tool point
    finger_inner: float          # joint position at which a finger's inner face is at y = 0
    grip_force: float
    time_step: float
    # Per object, its centre of mass in its frame where that is not the frame's origin
    # (None: the origin): Bullet reports and resets the centre's pose, the service the frame's.
    object_com: tuple = ()

    def __getattr__(self, name: str) -> int:
        """A body by its name (``handles.table``, ``handles.container``, ``handles.rail``)."""
        bodies = self.__dict__.get("bodies") or {}
        if name in bodies:
            return bodies[name]
        raise AttributeError(name)

    @property
    def blocks(self) -> tuple[int, ...]:
        """The bodies named b1, b2, ... (the block worlds'), in order."""
        return tuple(i for n, i in self.bodies.items() if re.fullmatch(r"b\d+", n))


def configure_physics(client: int, desc: SceneDescription) -> None:
    pb.setGravity(*desc.gravity, physicsClientId=client)
    pb.setPhysicsEngineParameter(
        fixedTimeStep=desc.time_step,
        numSolverIterations=desc.solver_iterations,
        numSubSteps=0,
        deterministicOverlappingPairs=1,
        physicsClientId=client,
    )


def box_shape(client: int, half) -> int:
    return pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half), physicsClientId=client)


def _one_shape(client: int, s) -> int:
    """A shape at the body's origin."""
    if isinstance(s, BoxShape):
        return box_shape(client, s.half)
    if isinstance(s, CylinderShape):
        return pb.createCollisionShape(pb.GEOM_CYLINDER, radius=s.radius, height=s.height,
                                       physicsClientId=client)
    return pb.createCollisionShape(pb.GEOM_MESH, fileName=s.path, meshScale=list(s.scale),
                                   physicsClientId=client)


def build_body(client: int, body: Body) -> int:
    if len(body.shapes) == 1 and tuple(body.shapes[0].position) == (0.0, 0.0, 0.0):
        shape = _one_shape(client, body.shapes[0])
    elif all(isinstance(s, BoxShape) for s in body.shapes):
        shape = pb.createCollisionShapeArray(
            [pb.GEOM_BOX] * len(body.shapes), halfExtents=[list(s.half) for s in body.shapes],
            collisionFramePositions=[list(s.position) for s in body.shapes], physicsClientId=client)
    else:
        shape = _compound(client, body.shapes)
    extra = {"useMaximalCoordinates": True} if body.maximal_coordinates else {}
    mass = float(body.mass) if body.mass else 0
    explicit = bool(mass) and not engines_derive_alike(body)
    if explicit:
        com, inertia = inertial(body)
        if np.any(com):
            extra["baseInertialFramePosition"] = [float(x) for x in com]
    uid = pb.createMultiBody(mass, shape, basePosition=list(body.position), **extra, physicsClientId=client)
    if explicit:
        derived = np.array(pb.getDynamicsInfo(uid, -1, physicsClientId=client)[2])
        # Bullet derives a compound's inertia from its bounding box; a declared or
        # shape-derived one replaces it (kept where they agree to rounding: same bits).
        if not np.allclose(derived, inertia, rtol=1e-12, atol=0.0):
            if body.maximal_coordinates:
                # Bullet's changeDynamics turns a maximal-coordinates body's state to NaN
                # when it sets the inertia (pybullet 3.2.x): that body is built as a
                # multibody instead (the flag is a speed hint; the physics is the same).
                pb.removeBody(uid, physicsClientId=client)
                extra.pop("useMaximalCoordinates")
                uid = pb.createMultiBody(mass, shape, basePosition=list(body.position), **extra,
                                         physicsClientId=client)
            pb.changeDynamics(uid, -1, localInertiaDiagonal=[float(x) for x in inertia], physicsClientId=client)
    pb.changeDynamics(uid, -1, lateralFriction=body.friction, physicsClientId=client)
    return uid


def centre_offset(body: Body) -> np.ndarray | None:
    """The centre of mass in the body frame where Bullet's base pose is not the frame's
    (Bullet's base pose is the inertial frame's); None where they coincide."""
    if not body.mass or engines_derive_alike(body):
        return None
    com, _ = inertial(body)
    return com if np.any(com) else None


def _compound(client: int, shapes) -> int:
    """Shapes of several kinds in one compound body."""
    kinds = {BoxShape: pb.GEOM_BOX, CylinderShape: pb.GEOM_CYLINDER, MeshShape: pb.GEOM_MESH}
    args = {"shapeTypes": [kinds[type(s)] for s in shapes],
            "halfExtents": [list(s.half) if isinstance(s, BoxShape) else [0, 0, 0] for s in shapes],
            "radii": [s.radius if isinstance(s, CylinderShape) else 0.0 for s in shapes],
            "lengths": [s.height if isinstance(s, CylinderShape) else 0.0 for s in shapes],
            "fileNames": [s.path if isinstance(s, MeshShape) else "" for s in shapes],
            "meshScales": [list(s.scale) if isinstance(s, MeshShape) else [1, 1, 1] for s in shapes],
            "collisionFramePositions": [list(s.position) for s in shapes]}
    return pb.createCollisionShapeArray(physicsClientId=client, **args)


def build_gripper(client: int, g: Gripper) -> tuple[int, tuple[int, int], int]:
    """A palm carried by a fixed constraint and two prismatic fingers closing along local y."""
    pz = g.palm_half[2]
    fy, fz = g.finger_half[1], g.finger_half[2]
    palm = box_shape(client, g.palm_half)
    finger = box_shape(client, g.finger_half)
    z0 = g.carry_height + g.palm_offset
    body = pb.createMultiBody(
        baseMass=g.palm_mass, baseCollisionShapeIndex=palm, basePosition=[0, 0, z0],
        linkMasses=[g.finger_mass, g.finger_mass], linkCollisionShapeIndices=[finger, finger],
        linkVisualShapeIndices=[-1, -1],
        linkPositions=[[0, 0, -(pz + fz)], [0, 0, -(pz + fz)]],
        linkOrientations=[[0, 0, 0, 1]] * 2,
        linkInertialFramePositions=[[0, 0, 0]] * 2,
        linkInertialFrameOrientations=[[0, 0, 0, 1]] * 2,
        linkParentIndices=[0, 0], linkJointTypes=[pb.JOINT_PRISMATIC] * 2,
        linkJointAxis=[[0, 1, 0], [0, -1, 0]], physicsClientId=client)
    for j in (-1, 0, 1):
        pb.changeDynamics(body, j, lateralFriction=g.friction, physicsClientId=client)
    for j in (0, 1):
        pb.changeDynamics(body, j, jointLowerLimit=fy, jointUpperLimit=g.max_opening / 2 + fy,
                          physicsClientId=client)
    # The fingers must not collide with each other or the palm (they overlap at the joint).
    pb.setCollisionFilterPair(body, body, 0, 1, 0, physicsClientId=client)
    gear = pb.createConstraint(body, 0, body, 1, pb.JOINT_GEAR, [1, 0, 0], [0, 0, 0], [0, 0, 0],
                               physicsClientId=client)
    pb.changeConstraint(gear, gearRatio=-1, erp=GEAR_ERP, maxForce=GEAR_MAX_FORCE, physicsClientId=client)
    cid = pb.createConstraint(body, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                              [0, 0, z0], physicsClientId=client)
    pb.changeConstraint(cid, maxForce=g.base_max_force, physicsClientId=client)
    return body, (0, 1), cid


def build_scene(client: int, desc: SceneDescription) -> SceneHandles:
    """Build every body of `desc` in its order, then the friction anchors, then the gripper."""
    configure_physics(client, desc)
    bodies = {b.name: build_body(client, b) for b in desc.bodies}
    for b in desc.bodies:
        if b.friction_anchor:
            pb.changeDynamics(bodies[b.name], -1, frictionAnchor=1, physicsClientId=client)
    gripper, fingers, cid = build_gripper(client, desc.gripper)
    g = desc.gripper
    return SceneHandles(client, bodies, tuple(bodies[n] for n in desc.objects), gripper, fingers, cid,
                        g.palm_offset, g.finger_half[1], g.grip_force, desc.time_step,
                        tuple(centre_offset(desc.body(n)) for n in desc.objects))
