"""planner package of the TMOC service: the task half of each domain (``planner.<domain>``,
on the protocol ``planner.domain.TaskDomain``), the block-world toolkit (``planner.blocks``)
and the motion planner (``planner.motion``)."""
from planner.blocks.model import Plan, PlanningError, optimistic_transition
from planner.container.model import expected_utility
from planner.container.planner import plan, satisficing

__all__ = ["Plan", "PlanningError", "expected_utility", "optimistic_transition", "plan",
           "satisficing"]
