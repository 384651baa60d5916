"""Builds the stack-and-push scene in one pybullet client: table, rail, blocks, gripper.

The table, blocks and floating gripper are the container domain's builders (the spec
carries the same field names); only the rail is new. Every call passes
``physicsClientId``: the world owns its client, never the global one.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from ..blocks.scene import build_blocks, build_gripper, build_table, configure_physics
from .spec import StackAndPushSpec


@dataclass(frozen=True)
class SceneHandles:
    """Body ids of one built scene (valid only inside the client that built it).

    The same fields as the container's handles (the generic world drives the gripper
    through them), with the rail in place of the container."""

    client: int
    table: int
    rail: int
    blocks: tuple[int, ...]
    gripper: int
    fingers: tuple[int, int]
    base_constraint: int
    palm_offset: float
    finger_inner: float
    grip_force: float
    time_step: float

    @property
    def objects(self) -> tuple[int, ...]:
        """Bodies in the domain's object order: b1..bN (the rail is fixed, not an object)."""
        return self.blocks


def build_rail(client: int, spec: StackAndPushSpec) -> int:
    """Two fixed low walls along x, one static compound body; the floor is the table."""
    x0, x1 = spec.rail_x
    hx = (x1 - x0) / 2.0
    t, h = spec.wall_thickness, spec.wall_height
    yc = spec.rail_half_gap + t / 2.0
    half = [hx, t / 2.0, h / 2.0]
    shape = pb.createCollisionShapeArray(
        [pb.GEOM_BOX] * 2, halfExtents=[half, half],
        collisionFramePositions=[[0, -yc, h / 2.0], [0, yc, h / 2.0]], physicsClientId=client)
    body = pb.createMultiBody(0, shape, basePosition=[(x0 + x1) / 2.0, 0.0, 0.0],
                              physicsClientId=client)
    pb.changeDynamics(body, -1, lateralFriction=spec.mu_rail, physicsClientId=client)
    return body


def build_scene(client: int, spec: StackAndPushSpec, sizes: np.ndarray, masses: np.ndarray) -> SceneHandles:
    """Build every body in a fixed order (the order is part of determinism)."""
    configure_physics(client, spec)
    table = build_table(client, spec)
    rail = build_rail(client, spec)
    blocks = build_blocks(client, spec, sizes, masses)
    if spec.friction_anchor:
        # Bullet's friction anchors hold resting contacts in place. Without them the
        # stacked contacts creep: a block slid 20 mm on the one below over seven stacks
        # (about 1 mm per action, growing) and a tower of seven fell on its own (measured).
        for b in blocks:
            pb.changeDynamics(b, -1, frictionAnchor=1, physicsClientId=client)
    gripper, fingers, cid = build_gripper(client, spec)
    return SceneHandles(client, table, rail, blocks, gripper, fingers, cid,
                        spec.palm_offset, spec.finger_half[1], spec.grip_force,
                        spec.time_step)
