"""The container scene as data: table, tray, blocks, floating gripper (built by an engine
backend, ``sim_workers.engines``)."""
from __future__ import annotations

import numpy as np

from ..blocks.scene import FINGER_MASS, GRIPPER_MASS, PALM_MASS, block_world  # noqa: F401
from ..scene import Body, BoxShape, SceneDescription
from .spec import ContainerSpec


def tray(spec: ContainerSpec) -> Body:
    """An open tray: a floor and four low walls in one compound rigid body."""
    ix, iy = spec.inner_half
    t, h, f = spec.wall_thickness, spec.wall_height, spec.floor_thickness
    ox, oy = ix + t, iy + t
    halves = [(ox, oy, f / 2), (t / 2, oy, h / 2), (t / 2, oy, h / 2),
              (ix, t / 2, h / 2), (ix, t / 2, h / 2)]
    zc = f + h / 2
    positions = [(0, 0, f / 2), (-(ix + t / 2), 0, zc), (ix + t / 2, 0, zc),
                 (0, -(iy + t / 2), zc), (0, iy + t / 2, zc)]
    x, y = spec.container_init
    # Its mass properties are declared, not derived from the walls: the centre of mass on
    # the floor's underside at the frame's origin and the moments of its outer box (half
    # extents ox, oy and half its height) about it. That is the tray every published
    # figure was measured with (Bullet's own choice for a compound); a tray of uniform
    # walls would have its centre 15 mm higher. Declared, both engines build this one.
    m, hz = float(spec.container_mass), (f + h) / 2.0
    inertia = (m / 12.0 * ((2 * oy) ** 2 + (2 * hz) ** 2), m / 12.0 * ((2 * ox) ** 2 + (2 * hz) ** 2),
               m / 12.0 * ((2 * ox) ** 2 + (2 * oy) ** 2))
    return Body("container", tuple(BoxShape(hf, p) for hf, p in zip(halves, positions)),
                spec.container_mass, (x, y, 0.0), spec.mu_container, maximal_coordinates=True,
                center_of_mass=(0.0, 0.0, 0.0), inertia=inertia)


def scene_description(spec: ContainerSpec, sizes: np.ndarray, masses: np.ndarray) -> SceneDescription:
    """Table, tray, blocks, gripper in a fixed order (the order is part of determinism);
    the objects are the tray, then b1..bN."""
    names = ("container",) + tuple(f"b{i + 1}" for i in range(len(sizes)))
    return block_world(spec, (tray(spec),), sizes, masses, names)
