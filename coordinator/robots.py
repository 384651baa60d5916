"""The robots as the service shows them (the registry itself is ``sim_workers.robots``):
their names and JSON-ready descriptions, for `tmoc robots` and GET /v1/robots."""
from __future__ import annotations

import math

from sim_workers.robots import RobotError, broken, names, robot

__all__ = ["RobotError", "broken", "describe", "names", "robot"]


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
