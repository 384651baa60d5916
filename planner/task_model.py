"""Kept for imports from before issue 26: the block-world trip model is
``planner.blocks.model``, the container's expected utility ``planner.container.model``."""
from planner.blocks.model import *  # noqa: F401,F403
from planner.blocks.model import (DEFAULT_CLASS, DEFAULT_COSTS, TRANSITION_FIELDS, Model,  # noqa: F401
                                  P_ATTEMPT_FLOOR, Plan, PlanningError, _block_classes, _is_number,
                                  _Model, _validate_transition, attempt_cost, classes_of,
                                  optimistic_transition, push_value, redo_costs, simulate_plan)
from planner.container.model import _checked_state, _evaluate, expected_utility  # noqa: F401
