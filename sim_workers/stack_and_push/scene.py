"""The stack-and-push scene as data: table, a guide rail, blocks, floating gripper (built
by an engine backend, ``sim_workers.engines``)."""
from __future__ import annotations

import numpy as np

from ..blocks.scene import block_world
from ..scene import Body, BoxShape, SceneDescription
from .spec import StackAndPushSpec


def rail(spec: StackAndPushSpec) -> Body:
    """Two fixed low walls along x, one static compound body; the floor is the table."""
    x0, x1 = spec.rail_x
    hx = (x1 - x0) / 2.0
    t, h = spec.wall_thickness, spec.wall_height
    yc = spec.rail_half_gap + t / 2.0
    half = (hx, t / 2.0, h / 2.0)
    return Body("rail", (BoxShape(half, (0, -yc, h / 2.0)), BoxShape(half, (0, yc, h / 2.0))), 0,
                ((x0 + x1) / 2.0, 0.0, 0.0), spec.mu_rail)


def scene_description(spec: StackAndPushSpec, sizes: np.ndarray, masses: np.ndarray) -> SceneDescription:
    """Table, rail, blocks, gripper in a fixed order (the order is part of determinism); the
    objects are b1..bN (the rail is fixed, not an object). With ``friction_anchor``,
    Bullet's friction anchors hold resting contacts in place: without them the stacked
    contacts creep (a block slid 20 mm on the one below over seven stacks, about 1 mm per
    action, growing, and a tower of seven fell on its own: measured)."""
    return block_world(spec, (rail(spec),), sizes, masses, friction_anchor=bool(spec.friction_anchor))
