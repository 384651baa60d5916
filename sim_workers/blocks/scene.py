"""The pybullet bodies every block world shares: physics settings, the table, cubes and the
floating gripper (a palm on a force-limited constraint, two coupled prismatic fingers).

Each builder takes the domain's spec and reads only the fields it names (``time_step``,
``solver_iterations``, ``mu_*``, ``palm_half``, ``finger_half``, ``max_opening``,
``carry_height``, ``palm_offset``, ``base_max_force``, ``init_slot(i)``), so a block world
of any layout builds from them.
"""
from __future__ import annotations

import numpy as np
import pybullet as pb


def configure_physics(client: int, spec) -> None:
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    pb.setPhysicsEngineParameter(
        fixedTimeStep=spec.time_step,
        numSolverIterations=spec.solver_iterations,
        numSubSteps=0,
        deterministicOverlappingPairs=1,
        physicsClientId=client,
    )


def box_shape(client: int, half) -> int:
    return pb.createCollisionShape(pb.GEOM_BOX, halfExtents=list(half), physicsClientId=client)


def build_table(client: int, spec) -> int:
    # A thick slab, not an infinite plane: a block dropped from the hand hits it at ~2 m/s
    # (15 mm a step) and against a plane it stayed stuck ~1 cm deep (measured); box-box
    # contacts push it back out.
    slab = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[2, 2, 0.05], physicsClientId=client)
    table = pb.createMultiBody(0, slab, basePosition=[0, 0, -0.05], physicsClientId=client)
    pb.changeDynamics(table, -1, lateralFriction=spec.mu_table, physicsClientId=client)
    return table


def build_blocks(client: int, spec, sizes: np.ndarray, masses: np.ndarray) -> tuple[int, ...]:
    bodies = []
    for i, (s, m) in enumerate(zip(sizes, masses)):
        x, y = spec.init_slot(i)
        shape = box_shape(client, (s / 2, s / 2, s / 2))
        body = pb.createMultiBody(float(m), shape, basePosition=[x, y, s / 2],
                                  useMaximalCoordinates=True, physicsClientId=client)
        pb.changeDynamics(body, -1, lateralFriction=spec.mu_block, physicsClientId=client)
        bodies.append(body)
    return tuple(bodies)


PALM_MASS = 0.5      # kg
FINGER_MASS = 0.05   # kg each
GRIPPER_MASS = PALM_MASS + 2 * FINGER_MASS   # what a wrist sensor reads with an empty hand


def build_gripper(client: int, spec) -> tuple[int, tuple[int, int], int]:
    """A palm carried by a fixed constraint and two prismatic fingers closing along local y."""
    px, py, pz = spec.palm_half
    fx, fy, fz = spec.finger_half
    palm = box_shape(client, spec.palm_half)
    finger = box_shape(client, spec.finger_half)
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
