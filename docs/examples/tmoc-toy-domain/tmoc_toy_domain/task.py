"""The task half: symbolic model, T's contexts, utility terms and the planner.

Same symbols and clingo planner as the container (so same contexts: pickup, stack by pile
height, push by load), with the domain's own utility terms.
"""
from __future__ import annotations

from planner.container import ContainerTask


class ToyTrayTask(ContainerTask):
    name = "toy_tray"
    default_costs = {"pickup": 10.0, "stack": 5.0, "push": 20.0, "fail": 40.0,
                     "deliver": 30.0, "all_delivered": 60.0}
