"""Mass in Y (issue 14): the efforts a robot chooses from the believed mass.

A robot does not squeeze or shove harder than it must (a delicate object, a tower that
tips when accelerated hard), so it sizes two efforts from what it believes a block
weighs:

- **grip force** (N per finger) on a pickup and while carrying to a stack: enough to
  hold the believed weight through two friction contacts, times ``grip_safety``. Too
  light a belief: the block slips out of the fingers on the lift;
- **push force limit** (N): the stroke's reference speeds up at ``push_accel_ref``, and
  the wrist may exert at most what accelerates the believed tower at ``push_accel`` against
  its believed floor friction (plus the gripper's own inertia, which the robot knows).
  Too light a belief: the limit does not beat the tower's friction and it stalls at the
  start; too heavy: nothing holds the stroke back and the tower is thrown forward at up
  to ``push_accel_ref`` and topples.

Both are the sixth entry of the key pose (Y's output), so a particle filter's pose rule
weighs them like the rest of the pose, and become the trajectory's ``grip_force`` and
``force_limit`` columns.
"""
from __future__ import annotations

import numpy as np

from .. import trajectory as tr
from ..blocks.scene import GRIPPER_MASS
from .spec import StackAndPushSpec

GRAVITY = 9.81
MIN_EFFORT = 0.05     # N: a command the controller can still resolve


def finger_friction(spec: StackAndPushSpec) -> float:
    """Nominal finger-block friction (Bullet multiplies the two bodies' coefficients)."""
    return spec.mu_finger * spec.mu_block


def floor_friction(spec: StackAndPushSpec) -> float:
    """Nominal block-floor friction."""
    return spec.mu_block * spec.mu_table


def grip_force(spec: StackAndPushSpec, mass: float) -> float:
    """Per finger: the believed block's weight over two friction contacts, with margin."""
    return max(MIN_EFFORT, spec.grip_safety * mass * GRAVITY / (2.0 * finger_friction(spec)))


def push_force_limit(spec: StackAndPushSpec, tower_mass: float) -> float:
    """The most the wrist may push with: the gripper's inertia at the stroke's intended
    acceleration plus the believed tower's (inertia and floor friction), with margin."""
    a = spec.push_accel
    tower = tower_mass * (a + floor_friction(spec) * GRAVITY)
    return max(MIN_EFFORT, GRIPPER_MASS * a + spec.push_safety * tower)


def effort(spec: StackAndPushSpec, masses: np.ndarray, action: str, block: int | None,
           chain: list[int]) -> float:
    """The effort entry of Y's key pose: the grip force for a pickup or a stack of `block`,
    the push force limit for a push of the tower `chain` (block indices, bottom first)."""
    if action == "push":
        return push_force_limit(spec, float(np.sum(np.asarray(masses)[chain])) if chain else 0.0)
    return grip_force(spec, float(masses[block]))


def efforts(spec: StackAndPushSpec, masses: np.ndarray, action: str, block: int | None,
            chain: list[int]) -> np.ndarray:
    """`effort` for many hypotheses at once: (N, n_blocks) masses -> (N,), equal bit for
    bit to `effort` row by row."""
    masses = np.asarray(masses, dtype=np.float64)
    if action == "push":
        if not chain:
            return np.full(len(masses), push_force_limit(spec, 0.0))
        # C order: numpy then sums each row as np.sum sums one tower (pairwise, 8 partial
        # sums from 8 blocks on); the F-ordered result of fancy indexing sums column by column.
        tower = np.ascontiguousarray(masses[:, chain]).sum(axis=1)
        a = spec.push_accel
        return np.maximum(MIN_EFFORT, GRIPPER_MASS * a
                          + spec.push_safety * (tower * (a + floor_friction(spec) * GRAVITY)))
    m = masses[:, block]
    return np.maximum(MIN_EFFORT, spec.grip_safety * m * GRAVITY / (2.0 * finger_friction(spec)))


def add_efforts(spec: StackAndPushSpec, traj: np.ndarray, action: str, value: float,
                limited: tuple[float, float] | None = None) -> np.ndarray:
    """`traj` with the effort columns: a pickup or stack grips at `value` throughout; a push
    keeps the scene's grip and is force-limited to `value` over the times `limited`
    (the descent behind the tower and the stroke), the scene's wrist limit elsewhere."""
    if action != "push":
        return tr.with_efforts(traj, value, spec.base_max_force)
    t = traj[:, 0]
    inside = (t >= limited[0]) & (t < limited[1])    # efforts hold from a row on
    return tr.with_efforts(traj, spec.grip_force, np.where(inside, value, spec.base_max_force))
