"""Which bodies an action can touch: the rest are left out of a particle world.

A particle-action's physics is mostly contacts, and a body resting on the table costs
solver work every step although the action never comes near it: measured in
``benchmarks/bench_worlds.py``, a pickup steps at ~125 us with the other seven blocks and
the container present and at ~60 us without them. So before an action a grounded world
removes the bodies outside the action's reach, and watches, while it steps, that nothing
it kept comes near one it removed; if something does, the particle-action is run again in
the full world (``GroundedWorld.execute``), so a left-out body can never change an
outcome by being absent.

The reach (all axis-aligned boxes, world frame):
- the *moving box*: the gripper and every object touching it at the start (a held block),
  as offsets from the tool point, made yaw-invariant (a disc of the largest horizontal
  radius);
- swept along the action's commanded tool points, extended down to the floor (whatever
  is dropped falls down) and grown by ``SWEEP_MARGIN``;
- every object overlapping the swept box is kept, and so is every object touching a kept
  one (a pile in a container, a tower), to a fixed point.

The guard makes the outcome independent of this choice: it trips when the gripper's box,
or a kept object's ball (base position and farthest corner: it holds the body at any
orientation; one position read per body), comes within ``GUARD_MARGIN`` of a left-out box
and nearer than it started by ``APPROACH`` (a resting neighbour that starts that near, and
stays, touches nothing); the action then runs again with every body.
The margins are Bullet's: a pair of shapes gets contact points only once they are within
its contact-breaking threshold (2 cm), and a contact with a positive gap pushes nothing;
``GUARD_MARGIN`` adds the distance a body moving at 1 m/s covers between two checks.
"""
from __future__ import annotations

import math

import numpy as np

CONTACT_THRESHOLD = 0.02     # m, Bullet's default contact-breaking threshold
TOUCH = 0.005                # m: boxes this close count as touching (resting contact)
SWEEP_MARGIN = 0.04          # m, around the swept moving box
GUARD_EVERY = 4              # steps between two checks of the guard
GUARD_MARGIN = CONTACT_THRESHOLD + 0.034   # + 1 m/s x 4 steps of 1/120 s, rounded up
APPROACH = 0.001             # m nearer than at the start: a kept body moved toward one left out


def body_box(body: int, client: int) -> np.ndarray:
    """(6,) lo xyz, hi xyz of a body and all its links."""
    import pybullet as pb     # (the pybullet world's; MuJoCo worlds leave nothing out)

    boxes = [pb.getAABB(body, link, physicsClientId=client)
             for link in range(-1, pb.getNumJoints(body, physicsClientId=client))]
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    return np.concatenate([lo, hi])


def gaps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) largest per-axis gap between boxes (<= 0: the boxes overlap)."""
    a, b = np.atleast_2d(a)[:, None, :], np.atleast_2d(b)[None, :, :]
    return np.max(np.maximum(a[..., :3] - b[..., 3:], b[..., :3] - a[..., 3:]), axis=-1)


def kept_objects(object_boxes: np.ndarray, gripper_box: np.ndarray, tool_point: np.ndarray,
                 path: np.ndarray, widening: float = 0.0, link_boxes: np.ndarray | None = None) -> np.ndarray:
    """Boolean mask over objects: those an action can touch (see the module's docstring).

    object_boxes: (M, 6) at the start; gripper_box: (6,) gripper and fingers at the start;
    tool_point: (3,) the gripper's commanded tool point at the start; path: (T, 3) the
    tool points the action commands from then on; widening: how much wider (m) the
    fingers open later than at the start; link_boxes: (K, 6) an arm's link capsules at
    every step of the action (their motion is commanded, so an object ``SWEEP_MARGIN`` clear
    of every one of them, twice Bullet's contact threshold, is never touched by a link).
    """
    carried = gaps(gripper_box, object_boxes)[0] <= TOUCH
    moving = np.concatenate([gripper_box[None], object_boxes[carried]])
    lo, hi = moving[:, :3].min(axis=0) - tool_point, moving[:, 3:].max(axis=0) - tool_point
    corners = np.array([[x, y] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])])
    radius = float(np.max(np.hypot(corners[:, 0], corners[:, 1]))) + max(widening, 0.0) / 2
    swept = np.concatenate([path.min(axis=0) + [-radius, -radius, lo[2]],
                            path.max(axis=0) + [radius, radius, hi[2]]])
    swept[2] = -np.inf                          # down to the floor: dropped things fall
    keep = (gaps(swept, object_boxes)[0] <= SWEEP_MARGIN) | carried
    if link_boxes is not None and len(link_boxes):
        near = np.concatenate([link_boxes.min(axis=0)[:3], link_boxes.max(axis=0)[3:]])
        maybe = gaps(near, object_boxes)[0] <= SWEEP_MARGIN         # one box first: most are far
        if maybe.any():
            keep[maybe] |= gaps(link_boxes, object_boxes[maybe]).min(axis=0) <= SWEEP_MARGIN
    touching = gaps(object_boxes, object_boxes) <= TOUCH
    while True:                                 # resting contact, to a fixed point
        grown = keep | touching[keep].any(axis=0)
        if (grown == keep).all():
            return keep
        keep = grown


def radii(positions: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """(K,) the distance from each body's base position to its box's farthest corner: a
    ball that holds the body at any orientation."""
    corners = np.stack([boxes[:, :3], boxes[:, 3:]], axis=1) - positions[:, None]
    return np.linalg.norm(np.max(np.abs(corners), axis=1), axis=-1)


class Guard:
    """Watches a world with left-out bodies: trips when a kept object's ball, or the
    gripper's box, came within ``GUARD_MARGIN`` of a left-out box and nearer than it
    started (by ``APPROACH``). One pybullet call per kept object and one per gripper link
    per check, in plain Python: with a handful of boxes numpy's per-call cost was most of
    the time (measured: 6 ms of a 25 ms pickup with numpy every 2 steps)."""

    def __init__(self, client: int, gripper: int, bodies: list[int], radii: np.ndarray,
                 left_out: np.ndarray) -> None:
        import pybullet as pb
        self.client, self.bodies = client, bodies
        self.radii = [float(r) for r in radii]
        self.left_out = [tuple(b) for b in left_out.tolist()]
        self.gripper = [(gripper, link) for link in range(-1, pb.getNumJoints(gripper, physicsClientId=client))]
        self.start = [d - APPROACH for d in self._clearance()]

    def _clearance(self) -> list[float]:
        """The gripper's box gap, then each kept object's ball gap, to the nearest left-out box."""
        import pybullet as pb
        c, out = self.client, []
        aabbs = [pb.getAABB(b, link, physicsClientId=c) for b, link in self.gripper]
        lo = [min(a[0][k] for a in aabbs) for k in range(3)]
        hi = [max(a[1][k] for a in aabbs) for k in range(3)]
        out.append(min(max(b[0] - hi[0], lo[0] - b[3], b[1] - hi[1], lo[1] - b[4], b[2] - hi[2], lo[2] - b[5])
                       for b in self.left_out))
        for body, r in zip(self.bodies, self.radii):
            x, y, z = pb.getBasePositionAndOrientation(body, physicsClientId=c)[0]
            out.append(min(math.sqrt(max(b[0] - x, x - b[3], 0.0) ** 2 + max(b[1] - y, y - b[4], 0.0) ** 2
                                     + max(b[2] - z, z - b[5], 0.0) ** 2) for b in self.left_out) - r)
        return out

    def tripped(self) -> bool:
        return any(d <= GUARD_MARGIN and d < s for d, s in zip(self._clearance(), self.start))
