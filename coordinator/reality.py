"""The "real world" of a task behind one interface.

`SimulatedReality` is a grounded world with hidden true properties and a configurable
reality gap (friction and placement jitter); an external robot implements the same
`Reality` protocol (the HTTP service wires it to a robot that posts observations).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sim_workers.configuration import Configuration
from sim_workers.grounded_world import GroundedWorld
from sim_workers.reality_gap import RealityGap, jitter_planar, jittered_domain


@dataclass(frozen=True)
class Observation:
    """What the real world reports after an action."""

    configuration: Configuration
    state: frozenset[str]
    measurements: np.ndarray


class Reality(Protocol):
    def start_episode(self, rng: np.random.Generator) -> Observation: ...
    def execute(self, trajectory: np.ndarray, action: str) -> Observation: ...


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
        domain = jittered_domain(rng, self.gap.friction, domain=self.domain_name, **self.options)
        if self.world is not None:
            self.world.close()
        self.world = GroundedWorld(domain)
        config = domain.initial_configuration(self.truth)
        # Row 0 is the container: it stays put; the blocks are placed with jitter.
        objects = jitter_planar(rng, config.objects, range(1, len(config.objects)),
                                self.gap.placement_m, self.gap.yaw_rad)
        placed = self.world.reset(Configuration(config.robot, objects), self.truth)
        return Observation(placed, domain.symbolic_state(placed), domain.measurements(placed))

    def execute(self, trajectory: np.ndarray, action: str) -> Observation:
        out = self.world.execute(trajectory, action)
        return Observation(out.configuration, out.state, out.measurements)

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None
