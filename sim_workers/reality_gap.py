"""The reality gap: how a "real" world differs from the one Y plans in (one place for it).

Friction is scaled per world by U(1 +- friction); objects are placed with N(0, placement)
clipped at 2 std and turned by U(+-yaw); a domain's ``execution_jitter`` makes the real
arm run an action kind U(1 +- jitter) times faster or slower than planned (``executed``). The
probe's trials and the coordinator's simulated reality
(``coordinator.reality.SimulatedReality``) both draw from here, so the gap a probe
measures is the gap the loop meets.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .configuration import quat_from_yaw
from .domains import load

PLACEMENT_JITTER_M = 0.002   # std of block placement, clipped at 2 std
YAW_JITTER_RAD = 0.05
FRICTION_JITTER = 0.10       # relative, uniform


@dataclass(frozen=True)
class RealityGap:
    """The jitter of one reality: friction (relative), placement std (m), yaw (rad)."""

    friction: float = FRICTION_JITTER       # redrawn each episode
    placement_m: float = PLACEMENT_JITTER_M
    yaw_rad: float = YAW_JITTER_RAD


def jittered_domain(rng: np.random.Generator, friction: float = FRICTION_JITTER, *,
                    domain: str, **options):
    """`domain` with every friction coefficient (spec fields mu_*) scaled by U(1 +- friction)."""
    base = load(domain, **options)
    mus = {f.name: getattr(base.spec, f.name) * rng.uniform(1 - friction, 1 + friction)
           for f in dataclasses.fields(base.spec) if f.name.startswith("mu_")}
    return load(domain, **{**options, **mus})


def jitter_planar(rng: np.random.Generator, objects: np.ndarray, rows,
                  placement_m: float = PLACEMENT_JITTER_M, yaw_rad: float = YAW_JITTER_RAD) -> np.ndarray:
    """Objects `rows` moved by N(0, placement) clipped at 2 std, and turned by U(+-yaw)."""
    objects = objects.copy()
    for i in rows:
        objects[i, :2] += np.clip(rng.normal(0, placement_m, 2), -2 * placement_m, 2 * placement_m)
        objects[i, 3:] = quat_from_yaw(rng.uniform(-yaw_rad, yaw_rad))
    return objects


def action_jitter(domain, action: str) -> float:
    """The real arm's relative timing jitter for `action` (its kind's entry in the domain's
    ``execution_jitter``; 0: run as commanded)."""
    return float(domain.execution_jitter.get(action.partition("(")[0].strip(), 0.0))


def executed(traj: np.ndarray, action: str, rng: np.random.Generator, jitter: float) -> np.ndarray:
    """The trajectory a real arm runs for `action`: its timing scaled by 1/e with e ~
    U(1 +- jitter) (`jitter`: ``action_jitter(domain, action)``), so its speed scales by e
    and its accelerations by e^2; the efforts are commands the wrist meets exactly (a
    force-limited stroke's limit still sets its pace). With jitter 0, unchanged and
    without a draw (runs without the jitter keep their random streams)."""
    if jitter <= 0:
        return traj
    e = float(rng.uniform(1.0 - jitter, 1.0 + jitter))
    out = np.array(traj, dtype=np.float64, copy=True)
    out[:, 0] = out[0, 0] + (out[:, 0] - out[0, 0]) / e
    return out
