"""Kept for imports from before issue 26: the container's planner is
``planner.container.planner``, the block-world search ``planner.blocks.trips``."""
from planner.blocks.trips import (DEFAULT_TIME_LIMIT_S, MAX_SCALE, Problem, Search, Weights,  # noqa: F401
                                  _optimise, _Problem, _weights, optimise, weights_for)
from planner.container.planner import ENCODING, _problem, plan, satisficing  # noqa: F401
from planner.task_model import *  # noqa: F401,F403
from planner.task_model import (DEFAULT_CLASS, DEFAULT_COSTS, TRANSITION_FIELDS, Plan,  # noqa: F401
                                PlanningError, expected_utility, optimistic_transition)
