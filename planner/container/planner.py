"""The container's task planner: the plan of maximum expected utility under T, and the GP
baseline's random satisficing plan, on ``planner/asp/container.lp`` and the block-world
search (``planner.blocks.trips``).

The encoding counts interchangeable blocks; this module states the problem from a
symbolic state, names the blocks in the solver's answer and recomputes the expected
utility exactly (``planner.container.model``).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from planner.blocks.model import Plan, PlanningError, classes_of, validate_transition
from planner.blocks.trips import DEFAULT_TIME_LIMIT_S, Problem, check_limits, search
from planner.container import symbolic
from planner.container.model import _checked_state, _evaluate, optimistic_transition

ENCODING = Path(__file__).resolve().parents[1] / "asp" / "container.lp"


def _problem(state: frozenset[str]) -> Problem:
    place = {}
    load0 = 0
    for block in symbolic.blocks(state):
        if f"at_container({block},{symbolic.CONTAINER})" in state:
            load0 += 1
        for where in symbolic.PICKUP_PLACES:
            if f"is_in({block},{where})" in state:
                place[block] = where
    order = sorted(place, key=lambda b: (place[b] != "table", symbolic.block_index(b)))
    held = symbolic.held_block(state)
    at_goal = symbolic.container_place(state) == "goal"
    if held is not None and at_goal:
        raise PlanningError(f"goal unreachable: {symbolic.ROBOT} holds {held} while "
                            f"{symbolic.CONTAINER} is at goal; stacking needs the container "
                            f"at init and pushing needs an empty hand")
    return Problem(tuple(order), place, held, load0, at_goal)


def _name_actions(problem: Problem, steps: Sequence[str]) -> tuple[str, ...]:
    """Turn the solver's count-level actions into named actions: the pickups take the
    blocks of problem.order in turn (seq/2 fixed their classes in that order)."""
    r, c = symbolic.ROBOT, symbolic.CONTAINER
    queue = list(problem.order)
    held = problem.held
    actions = []
    for name in steps:
        if name == "pick":
            held = queue.pop(0)
            actions.append(f"pickup({r},{held},{problem.place[held]})")
        elif name == "stack":
            actions.append(f"stack({r},{held},{c})")
            held = None
        elif name == "push_goal":
            actions.append(f"push({r},{c},init,goal)")
        else:
            actions.append(f"push({r},{c},goal,init)")
    return tuple(actions)


def plan(state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
         block_classes: Mapping[str, str] | None = None, max_steps: int | None = None,
         time_limit: float = DEFAULT_TIME_LIMIT_S) -> Plan:
    """The plan of maximum expected utility from the state under T and the costs.

    Horizon and stopping rule. The encoding keeps only waste-free plans (no empty round
    trips: with costs >= 0 they never pay), so a plan with m trips has exactly
    ``horizon(m)`` actions and m <= ``max_trips``; horizon h holds every plan of at most h
    actions (noop after the goal). We solve at the one-trip horizon, then extend the
    horizon by one trip at a time, each solve looking only for plans strictly better than
    the best so far (clingo's opt bound). Every step weight is >= 0 after the rewriting in
    ``_trip_weights``, so a plan with m trips costs at least the constant plus its return
    pushes (``_lower_bound``), which grows with m: once it reaches the best cost, no longer
    plan can be better and the search stops. Optimality is proven when every solve was
    exhausted. ``max_steps`` caps the horizon (optimal then means: among plans of at most
    max_steps actions); ``time_limit`` (seconds) caps the search, which then returns the
    best plan found with ``optimal=False``.

    Blocks are named afterwards: the pickups take the waiting blocks in the order table
    first, then init, lowest index first.
    """
    started = time.perf_counter()
    start = _checked_state(state)
    blocks = symbolic.blocks(start)
    classes = classes_of(blocks, block_classes)
    model = validate_transition(transition, len(blocks), set(classes.values()), costs)
    check_limits(max_steps, time_limit)
    problem = _problem(start)
    if problem.units == 0:
        return Plan((), (), 0.0, True, (time.perf_counter() - started) * 1e3)
    shortest = problem.horizon(1)
    if max_steps is not None and max_steps < shortest:
        raise PlanningError(f"goal unreachable within max_steps={max_steps}: the shortest "
                            f"plan from this state has {shortest} actions")
    last_trips = problem.max_trips
    if max_steps is not None:
        last_trips = min(last_trips, (max_steps - shortest) // 2 + 1)

    found = search(problem, model, classes, last_trips, started + float(time_limit), ENCODING)
    actions = _name_actions(problem, found.best_steps)
    value, loads, final = _evaluate(start, actions, model, classes)
    if not symbolic.is_goal(final):       # the encoding and symbolic.py disagree: a bug
        raise RuntimeError(f"internal error: planned actions do not reach the goal: {actions}")
    return Plan(actions, loads, value, found.proven, (time.perf_counter() - started) * 1e3)


# --------------------------------------------------------------------------- GP baseline

def _random_actions(problem: Problem, rng: np.random.Generator) -> tuple[str, ...]:
    """A uniformly random waste-free plan: the waiting blocks in a uniformly random order,
    and each gap between consecutive stacks (plus, with a loaded container and an empty
    hand, the gap before the first stack) ending a trip with probability 1/2, which makes
    every split of the stacking sequence into trips (every composition) equally likely."""
    r, c = symbolic.ROBOT, symbolic.CONTAINER
    order = [problem.order[i] for i in rng.permutation(len(problem.order))]
    units = ([problem.held] if problem.held is not None else []) + order
    early_push = problem.load0 > 0 and problem.held is None and bool(units)
    cuts = rng.random(len(units) - 1 + early_push) < 0.5 if units else np.zeros(0, bool)
    actions = [f"push({r},{c},goal,init)"] if problem.at_goal else []
    trip_done = f"push({r},{c},init,goal)"
    if early_push and cuts[0]:
        actions += [trip_done, f"push({r},{c},goal,init)"]
    cuts = cuts[int(early_push):]
    for i, block in enumerate(units):
        if block != problem.held:
            actions.append(f"pickup({r},{block},{problem.place[block]})")
        actions.append(f"stack({r},{block},{c})")
        if i < len(units) - 1 and cuts[i]:
            actions += [trip_done, f"push({r},{c},goal,init)"]
    return tuple(actions + [trip_done])


def satisficing(state: Iterable[str], *, rng: np.random.Generator,
                transition: Mapping | None = None, costs: Mapping | None = None,
                block_classes: Mapping[str, str] | None = None) -> Plan:
    """The GP baseline: a uniformly random valid plan (see ``_random_actions`` for what
    "uniform" ranges over), drawn from ``rng`` and so deterministic for its state. Its
    expected utility is reported under ``transition`` (optimistic T if None)."""
    started = time.perf_counter()
    if not isinstance(rng, np.random.Generator):
        raise PlanningError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    start = _checked_state(state)
    blocks = symbolic.blocks(start)
    classes = classes_of(blocks, block_classes)
    if transition is None:
        transition = optimistic_transition(len(blocks))
    model = validate_transition(transition, len(blocks), set(classes.values()), costs)
    problem = _problem(start)
    actions = _random_actions(problem, rng) if problem.units else ()
    value, loads, _ = _evaluate(start, actions, model, classes)
    return Plan(actions, loads, value, False, (time.perf_counter() - started) * 1e3)
