"""Builds the container scene in one pybullet client: table, tray, blocks, floating gripper.

Every call passes ``physicsClientId``: the world owns its client, never the global one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from .spec import ContainerSpec


@dataclass(frozen=True)
class SceneHandles:
    """Body ids of one built scene (valid only inside the client that built it)."""

    client: int
    table: int
    container: int
    blocks: tuple[int, ...]
    gripper: int
    fingers: tuple[int, int]     # joint indices of the two prismatic fingers
    base_constraint: int
    palm_offset: float           # palm centre above the fingertip tool point
    finger_inner: float          # joint position at which a finger's inner face is at y = 0
    grip_force: float
    time_step: float

    @property
    def objects(self) -> tuple[int, ...]:
        """Bodies in the domain's object order: c, b1..bN."""
        return (self.container,) + self.blocks


def configure_physics(client: int, spec: ContainerSpec) -> None:
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    pb.setPhysicsEngineParameter(
        fixedTimeStep=spec.time_step,
        numSolverIterations=spec.solver_iterations,
        numSubSteps=0,
        deterministicOverlappingPairs=1,
        physicsClientId=client,
    )


def _box(client: int, half) -> int:
    return pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half), physicsClientId=client)


def build_table(client: int, spec: ContainerSpec) -> int:
    # A thick slab, not an infinite plane: a block dropped from the hand hits it at ~2 m/s
    # (15 mm a step) and against a plane it stayed stuck ~1 cm deep (measured); box-box
    # contacts push it back out.
    slab = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[2, 2, 0.05], physicsClientId=client)
    table = pb.createMultiBody(0, slab, basePosition=[0, 0, -0.05], physicsClientId=client)
    pb.changeDynamics(table, -1, lateralFriction=spec.mu_table, physicsClientId=client)
    return table


def build_container(client: int, spec: ContainerSpec) -> int:
    """An open tray: a floor and four low walls in one compound rigid body."""
    ix, iy = spec.inner_half
    t, h, f = spec.wall_thickness, spec.wall_height, spec.floor_thickness
    ox, oy = ix + t, iy + t
    halves = [(ox, oy, f / 2), (t / 2, oy, h / 2), (t / 2, oy, h / 2),
              (ix, t / 2, h / 2), (ix, t / 2, h / 2)]
    zc = f + h / 2
    positions = [(0, 0, f / 2), (-(ix + t / 2), 0, zc), (ix + t / 2, 0, zc),
                 (0, -(iy + t / 2), zc), (0, iy + t / 2, zc)]
    shape = pb.createCollisionShapeArray(
        [pb.GEOM_BOX] * 5, halfExtents=[list(x) for x in halves],
        collisionFramePositions=[list(p) for p in positions], physicsClientId=client)
    x, y = spec.container_init
    body = pb.createMultiBody(spec.container_mass, shape, basePosition=[x, y, 0.0],
                              useMaximalCoordinates=True, physicsClientId=client)
    pb.changeDynamics(body, -1, lateralFriction=spec.mu_container, physicsClientId=client)
    return body


def build_blocks(client: int, spec: ContainerSpec, sizes: np.ndarray, masses: np.ndarray) -> tuple[int, ...]:
    bodies = []
    for i, (s, m) in enumerate(zip(sizes, masses)):
        x, y = spec.init_slot(i)
        shape = _box(client, (s / 2, s / 2, s / 2))
        body = pb.createMultiBody(float(m), shape, basePosition=[x, y, s / 2],
                                  useMaximalCoordinates=True, physicsClientId=client)
        pb.changeDynamics(body, -1, lateralFriction=spec.mu_block, physicsClientId=client)
        bodies.append(body)
    return tuple(bodies)


PALM_MASS = 0.5      # kg
FINGER_MASS = 0.05   # kg each
GRIPPER_MASS = PALM_MASS + 2 * FINGER_MASS   # what a wrist sensor reads with an empty hand


def build_gripper(client: int, spec: ContainerSpec) -> tuple[int, tuple[int, int], int]:
    """A palm carried by a fixed constraint and two prismatic fingers closing along local y."""
    px, py, pz = spec.palm_half
    fx, fy, fz = spec.finger_half
    palm = _box(client, spec.palm_half)
    finger = _box(client, spec.finger_half)
    z0 = spec.carry_height + spec.palm_offset
    body = pb.createMultiBody(
        baseMass=PALM_MASS, baseCollisionShapeIndex=palm, basePosition=[0, 0, z0],
        linkMasses=[FINGER_MASS, FINGER_MASS], linkCollisionShapeIndices=[finger, finger],
        linkVisualShapeIndices=[-1, -1],
        linkPositions=[[0, 0, -(pz + fz)], [0, 0, -(pz + fz)]],
        linkOrientations=[[0, 0, 0, 1]] * 2,
        linkInertialFramePositions=[[0, 0, 0]] * 2,
        linkInertialFrameOrientations=[[0, 0, 0, 1]] * 2,
        linkParentIndices=[0, 0], linkJointTypes=[pb.JOINT_PRISMATIC] * 2,
        linkJointAxis=[[0, 1, 0], [0, -1, 0]], physicsClientId=client)
    for j in (-1, 0, 1):
        pb.changeDynamics(body, j, lateralFriction=spec.mu_finger, physicsClientId=client)
    for j in (0, 1):
        pb.changeDynamics(body, j, jointLowerLimit=fy, jointUpperLimit=spec.max_opening / 2 + fy,
                          physicsClientId=client)
    # The fingers must not collide with each other or the palm (they overlap at the joint).
    pb.setCollisionFilterPair(body, body, 0, 1, 0, physicsClientId=client)
    # Couple the fingers (as pybullet's Panda example does): two independent position
    # servos squeezing one object drift sideways together and carry it off centre.
    gear = pb.createConstraint(body, 0, body, 1, pb.JOINT_GEAR, [1, 0, 0], [0, 0, 0], [0, 0, 0],
                               physicsClientId=client)
    pb.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50, physicsClientId=client)
    cid = pb.createConstraint(body, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                              [0, 0, z0], physicsClientId=client)
    pb.changeConstraint(cid, maxForce=spec.base_max_force, physicsClientId=client)
    return body, (0, 1), cid


def build_scene(client: int, spec: ContainerSpec, sizes: np.ndarray, masses: np.ndarray) -> SceneHandles:
    """Build every body in a fixed order (the order is part of determinism)."""
    configure_physics(client, spec)
    table = build_table(client, spec)
    container = build_container(client, spec)
    blocks = build_blocks(client, spec, sizes, masses)
    gripper, fingers, cid = build_gripper(client, spec)
    return SceneHandles(client, table, container, blocks, gripper, fingers, cid,
                        spec.palm_offset, spec.finger_half[1], spec.grip_force,
                        spec.time_step)
