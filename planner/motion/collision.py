"""A pure-geometry validity check: boxes against the gripper (a turned box or a sphere).
The loop checks transits with it against the observed obstacles; tests and benchmarks use
it as a stand-in for a physics world's collision query."""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np

# Added to |R_ij| in the separating-axis test: two near-parallel edges give a cross
# product near zero, which rounding must not turn into a separating axis.
_SAT_EPS = 1e-12


def _obstacle(k: int, obstacle, margin: float) -> tuple:
    """One obstacle as floats: its axis-aligned bounds (cx, cy, cz, hx, hy, hz), then its
    rotation (9 floats, row-major) and its own half extents, or None for an axis-aligned one."""
    c, h = (np.asarray(v, dtype=np.float64) for v in obstacle[:2])
    rot = np.asarray(obstacle[2], dtype=np.float64) if len(obstacle) > 2 and obstacle[2] is not None else None
    if c.shape != (3,) or h.shape != (3,) or not (np.all(np.isfinite(c)) and np.all(np.isfinite(h))):
        raise ValueError(f"obstacle {k} must be (center (3,), half_extents (3,)[, rotation (3, 3)]), finite")
    if np.any(h < 0):
        raise ValueError(f"obstacle {k} has negative half extents {h.tolist()}")
    if rot is not None and (rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6)):
        raise ValueError(f"obstacle {k}: rotation must be a (3, 3) rotation matrix")
    own = h + margin
    if rot is not None and np.array_equal(rot, np.eye(3)):
        rot = None                      # axis-aligned: the bounds are the box
    if rot is None:
        return (*(float(v) for v in (*c, *own)), None, None)
    bounds = np.abs(rot) @ own          # the axis-aligned box around the turned one
    return (*(float(v) for v in (*c, *bounds)), tuple(float(v) for v in rot.ravel()),
            tuple(float(v) for v in own))


def box_checker(obstacles: Sequence[tuple],
                gripper_half_extents: Sequence[float] = (0.02, 0.085, 0.05), *,
                gripper_radius: float | None = None,
                margin: float = 0.0) -> Callable[[np.ndarray], bool]:
    """A pure-geometry validity checker: boxes against the gripper.

    ``obstacles`` are ``(center (3,), half_extents (3,))`` pairs, axis-aligned, or
    ``(center, half_extents, rotation (3, 3))`` triples, boxes turned by a rotation matrix
    (its columns the box's axes in the world: a block as it lies, tipped or turned). The
    gripper is a box of ``gripper_half_extents`` (along its own x, its own y =
    finger-opening direction, and z) centred at ``q[:3]`` and turned by ``q[3]`` about z,
    so yaw matters; or, when ``gripper_radius`` is given, a sphere of that radius (yaw then
    does not matter). Obstacles are inflated by ``margin``. Touching counts as collision;
    non-finite q is invalid.
    """
    boxes = [_obstacle(k, o, margin) for k, o in enumerate(obstacles)]

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
            for cx, cy, cz, hx, hy, hz, rot, own in boxes:
                px, py, pz = x - cx, y - cy, z - cz
                if rot is not None:       # the centre in the box's own frame (R^T p)
                    px, py, pz = (rot[0] * px + rot[3] * py + rot[6] * pz,
                                  rot[1] * px + rot[4] * py + rot[7] * pz,
                                  rot[2] * px + rot[5] * py + rot[8] * pz)
                    hx, hy, hz = own
                dx = max(abs(px) - hx, 0.0)
                dy = max(abs(py) - hy, 0.0)
                dz = max(abs(pz) - hz, 0.0)
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
        for cx, cy, cz, hx, hy, hz, rot, own in boxes:
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
            # Overlapping the bounds of a turned box: the exact test against the box itself.
            if rot is not None and _obb_separated(-dx, -dy, -dz, c, s, (ga, gb, gz), rot, own):
                continue
            return False
        return True

    return box_valid


def _obb_separated(tx: float, ty: float, tz: float, c: float, s: float,
                   a: tuple[float, float, float], rot: tuple, b: tuple[float, float, float]) -> bool:
    """Whether the gripper box (half extents `a`, turned by the yaw whose cosine and sine
    are c, s) and a turned box (`rot` row-major, half extents `b`), whose centre is (tx,
    ty, tz) from the gripper's, are apart: the separating-axis test on the 15 axes (each
    box's three, and the nine cross products of their edges), as in Ericson, Real-Time
    Collision Detection, 4.4.1. Touching is not apart."""
    # R[i][j] = A_i . B_j, the gripper's axes A = (c, s, 0), (-s, c, 0), (0, 0, 1).
    r = [[c * rot[j] + s * rot[3 + j] for j in range(3)],
         [-s * rot[j] + c * rot[3 + j] for j in range(3)],
         [rot[6 + j] for j in range(3)]]
    ar = [[abs(v) + _SAT_EPS for v in row] for row in r]
    t = (c * tx + s * ty, -s * tx + c * ty, tz)          # the offset in the gripper's frame
    for i in range(3):
        if abs(t[i]) > a[i] + b[0] * ar[i][0] + b[1] * ar[i][1] + b[2] * ar[i][2]:
            return True
    for j in range(3):
        if abs(t[0] * r[0][j] + t[1] * r[1][j] + t[2] * r[2][j]) > \
                a[0] * ar[0][j] + a[1] * ar[1][j] + a[2] * ar[2][j] + b[j]:
            return True
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            dist = abs(t[i2] * r[i1][j] - t[i1] * r[i2][j])
            reach = a[i1] * ar[i2][j] + a[i2] * ar[i1][j] + b[j1] * ar[i][j2] + b[j2] * ar[i][j1]
            if dist > reach:
                return True
    return False
