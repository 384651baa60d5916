"""Builds the container scene in one pybullet client: table, tray, blocks, floating gripper.

Every call passes ``physicsClientId``: the world owns its client, never the global one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from ..blocks.scene import (FINGER_MASS, GRIPPER_MASS, PALM_MASS, box_shape,  # noqa: F401
                           build_blocks, build_gripper, build_table, configure_physics)
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
