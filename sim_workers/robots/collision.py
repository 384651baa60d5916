"""An arm's links as collision shapes: capsules declared in the link frames, checked as
chains of spheres against boxes (the believed scene) and the table's plane.

A capsule of radius r is covered by spheres on its axis ``s`` apart of radius
``sqrt(r^2 + (s/2)^2)`` (the farthest point of the capsule's surface from the nearest sphere
centre), so a chain never misses a contact the capsule has; with ``s = r / 2`` the spheres
are 3 % wider than the capsule. Sphere against an oriented box is exact (the box's nearest
point, clamped in the box's frame), so the check is conservative by that 3 % alone.

The gripper's palm and fingers are not links here: they touch what they grasp, and the
service's gripper check (``planner.motion.box_checker`` on the domain's gripper boxes) is
theirs. The links end where the gripper's coupling meets its palm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .kinematics import frames

__all__ = ["Capsule", "first_contact", "link_spheres", "links_checker", "moving_links", "sphere_chain"]

SPACING = 0.5       # sphere spacing along a capsule, as a fraction of its radius (see above)


@dataclass(frozen=True)
class Capsule:
    """A link's capsule: endpoints `a`, `b` (m) in link frame `frame` (0: the arm's base,
    1-6: the Denavit-Hartenberg frames, 6 is the flange) and its `radius` (m). `floor`:
    whether it is checked against the table's plane (the base link stands on it)."""

    name: str
    frame: int
    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float
    floor: bool = True


def sphere_chain(capsule: Capsule) -> tuple[np.ndarray, float]:
    """(K, 3) sphere centres in the capsule's frame and the spheres' common radius."""
    a, b = np.asarray(capsule.a, dtype=np.float64), np.asarray(capsule.b, dtype=np.float64)
    step = SPACING * capsule.radius
    k = max(1, math.ceil(float(np.linalg.norm(b - a)) / step))
    f = np.linspace(0.0, 1.0, k + 1)[:, None]
    return a + f * (b - a), math.hypot(capsule.radius, 0.5 * float(np.linalg.norm(b - a)) / k)


class _Chains:
    """Every capsule's spheres, grouped by frame, for one arm (built once)."""

    def __init__(self, capsules: Sequence[Capsule]) -> None:
        self.frames = sorted({c.frame for c in capsules})
        self.centres, self.radii, self.floor, self.names = [], [], [], []
        for fr in self.frames:
            pts, rad, flo = [], [], []
            for c in capsules:
                if c.frame == fr:
                    p, r = sphere_chain(c)
                    pts.append(p)
                    rad.append(np.full(len(p), r))
                    flo.append(np.full(len(p), c.floor))
                    self.names += [c.name] * len(p)
            self.centres.append(np.concatenate(pts))
            self.radii.append(np.concatenate(rad))
            self.floor.append(np.concatenate(flo))
        self.radius = np.concatenate(self.radii)
        self.on_floor = np.concatenate(self.floor)


def link_spheres(arm, q: np.ndarray, chains: _Chains | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The world centres (K, 3) and radii (K,) of the arm's link spheres at joints `q`."""
    chains = chains or _Chains(arm.links)
    fs = [np.eye(4)] + frames(arm.dh, q)
    out = []
    for fr, pts in zip(chains.frames, chains.centres):
        t = arm.base @ fs[fr]
        out.append(pts @ t[:3, :3].T + t[:3, 3])
    return np.concatenate(out), chains.radius


def _boxes(obstacles: Sequence[tuple]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (B, 3), half extents (B, 3) and rotations (B, 3, 3) of (centre, half[, rot])."""
    c = np.array([np.asarray(o[0], dtype=np.float64) for o in obstacles]).reshape(-1, 3)
    h = np.array([np.asarray(o[1], dtype=np.float64) for o in obstacles]).reshape(-1, 3)
    r = np.array([np.asarray(o[2], dtype=np.float64) if len(o) > 2 and o[2] is not None else np.eye(3)
                  for o in obstacles]).reshape(-1, 3, 3)
    return c, h, r


def moving_links(arm) -> tuple:
    """The links a joint moves (not frame 0's, the base): only these can be cleared by a
    plan. A resting object against the fixed base (a block that fell beside it) is no
    reason to refuse every motion."""
    return tuple(c for c in arm.links if c.frame != 0)


def links_checker(arm, obstacles: Sequence[tuple], *, floor_z: float | None = 0.0,
                  margin: float = 0.0) -> Callable[[np.ndarray], bool]:
    """is_valid(q): every moving link sphere of `arm` at joints q (``moving_links``) clear
    of every box of `obstacles` ((centre, half extents[, rotation]) in the world, as a
    domain's ``obstacles``) by `margin`, and above the table's plane `floor_z` (None: no
    table) for links that are checked against it; joints outside the arm's limits are
    invalid."""
    chains = _Chains(moving_links(arm))
    c, h, rot = _boxes(obstacles)
    low, high = arm.low, arm.high

    def is_valid(q: np.ndarray) -> bool:
        q = np.asarray(q, dtype=np.float64)
        if not np.all(np.isfinite(q)) or np.any(q < low - 1e-9) or np.any(q > high + 1e-9):
            return False
        return _contact(arm, chains, q, c, h, rot, floor_z, margin) is None

    is_valid.contact = lambda q: _contact(arm, chains, np.asarray(q, dtype=np.float64), c, h, rot, floor_z,
                                          margin)
    return is_valid


def _contact(arm, chains: _Chains, q: np.ndarray, c, h, rot, floor_z, margin) -> tuple[str, int] | None:
    """(link name, box index; -1: the table) of the first contact at joints q, else None."""
    p, r = link_spheres(arm, q, chains)
    if floor_z is not None:
        low = np.flatnonzero((p[:, 2] - r < floor_z + margin) & chains.on_floor)
        if low.size:
            return chains.names[low[0]], -1
    if not len(c):
        return None
    # each sphere in each box's frame: the nearest point of the box, clamped
    local = np.einsum("bji,kbj->kbi", rot, p[:, None, :] - c[None, :, :])
    gap = local - np.clip(local, -h[None], h[None])
    hit = np.argwhere(np.einsum("kbi,kbi->kb", gap, gap) <= (r[:, None] + margin) ** 2)
    return (chains.names[hit[0, 0]], int(hit[0, 1])) if hit.size else None


def first_contact(arm, obstacles: Sequence[tuple], q: np.ndarray, floor_z: float | None = 0.0) -> str | None:
    """Which link of `arm` at joints `q` meets which box of `obstacles` (or the table), in
    words; None when every link is clear."""
    c, h, rot = _boxes(obstacles)
    hit = _contact(arm, _Chains(moving_links(arm)), np.asarray(q, dtype=np.float64), c, h, rot, floor_z, 0.0)
    if hit is None:
        return None
    return f"the {hit[0]} meets the table" if hit[1] < 0 else f"the {hit[0]} meets obstacle {hit[1]}"
