"""The "real world" of a task behind one interface.

`SimulatedReality` is a grounded world with hidden true properties and a configurable
reality gap (friction and placement jitter); an external robot implements the same
`Reality` protocol (the HTTP service wires it to a robot that posts observations).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim_workers.configuration import Configuration, quat_from_yaw
from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld


@dataclass(frozen=True)
class Observation:
    """What the real world reports after an action."""

    configuration: Configuration
    state: frozenset[str]
    measurements: np.ndarray


class Reality(Protocol):
    def start_episode(self, rng: np.random.Generator) -> Observation: ...
    def execute(self, trajectory: np.ndarray, action: str) -> Observation: ...


@dataclass(frozen=True)
class RealityGap:
    friction: float = 0.10       # relative, uniform, redrawn each episode
    placement_m: float = 0.002   # std of initial block placement
    yaw_rad: float = 0.05


class SimulatedReality:
    """A grounded world holding the hidden truth, perturbed per episode by the reality gap."""

    def __init__(self, domain_name: str, domain_options: dict, true_properties: dict,
                 gap: RealityGap = RealityGap()) -> None:
        self.domain_name = domain_name
        self.options = dict(domain_options)
        self.truth = true_properties
        self.gap = gap
        self.world: GroundedWorld | None = None

    def start_episode(self, rng: np.random.Generator) -> Observation:
        base = load(self.domain_name, **self.options)
        mus = {f.name: getattr(base.spec, f.name) * rng.uniform(1 - self.gap.friction, 1 + self.gap.friction)
               for f in dataclasses.fields(base.spec) if f.name.startswith("mu_")}
        domain = load(self.domain_name, **self.options, **mus)
        if self.world is not None:
            self.world.close()
        self.world = GroundedWorld(domain)
        config = domain.initial_configuration(self.truth)
        objects = config.objects.copy()
        for i in range(1, len(objects)):      # row 0 is the container: it stays put
            objects[i, :2] += np.clip(rng.normal(0, self.gap.placement_m, 2),
                                      -2 * self.gap.placement_m, 2 * self.gap.placement_m)
            objects[i, 3:] = quat_from_yaw(rng.uniform(-self.gap.yaw_rad, self.gap.yaw_rad))
        placed = self.world.reset(Configuration(config.robot, objects), self.truth)
        return Observation(placed, domain.symbolic_state(placed), domain.measurements(placed))

    def execute(self, trajectory: np.ndarray, action: str) -> Observation:
        out = self.world.execute(trajectory, action)
        return Observation(out.configuration, out.state, out.measurements)

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None
