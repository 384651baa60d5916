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
