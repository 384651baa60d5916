"""A domain's scene as data: what an engine backend builds (the engine seam, issue 26).

The physics half declares its scene once, for one hypothesis of L
(``PhysicsDomain.scene_description(props)``): rigid bodies made of boxes with their mass,
pose and friction, in build order; which of them are the domain's objects (the rows of
``Configuration.objects``); the floating gripper; the physics settings. Which properties of
L set which physical parameter is explicit here: a block's size is its box, its mass the
body's mass. ``sim_workers.engines`` turns a description into a built scene in one engine
(pybullet, the default); a second engine is another backend over the same description,
not a second copy of any domain's scene.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class BoxShape:
    """A box collision shape: half extents, and its centre in the body's frame."""

    half: Vec3
    position: Vec3 = (0.0, 0.0, 0.0)

    def extent(self) -> float:
        return float(min(self.half))


@dataclass(frozen=True)
class CylinderShape:
    """A cylinder along the body's z axis: radius and full height, centre in the body frame."""

    radius: float
    height: float
    position: Vec3 = (0.0, 0.0, 0.0)

    def extent(self) -> float:
        return float(min(self.radius, self.height))


@dataclass(frozen=True)
class MeshShape:
    """A convex mesh from a file a domain ships (Wavefront .obj), scaled per axis; centre
    in the body frame. The engine takes the file's convex hull as the collision shape."""

    path: str
    scale: Vec3 = (1.0, 1.0, 1.0)
    position: Vec3 = (0.0, 0.0, 0.0)

    def extent(self) -> float:
        return float(min(self.scale))


Shape = BoxShape | CylinderShape | MeshShape


@dataclass(frozen=True)
class Body:
    """A rigid body: one shape, or a compound of several in one body. `mass` 0 is fixed."""

    name: str
    shapes: tuple[Shape, ...]
    mass: float
    position: Vec3                    # the base frame's position at build time
    friction: float                   # lateral (Coulomb) friction coefficient
    # Bullet's maximal-coordinates rigid body (a free body's cheaper, exact integration);
    # another engine may ignore it.
    maximal_coordinates: bool = False
    # Hold resting contacts in place (Bullet's friction anchors): a stacked body does not
    # creep over many actions.
    friction_anchor: bool = False
    # The centre of mass in the body's frame, and the principal moments of inertia about it
    # along the body's axes (kg m^2). None: derived from the shapes as one solid of uniform
    # density (``inertial``). Both engines build the body with these values (issue 39:
    # pybullet put the centre of mass at the frame's origin, MuJoCo at the shapes' centroid,
    # so one declaration made two different bodies).
    center_of_mass: Vec3 | None = None
    inertia: Vec3 | None = None


@dataclass(frozen=True)
class Gripper:
    """The floating gripper: a palm carried by a force-limited fixed constraint, two
    prismatic fingers closing along the palm's y axis and coupled to move as one."""

    palm_half: Vec3
    finger_half: Vec3
    palm_mass: float
    finger_mass: float
    carry_height: float               # tool point (fingertips) height at build time
    palm_offset: float                # palm centre above the tool point
    max_opening: float
    friction: float
    base_max_force: float             # N, the carrying constraint's force limit
    grip_force: float                 # N per finger


@dataclass(frozen=True)
class SceneDescription:
    """One scene for one hypothesis of L, in build order (the order is part of determinism)."""

    time_step: float
    solver_iterations: int
    bodies: tuple[Body, ...]
    objects: tuple[str, ...]          # body names in Configuration.objects order
    gripper: Gripper
    gravity: Vec3 = (0.0, 0.0, -9.81)

    def body(self, name: str) -> Body:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(f"scene: no body named {name!r}")


# -- mass properties ---------------------------------------------------------------------
@lru_cache(maxsize=64)
def _mesh_box(path: str) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half extents) of a Wavefront file's vertices, unscaled."""
    verts = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
    v = np.asarray(verts, dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return (lo + hi) / 2.0, (hi - lo) / 2.0


def _solid(shape: Shape) -> tuple[float, np.ndarray, np.ndarray]:
    """(volume, centre in the body frame, principal moments per unit mass about the centre)."""
    pos = np.asarray(shape.position, dtype=np.float64)
    if isinstance(shape, CylinderShape):
        r, h = float(shape.radius), float(shape.height)
        side = (3.0 * r * r + h * h) / 12.0
        return float(np.pi * r * r * h), pos, np.array([side, side, r * r / 2.0])
    if isinstance(shape, MeshShape):
        # A mesh counts as its scaled bounding box: declare center_of_mass and inertia
        # where that is too rough (a hollow or an L-shaped mesh).
        centre, half = _mesh_box(shape.path)
        scale = np.asarray(shape.scale, dtype=np.float64)
        pos, half = pos + centre * scale, half * np.abs(scale)
    else:
        half = np.asarray(shape.half, dtype=np.float64)
    sq = half * half
    return float(8.0 * np.prod(half)), pos, np.array([sq[1] + sq[2], sq[0] + sq[2], sq[0] + sq[1]]) / 3.0


def engines_derive_alike(body: Body) -> bool:
    """Whether every engine derives the same mass properties from the body's shapes by
    itself: one box centred on the frame, nothing declared (centre at the origin, the
    box's own moments). Any other body is built with ``inertial(body)`` set explicitly."""
    return (body.center_of_mass is None and body.inertia is None and len(body.shapes) == 1
            and isinstance(body.shapes[0], BoxShape) and tuple(body.shapes[0].position) == (0.0, 0.0, 0.0))


def inertial(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """(centre of mass in the body frame, principal moments about it in kg m^2) of a body:
    what it declares, else its shapes as one solid of uniform density (overlaps counted
    twice; the shapes' axes are the body's). Products of inertia are left out: a compound
    whose principal axes are not the body's should declare ``inertia``."""
    solids = [_solid(s) for s in body.shapes]
    vol = np.array([v for v, _, _ in solids])
    share = vol / vol.sum()
    centres = np.array([c for _, c, _ in solids])
    com = (np.asarray(body.center_of_mass, dtype=np.float64) if body.center_of_mass is not None
           else share @ centres)
    if body.inertia is not None:
        return com, np.asarray(body.inertia, dtype=np.float64)
    moments = np.zeros(3)
    for w, (_, c, own) in zip(share, solids):
        d = c - com
        moments += w * (own + np.array([d[1] ** 2 + d[2] ** 2, d[0] ** 2 + d[2] ** 2, d[0] ** 2 + d[1] ** 2]))
    return com, float(body.mass) * moments
