"""Who acts in a probe trial: the floating gripper (its tool rows are its commands) or an arm.

A probe trial (``sim_workers.probe``) runs its actions through ``grounded_world.act``. With
an arm set by ``arm_moves(factory)`` around the probe, each trial gets its own arm
(``factory()``, so that no trial's outcome depends on another's) and ``act`` asks it, per
action, for its plan (the rows the arm's tool draws, the action's start on the arm's clock
and the arm's joints, ``ArmMotion``) and then, once the plan is timed as the robot runs it,
for what the arm does with it (``track``): the world moves the arm's links with the
action, as the particle worlds and the simulated arm reality do. The arm's motion is planned outside this
package (``coordinator.loop.arm_trials``: inverse kinematics, joint-space search and
timing), which is why it is handed in as a callable. An action the arm cannot do raises
``ArmRefused``: the trial fails, as a refused action is a failed attempt in the loop.
"""
from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from typing import Callable, Iterator, Protocol

import numpy as np

from .motion import ArmMotion


class ArmRefused(RuntimeError):
    """The arm cannot do the action (no branch reaches it, or no path clears the scene)."""


class TrialArm(Protocol):
    def plan(self, domain, config, believed: dict, action: str, rows: np.ndarray, start: float,
             key: np.ndarray) -> tuple[np.ndarray, float, ArmMotion]:
        """The arm's plan for the action's tool `rows`: (the tool rows it draws, the action's
        start on its clock, its joints over that clock)."""
        ...

    def track(self, domain, believed: dict, rows: np.ndarray, motion: ArmMotion) -> tuple[np.ndarray, ArmMotion]:
        """What the arm does with the plan, as executed (its timing as the robot runs it):
        (the tool rows it draws, the joints it goes through)."""
        ...


_FACTORY: ContextVar[Callable[[], TrialArm] | None] = ContextVar("tmoc_trial_arm_factory", default=None)
_CURRENT: ContextVar[TrialArm | None] = ContextVar("tmoc_trial_arm", default=None)


@contextmanager
def arm_moves(factory: Callable[[], TrialArm] | None) -> Iterator[None]:
    """Within the block, every probe trial's actions are done by a fresh ``factory()`` arm
    (None: the floating gripper, as outside the block)."""
    token = _FACTORY.set(factory)
    try:
        yield
    finally:
        _FACTORY.reset(token)


@contextmanager
def trial_arm() -> Iterator[None]:
    """One trial's own arm, from the factory ``arm_moves`` set (none outside it)."""
    factory = _FACTORY.get()
    token = _CURRENT.set(factory() if factory is not None else None)
    try:
        yield
    finally:
        _CURRENT.reset(token)


def current_arm() -> TrialArm | None:
    """The arm that acts in the running trial, or None for the floating gripper."""
    return _CURRENT.get()


__all__ = ["ArmRefused", "TrialArm", "arm_moves", "current_arm", "trial_arm"]
