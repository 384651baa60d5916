"""The container's expected utility of a plan: its actions simulated on the container's
symbolic model (``planner.container.symbolic``) and valued by the block-world trip model
(``planner.blocks.model``): a pickup or stack at its expected attempts, a push to goal at
``push_value`` with the trip rebuilt after a failure (return push included), the return
push at its cost."""
from __future__ import annotations

from typing import Iterable, Mapping, Sequence

from planner.blocks.model import (DEFAULT_CLASS, DEFAULT_COSTS, TRANSITION_FIELDS,  # noqa: F401
                                  Model, Plan, PlanningError, attempt_cost, classes_of,
                                  is_number, optimistic_transition, push_value, redo_costs,
                                  simulate_plan, validate_transition)
from planner.container import symbolic


def _checked_state(state: Iterable[str]) -> frozenset[str]:
    """The canonical, checked and normalised state, or PlanningError naming the atom."""
    if isinstance(state, str):
        raise PlanningError("state: expected an iterable of atoms, got a string")
    try:
        return symbolic.normalize(symbolic.parse_state(list(state)))
    except ValueError as exc:
        raise PlanningError(str(exc)) from None


def _action_value(name: str, args: tuple[str, ...], state: frozenset[str], model: Model,
                  classes: Mapping[str, str]) -> tuple[float, int | None]:
    """Expected-utility contribution of an action in a state, and the load of a push to goal."""
    costs = model.costs
    if name == "pickup":
        p = model.p_pickup[classes[args[1]]]
        return -attempt_cost(costs["pickup"], costs["fail"], p), None
    loaded = sum(1 for atom in state if atom.startswith("at_container("))
    if name == "stack":
        p = float(model.p_stack[loaded])
        return -attempt_cost(costs["stack"], costs["fail"], p), None
    if args[3] == "init" or loaded == 0:           # return push / empty push: p = 1, no bonus
        return -costs["push"], (0 if args[3] == "goal" else None)
    p = float(model.p_push[loaded - 1])
    redo = float(redo_costs(model, classes, costs["push"])[loaded])
    return push_value(costs, p, loaded, redo), loaded


def _evaluate(state: frozenset[str], actions: Sequence[str], model: Model,
              classes: Mapping[str, str]) -> tuple[float, tuple[int, ...], frozenset[str]]:
    """Simulate the actions: (expected utility, loads of the pushes to goal, final state)."""
    return simulate_plan(state, actions, symbolic.parse_action, symbolic.apply,
                         lambda name, args, now: _action_value(name, args, now, model, classes))


def expected_utility(state: Iterable[str], actions: Sequence[str], transition: Mapping,
                     costs: Mapping | None = None, *,
                     block_classes: Mapping[str, str] | None = None) -> float:
    """The expected utility of the actions from the state under T and the costs, by
    simulating them (PlanningError names the step whose action is not applicable)."""
    start = _checked_state(state)
    blocks = symbolic.blocks(start)
    classes = classes_of(blocks, block_classes)
    model = validate_transition(transition, len(blocks), set(classes.values()), costs)
    return _evaluate(start, list(actions), model, classes)[0]
