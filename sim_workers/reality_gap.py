"""The reality gap: how a "real" world differs from the one Y plans in (one place for it).

Friction is scaled per world by U(1 +- friction); objects are placed with N(0, placement)
clipped at 2 std and turned by U(+-yaw); a domain's ``execution_jitter`` makes the real
arm run an action kind U(1 +- jitter) times faster or slower than planned (``executed``). The
probe's trials and the coordinator's simulated reality
(``coordinator.loop.reality.SimulatedReality``) both draw from here, so the gap a probe
measures is the gap the loop meets.

What the simulated reality *reports* is noisy too (``SensorNoise``, issue 37): each weighed
measurement channel gets noise of its declared sigma (``noisy_readings``) and the perceived
planar positions of the movable objects N(0, perception) (``perceived_planar``); the world
itself goes on from the true state.
"""
from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import ClassVar, Iterator

import numpy as np

from .configuration import Configuration, quat_from_yaw
from .domains import load

PLACEMENT_JITTER_M = 0.002   # std of block placement, clipped at 2 std
YAW_JITTER_RAD = 0.05
FRICTION_JITTER = 0.10       # relative, uniform
PERCEPTION_SIGMA_M = 0.002   # std of a perceived planar object position (per axis)
SENSOR_TAILS = ("gaussian", "student_t")
STUDENT_T_DOF = 3            # heavy tails: Student-t with 3 degrees of freedom (variance 3)


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


@dataclass(frozen=True)
class SensorNoise:
    """What a simulated reality's sensors add to the simulator's exact readings (issue 37).

    Each measurement channel with a declared sigma (``measurement_channels()``) reads
    ``exact + sigma * (bias + scale * e)``, e of unit std: standard normal, or with
    ``tails="student_t"`` a Student-t with 3 degrees of freedom divided by sqrt(3) (the same
    std, heavier tails). The perceived planar positions (x, y) of the domain's movable
    objects get N(0, perception_m^2) per axis. ``SensorNoise.NONE`` (scale 0, bias 0,
    perception 0) reports the exact readings of before, drawing nothing.

    >>> SensorNoise.NONE.exact, SensorNoise().exact
    (True, False)
    """

    scale: float = 1.0              # the std, in multiples of each channel's declared sigma
    bias: float = 0.0               # a constant offset, in declared sigmas
    tails: str = "gaussian"         # or "student_t"
    perception_m: float = PERCEPTION_SIGMA_M

    NONE: ClassVar["SensorNoise"]

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale >= 0):
            raise ValueError(f"scale: {self.scale} must be >= 0")
        if not np.isfinite(self.bias):
            raise ValueError(f"bias: {self.bias} must be finite")
        if self.tails not in SENSOR_TAILS:
            raise ValueError(f"tails: {self.tails!r} is not one of {', '.join(SENSOR_TAILS)}")
        if not (np.isfinite(self.perception_m) and self.perception_m >= 0):
            raise ValueError(f"perception_m: {self.perception_m} must be >= 0")

    @property
    def measures_exactly(self) -> bool:
        """Whether the weighed channels read exactly (no draw)."""
        return self.scale == 0 and self.bias == 0

    @property
    def perceives_exactly(self) -> bool:
        """Whether object positions are perceived exactly (no draw)."""
        return self.perception_m == 0

    @property
    def exact(self) -> bool:
        return self.measures_exactly and self.perceives_exactly


SensorNoise.NONE = SensorNoise(scale=0.0, bias=0.0, tails="gaussian", perception_m=0.0)


def unit_noise(rng: np.random.Generator, n: int, tails: str = "gaussian") -> np.ndarray:
    """`n` draws of zero mean and unit std: standard normal, or ("student_t") Student-t with
    3 degrees of freedom over sqrt(3)."""
    if tails == "gaussian":
        return rng.standard_normal(n)
    if tails == "student_t":
        return rng.standard_t(STUDENT_T_DOF, n) / np.sqrt(STUDENT_T_DOF / (STUDENT_T_DOF - 2))
    raise ValueError(f"tails: {tails!r} is not one of {', '.join(SENSOR_TAILS)}")


def noisy_readings(rng: np.random.Generator, values, sigmas, noise: SensorNoise) -> np.ndarray:
    """`values` as noisy sensors read them: each plus sigma * (bias + scale * e) with its own
    `sigmas` entry (``SensorNoise``). A NaN (a channel that did not measure) stays NaN; one
    draw per channel all the same, so the stream does not depend on which channels
    measured. With ``noise.measures_exactly``: the values, without a draw."""
    values = np.array(values, dtype=np.float64, copy=True).reshape(-1)
    if noise.measures_exactly or values.size == 0:
        return values
    sigmas = np.broadcast_to(np.asarray(sigmas, dtype=np.float64), values.shape)
    e = unit_noise(rng, values.size, noise.tails)
    return values + sigmas * (noise.bias + noise.scale * e)


def perceived_planar(rng: np.random.Generator, objects: np.ndarray, rows,
                     perception_m: float = PERCEPTION_SIGMA_M) -> np.ndarray:
    """`objects` as a camera perceives them: the planar position (x, y) of each of `rows`
    plus N(0, perception_m^2) per axis (heights and orientations as they are). With 0: a
    copy, without a draw."""
    objects = np.array(objects, dtype=np.float64, copy=True)
    rows = list(rows)
    if perception_m > 0 and rows:
        objects[rows, :2] += rng.normal(0.0, perception_m, (len(rows), 2))
    return objects


# A probe trial's perception (``trial_perception``): the std and the trial's own generator.
_PERCEPTION: ContextVar[tuple[float, np.random.Generator] | None] = ContextVar("tmoc_trial_perception",
                                                                               default=None)


@contextmanager
def trial_perception(perception_m: float, rng: np.random.Generator) -> Iterator[None]:
    """Within it, an action a probe trial runs (``grounded_world.act``) is planned, as the
    loop's robot plans it, from a perceived configuration: each movable object's planar
    position plus N(0, perception_m^2) per axis, drawn from `rng` afresh for each action
    (each observation of a real robot is perceived anew). The world acts in the truth."""
    token = _PERCEPTION.set((float(perception_m), rng) if perception_m > 0 else None)
    try:
        yield
    finally:
        _PERCEPTION.reset(token)


def as_perceived(domain, config: Configuration) -> Configuration:
    """`config` as the current probe trial's robot perceives it (``trial_perception``);
    `config` itself outside one or with a perception of 0."""
    current = _PERCEPTION.get()
    if current is None:
        return config
    perception_m, rng = current
    return Configuration(config.robot.copy(),
                         perceived_planar(rng, config.objects, domain.jittered_objects, perception_m))
