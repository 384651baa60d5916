"""The stack-and-push domain's task half (``planner.domain.TaskDomain``): T's contexts
(tower height before a stack, tower height pushed), the utility terms and the clingo
planner (``planner/asp/stack_and_push.lp`` on ``planner.blocks.trips``' weights and
multi-shot driver). Its symbolic model (atoms, actions, checked states, the tower) is
``planner.stack_and_push.symbolic``; its names are imported here, as before the split.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from planner.blocks import model as tm, trips as tp
from planner.domain import DENSITY_BOUNDS, Context, TaskDomain, UnknownAction
from planner.stack_and_push.symbolic import (GOAL, PICKUP_PLACES, PLACES, ROBOT, START,  # noqa: F401
                                             TOWER, apply, block_index, blocks, check_action,
                                             held_block, initial_state, is_goal, parse_state,
                                             parse_term, tower)
from planner.blocks.model import Plan, PlanningError

ENCODING = Path(__file__).resolve().parents[1] / "asp" / "stack_and_push.lp"


# --------------------------------------------------------------------------- contexts

def context_of(state: frozenset[str], action: str) -> Context:
    """pickup -> ("pickup", 0); stack -> ("stack", tower height before it, 0..N-1);
    push -> ("push", tower height pushed, 1..N). An unknown action, or a push with no
    tower, raises UnknownAction: every action of this domain is learned."""
    name, _ = check_action(action)
    if name == "pickup":
        return ("pickup", 0)
    h = len(tower(state))
    if name == "push" and h == 0:
        raise UnknownAction(f"action {action!r}: no tower to push (no context)")
    return (name, h)


# --------------------------------------------------------------------------- utility

def _action_value(name: str, args: tuple[str, ...], state: frozenset[str],
                  model: tm.Model, classes: Mapping[str, str]) -> tuple[float, int | None]:
    c = model.costs
    if name == "pickup":
        p = model.p_pickup[classes[args[1]]]
        return -tm.attempt_cost(c["pickup"], c["fail"], p), None
    h = len(tower(state))
    if name == "stack":
        p = float(model.p_stack[h])
        return -tm.attempt_cost(c["stack"], c["fail"], p), None
    if not h:
        return -c["push"], 0
    redo = float(tm.redo_costs(model, classes, 0.0)[h])     # a toppled tower is rebuilt; no return push
    return tm.push_value(c, float(model.p_push[h - 1]), h, redo), h


def _evaluate(state: frozenset[str], actions: Sequence[str], model: tm.Model,
              classes: Mapping[str, str]) -> tuple[float, tuple[int, ...], frozenset[str]]:
    return tm.simulate_plan(state, actions, check_action, apply,
                            lambda name, args, now: _action_value(name, args, now, model, classes))


def _checked_state(state: Iterable[str]) -> frozenset[str]:
    if isinstance(state, str):
        raise PlanningError("state: expected an iterable of atoms, got a string")
    try:
        return parse_state(list(state))
    except ValueError as exc:
        raise PlanningError(str(exc)) from None


def _model(start: frozenset[str], transition: Mapping, costs: Mapping | None,
           block_classes: Mapping[str, str] | None) -> tuple[dict, tm.Model]:
    names = blocks(start)
    classes = tm.classes_of(names, block_classes)
    return classes, tm.validate_transition(transition, len(names), set(classes.values()), costs)


def expected_utility(state: Iterable[str], actions: Sequence[str], transition: Mapping,
                     costs: Mapping | None = None, *,
                     block_classes: Mapping[str, str] | None = None) -> float:
    """The expected utility of the actions from the state, by simulating them."""
    start = _checked_state(state)
    classes, model = _model(start, transition, costs, block_classes)
    return _evaluate(start, list(actions), model, classes)[0]


# --------------------------------------------------------------------------- planning

def _problem(state: frozenset[str], first: Sequence[str] = ()) -> tp.Problem:
    place = {}
    for atom in state:
        if atom.startswith("is_in("):
            _, (b, where) = parse_term(atom)
            if where in PICKUP_PLACES:
                place[b] = where
    # Blocks off their supply slot first, those on the rail before all (a push would sweep
    # them: no push until they are picked, ``clear_first``), of those the ones resting on
    # others (`first`: a block under one cannot be taken while it is there), then by index.
    on_others = frozenset(first)
    order = sorted(place, key=lambda b: (place[b] != "rail", place[b] == "init", b not in on_others,
                                         block_index(b)))
    on_rail = sum(1 for b in place if place[b] == "rail")
    return tp.Problem(tuple(order), place, held_block(state), len(tower(state)), False,
                       return_push=False, clear_first=on_rail)


def _name_actions(problem: tp.Problem, steps: Sequence[str]) -> tuple[str, ...]:
    queue, held, out = list(problem.order), problem.held, []
    for step in steps:
        if step == "pick":
            held = queue.pop(0)
            out.append(f"pickup({ROBOT},{held},{problem.place[held]})")
        elif step == "stack":
            out.append(f"stack({ROBOT},{held},{TOWER})")
            held = None
        else:
            out.append(f"push({ROBOT},{TOWER},{START},{GOAL})")
    return tuple(out)


def plan(state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
         block_classes: Mapping[str, str] | None = None, max_steps: int | None = None,
         time_limit: float = tp.DEFAULT_TIME_LIMIT_S, first: Sequence[str] = ()) -> Plan:
    """The plan of maximum expected utility from the state under T (``{pickup, stack[N],
    push[N]}``) and the costs, proven optimal unless the time limit cut the search. `first`:
    blocks resting on others, picked before the other waiting blocks (the physics half's
    ``take_first``)."""
    started = time.perf_counter()
    start = _checked_state(state)
    classes, model = _model(start, transition, costs, block_classes)
    tp.check_limits(max_steps, time_limit)
    problem = _problem(start, first)
    if problem.units == 0:
        return Plan((), (), 0.0, True, (time.perf_counter() - started) * 1e3)
    shortest = problem.horizon(1)
    if max_steps is not None and max_steps < shortest:
        raise PlanningError(f"goal unreachable within max_steps={max_steps}: the shortest "
                            f"plan from this state has {shortest} actions")
    last_trips = problem.max_trips
    if max_steps is not None:
        last_trips = min(last_trips, max_steps - shortest + 1)
    search = tp.search(problem, model, classes, last_trips, started + float(time_limit), ENCODING)
    actions = _name_actions(problem, search.best_steps)
    value, loads, final = _evaluate(start, actions, model, classes)
    if not is_goal(final):
        raise RuntimeError(f"internal error: planned actions do not reach the goal: {actions}")
    return Plan(actions, loads, value, search.proven, (time.perf_counter() - started) * 1e3)


def _random_actions(problem: tp.Problem, rng: np.random.Generator) -> tuple[str, ...]:
    """A uniformly random waste-free plan: the waiting blocks in random order, each gap
    between consecutive stacks ending a trip (a push) with probability 1/2."""
    order = [problem.order[i] for i in rng.permutation(len(problem.order))]
    units = ([problem.held] if problem.held is not None else []) + order
    push = f"push({ROBOT},{TOWER},{START},{GOAL})"
    early = problem.load0 > 0 and problem.held is None and bool(units)
    cuts = rng.random(max(len(units) - 1 + early, 0)) < 0.5
    actions = []
    if early and cuts[0]:
        actions.append(push)
    cuts = cuts[int(early):]
    for i, b in enumerate(units):
        if b != problem.held:
            actions.append(f"pickup({ROBOT},{b},{problem.place[b]})")
        actions.append(f"stack({ROBOT},{b},{TOWER})")
        if i < len(units) - 1 and cuts[i]:
            actions.append(push)
    return tuple(actions + [push]) if units or problem.load0 else ()


def satisficing(state: Iterable[str], *, rng: np.random.Generator,
                transition: Mapping | None = None, costs: Mapping | None = None,
                block_classes: Mapping[str, str] | None = None) -> Plan:
    """The GP baseline: a uniformly random valid plan drawn from ``rng``."""
    started = time.perf_counter()
    if not isinstance(rng, np.random.Generator):
        raise PlanningError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    start = _checked_state(state)
    n = len(blocks(start))
    classes, model = _model(start, transition or tm.optimistic_transition(n), costs, block_classes)
    actions = _random_actions(_problem(start), rng)
    value, loads, _ = _evaluate(start, actions, model, classes)
    return Plan(actions, loads, value, False, (time.perf_counter() - started) * 1e3)


# --------------------------------------------------------------------------- the protocol

class StackAndPushTask(TaskDomain):
    """Blocks stacked into a tower and pushed along a rail to the goal: pickup 15, stack 10,
    push 30, fail 50, +40 per block delivered, +80 once all are; no return push."""

    name = "stack_and_push"
    action_names = ("pickup", "stack", "push")
    default_costs = dict(tm.DEFAULT_COSTS)
    transition_extras = ("trials",)       # ties between equal plans broken by evidence
    # What a task or session request may set over HTTP (api.schemas builds the domain's
    # request model from these): each option valid on its own, whatever the others say.
    # The bounds are the physics half's (sim_workers.stack_and_push: MIN_FORCE_SIGMA).
    http_options = {
        "unknown_density": {"type": bool, "description": "L = (size, density): learn the blocks' "
                                                         "density from the wrist force"},
        "force_sigma": {"type": float, "ge": 0.001, "le": 100.0,
                        "description": "noise of the held-weight channel (N; 0.1 an external F/T "
                                       "sensor, 3.5 a UR5e's built-in one)"},
        "force_from_mass": {"type": bool, "description": "size the grip force and the push's force "
                                                         "limit from the believed mass (default: "
                                                         "when the density is unknown)"},
    }
    http_truth = {"density": {"type": float, **DENSITY_BOUNDS, "description": "the blocks' density (kg/m^3)"}}

    def initial_state(self, n_blocks: int) -> frozenset[str]:
        return initial_state(n_blocks)

    def parse_state(self, atoms: Iterable[str]) -> frozenset[str]:
        return parse_state(atoms)

    def blocks(self, state: frozenset[str]) -> list[str]:
        return blocks(state)

    def apply(self, state: frozenset[str], action: str) -> frozenset[str]:
        return apply(state, action)

    def is_goal(self, state: frozenset[str]) -> bool:
        return is_goal(state)

    def contexts(self, n_blocks: int) -> tuple[Context, ...]:
        n = int(n_blocks)
        return (("pickup", 0),) + tuple(("stack", h) for h in range(n)) \
            + tuple(("push", h) for h in range(1, n + 1))

    def grounded_actions(self, n_blocks: int) -> tuple[str, ...]:
        bs = [f"b{i}" for i in range(1, int(n_blocks) + 1)]
        return tuple(f"pickup(r,{b},{p})" for b in bs for p in PICKUP_PLACES) \
            + tuple(f"stack(r,{b},tower)" for b in bs) + ("push(r,tower,start,goal)",)

    def atoms(self, n_blocks: int) -> tuple[str, ...]:
        bs = [f"b{i}" for i in range(1, int(n_blocks) + 1)]
        return tuple(f"is_in({b},{p})" for b in bs for p in PLACES) \
            + tuple(f"is_holding(r,{b})" for b in bs) + ("hand_empty(r)",) \
            + tuple(f"on({b},start)" for b in bs) + tuple(f"on({b},{b2})" for b in bs for b2 in bs if b2 != b)

    def context_of(self, state: frozenset[str], action: str) -> Context:
        return context_of(state, action)

    def optimistic_transition(self, n_blocks: int) -> dict:
        return tm.optimistic_transition(n_blocks)

    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             block_classes: Mapping[str, str] | None = None, max_steps: int | None = None,
             time_limit: float = tp.DEFAULT_TIME_LIMIT_S, first: Sequence[str] = ()) -> Plan:
        return plan(state, transition, costs, block_classes=block_classes,
                    max_steps=max_steps, time_limit=time_limit, first=first)

    def satisficing(self, state: Iterable[str], *, rng: np.random.Generator,
                    transition: Mapping | None = None, costs: Mapping | None = None) -> Plan:
        return satisficing(state, rng=rng, transition=transition, costs=costs)

    def expected_utility(self, state: Iterable[str], actions: Sequence[str], transition: Mapping,
                         costs: Mapping | None = None) -> float:
        return expected_utility(state, actions, transition, costs)

    @staticmethod
    def actions_for_loads(n_blocks: int, loads: Sequence[int]) -> list[str]:
        """The plan that pushes towers of `loads` blocks in turn (blocks in order)."""
        actions, b = [], 1
        for k in loads:
            for _ in range(int(k)):
                actions += [f"pickup({ROBOT},b{b},init)", f"stack({ROBOT},b{b},{TOWER})"]
                b += 1
            actions.append(f"push({ROBOT},{TOWER},{START},{GOAL})")
        return actions

    def step_reward(self, state: frozenset[str], action: str, next_state: frozenset[str],
                    costs: Mapping[str, float]) -> tuple[float, dict]:
        """+deliver per block newly at goal, +all_delivered when the goal is reached;
        metrics `delivered` and `load` (the tower height on a push, else None)."""
        load = len(tower(state)) if action.replace(" ", "").startswith("push(") else None
        at_goal = lambda st: sum(a.startswith("is_in(") and a.endswith(f",{GOAL})") for a in st)  # noqa: E731
        gained = at_goal(next_state) - at_goal(state)
        reward = costs["deliver"] * gained + (costs["all_delivered"] if is_goal(next_state) else 0.0)
        return reward, {"delivered": gained, "load": load}


TASK = StackAndPushTask()
