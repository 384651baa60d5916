"""The bodies every block world shares, as scene data (``sim_workers.scene``): the table,
cubes and the floating gripper; an engine backend builds them (``sim_workers.engines``).

Each builder takes the domain's spec and reads only the fields it names (``mu_*``,
``init_slot(i)``, ``palm_half``, ``finger_half``, ``max_opening``, ``carry_height``,
``palm_offset``, ``base_max_force``, ``grip_force``, ``time_step``,
``solver_iterations``), so a block world of any layout declares its scene from them.
"""
from __future__ import annotations

import numpy as np

from ..scene import Body, BoxShape, Gripper, SceneDescription

PALM_MASS = 0.5      # kg
FINGER_MASS = 0.05   # kg each
GRIPPER_MASS = PALM_MASS + 2 * FINGER_MASS   # what a wrist sensor reads with an empty hand


def table(spec) -> Body:
    """A thick slab, not an infinite plane: a block dropped from the hand hits it at ~2 m/s
    (15 mm a step) and against a plane it stayed stuck ~1 cm deep (measured); box-box
    contacts push it back out."""
    return Body("table", (BoxShape((2, 2, 0.05)),), 0, (0, 0, -0.05), spec.mu_table)


def blocks(spec, sizes: np.ndarray, masses: np.ndarray, friction_anchor: bool = False) -> tuple[Body, ...]:
    """Cube b<i+1> of side sizes[i] and mass masses[i] resting in its supply slot."""
    out = []
    for i, (s, m) in enumerate(zip(sizes, masses)):
        x, y = spec.init_slot(i)
        out.append(Body(f"b{i + 1}", (BoxShape((s / 2, s / 2, s / 2)),), float(m), (x, y, s / 2),
                        spec.mu_block, maximal_coordinates=True, friction_anchor=friction_anchor))
    return tuple(out)


def gripper(spec) -> Gripper:
    return Gripper(tuple(spec.palm_half), tuple(spec.finger_half), PALM_MASS, FINGER_MASS,
                   spec.carry_height, spec.palm_offset, spec.max_opening, spec.mu_finger,
                   spec.base_max_force, spec.grip_force)


def block_world(spec, fixtures: tuple[Body, ...], sizes: np.ndarray, masses: np.ndarray,
                objects: tuple[str, ...] | None = None, friction_anchor: bool = False) -> SceneDescription:
    """The table, the domain's `fixtures` (a tray, a rail), the cubes and the gripper, in
    that build order; `objects` default: the cubes."""
    cubes = blocks(spec, sizes, masses, friction_anchor)
    return SceneDescription(spec.time_step, spec.solver_iterations, (table(spec), *fixtures, *cubes),
                            tuple(objects) if objects is not None else tuple(b.name for b in cubes),
                            gripper(spec))
