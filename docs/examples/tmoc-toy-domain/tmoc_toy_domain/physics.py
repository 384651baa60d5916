"""The physics half: scene, Y, Y^-1, measurements and the prior over L.

This example builds on the container domain's scene code and changes its data: four
blocks, a tray that travels 0.45 m instead of 0.6 m, a gentler push. A new scene would
subclass sim_workers.base.PhysicsDomain (the protocol: abstract members required, the rest
defaulted) and declare its own scene as data; everything else in the service stays as it
is.
"""
from __future__ import annotations

from sim_workers.container import ContainerDomain
from sim_workers.container.spec import ContainerSpec

TOY_SPEC = ContainerSpec(n_blocks=4, container_goal=(0.45, 0.0), delivered_x=0.8,
                         push_speed=0.40, push_accel=6.0)


class ToyTrayPhysics(ContainerDomain):
    name = "toy_tray"

    def __init__(self, spec: ContainerSpec | None = None, **overrides) -> None:
        super().__init__(spec or TOY_SPEC, **overrides)
