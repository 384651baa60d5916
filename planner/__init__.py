"""planner package of the TMOC service."""
from planner.task_planner import (Plan, PlanningError, expected_utility, optimistic_transition,
                                  plan, satisficing)

__all__ = ["Plan", "PlanningError", "expected_utility", "optimistic_transition", "plan",
           "satisficing"]
