"""The robots as the service shows them (the registry itself is ``sim_workers.robots``):
their names and JSON-ready descriptions, for `tmoc robots` and GET /v1/robots."""
from __future__ import annotations

import math

from sim_workers.robots import RobotError, broken, names, robot

from .domains import options_of

__all__ = ["RobotError", "broken", "describe", "fits", "names", "names_for", "options_for", "robot"]


def fits(name: str, physics) -> bool:
    """Whether robot `name` can work in a domain's scene: an arm stands where the domain
    declares (``robot_base``); the floating gripper needs nothing."""
    return robot(name).kind != "arm" or getattr(physics, "robot_base", None) is not None


def options_for(name: str, physics, options: dict) -> dict:
    """A domain's `options` as robot `name` runs it: a domain that can push with the open
    front finger (``push_open``) does so for an arm, whose wrist then clears the tower or the
    tray (docs/SERVICE.md), unless the options say otherwise."""
    if robot(name).kind == "arm" and "push_open" in options_of(physics) and "push_open" not in options:
        return {**options, "push_open": True}
    return dict(options)


def names_for(physics) -> list[str]:
    """The registered robots that can work in the scene of `physics` (a domain's physics half)."""
    return [n for n in names() if fits(n, physics)]


def _jsonable(x):
    """An unbounded limit as None (JSON has no infinity)."""
    if isinstance(x, float) and math.isinf(x):
        return None
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_jsonable(v) for v in x]
    return x


def describe(name: str) -> dict:
    """One robot: its joints (limits; None: unbounded or unpublished) and, for an arm, its
    Denavit-Hartenberg parameters, base pose, flange-to-tool transform and home joints."""
    return _jsonable(robot(name).describe())
