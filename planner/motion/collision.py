"""A pure-geometry validity check: axis-aligned boxes against the gripper (a turned box
or a sphere). The loop checks transits with it against the observed obstacles; tests and
benchmarks use it as a stand-in for a physics world's collision query."""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np


def box_checker(obstacles: Sequence[tuple[Sequence[float], Sequence[float]]],
                gripper_half_extents: Sequence[float] = (0.02, 0.085, 0.05), *,
                gripper_radius: float | None = None,
                margin: float = 0.0) -> Callable[[np.ndarray], bool]:
    """A pure-geometry validity checker: axis-aligned boxes against the gripper.

    ``obstacles`` are ``(center (3,), half_extents (3,))`` pairs. The gripper is a box of
    ``gripper_half_extents`` (along its own x, its own y = finger-opening direction, and z)
    centred at ``q[:3]`` and turned by ``q[3]`` about z, so yaw matters; or, when
    ``gripper_radius`` is given, a sphere of that radius (yaw then does not matter).
    Obstacles are inflated by ``margin``. Touching counts as collision; non-finite q is invalid.
    """
    boxes: list[tuple[float, float, float, float, float, float]] = []
    for k, (c, h) in enumerate(obstacles):
        c = np.asarray(c, dtype=np.float64)
        h = np.asarray(h, dtype=np.float64)
        if c.shape != (3,) or h.shape != (3,) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(h))):
            raise ValueError(f"obstacle {k} must be (center (3,), half_extents (3,)), finite")
        if np.any(h < 0):
            raise ValueError(f"obstacle {k} has negative half extents {h.tolist()}")
        boxes.append(tuple(float(v) for v in (*c, *(h + margin))))  # type: ignore[arg-type]

    # Pure-Python arithmetic on floats: called tens of thousands of times per RRT* run,
    # where per-call numpy overhead would dominate for a handful of boxes.
    if gripper_radius is not None:
        r = float(gripper_radius)
        if not (math.isfinite(r) and r >= 0):
            raise ValueError(f"gripper_radius must be a non-negative finite number, got {r}")
        r2 = r * r

        def sphere_valid(q: np.ndarray) -> bool:
            x, y, z = float(q[0]), float(q[1]), float(q[2])
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
                return False
            for cx, cy, cz, hx, hy, hz in boxes:
                dx = max(abs(x - cx) - hx, 0.0)
                dy = max(abs(y - cy) - hy, 0.0)
                dz = max(abs(z - cz) - hz, 0.0)
                if dx * dx + dy * dy + dz * dz <= r2:
                    return False
            return True

        return sphere_valid

    g = np.asarray(gripper_half_extents, dtype=np.float64)
    if g.shape != (3,) or not np.all(np.isfinite(g)) or np.any(g < 0):
        raise ValueError(f"gripper_half_extents must be 3 non-negative numbers, got {gripper_half_extents!r}")
    ga, gb, gz = (float(v) for v in g)

    def box_valid(q: np.ndarray) -> bool:
        x, y, z, yaw = float(q[0]), float(q[1]), float(q[2]), float(q[3])
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(yaw)):
            return False
        c, s = math.cos(yaw), math.sin(yaw)
        ac, as_ = abs(c), abs(s)
        # The gripper's footprint projected on the world axes (its xy bounding box).
        fx = ga * ac + gb * as_
        fy = ga * as_ + gb * ac
        for cx, cy, cz, hx, hy, hz in boxes:
            dz = z - cz
            if abs(dz) > hz + gz:
                continue
            dx, dy = x - cx, y - cy
            if abs(dx) > hx + fx or abs(dy) > hy + fy:
                continue
            # Separating-axis test on the gripper's own axes (the other two are done above).
            if abs(dx * c + dy * s) > ga + hx * ac + hy * as_:
                continue
            if abs(-dx * s + dy * c) > gb + hx * as_ + hy * ac:
                continue
            return False
        return True

    return box_valid
