"""The stack-and-push domain's task half (``planner.domain.TaskDomain``): the symbolic
model, T's contexts (tower height before a stack, tower height pushed), the utility terms
and the clingo planner (``planner/asp/stack_and_push.lp`` on ``planner.task_planner``'s
weights and multi-shot driver).

Atoms (what Y^-1 in ``sim_workers.stack_and_push`` reads off a configuration):
``is_in(B,init|table|rail|goal)``, ``is_holding(r,B)``, ``hand_empty(r)``, ``on(B,start)``
for the tower's bottom block and ``on(B,B2)`` for a block on B2. Actions:
``pickup(r,B,L)`` (L in init, table, rail), ``stack(r,B,tower)``, ``push(r,tower,start,goal)``.
"""
from __future__ import annotations

import math
import numbers
import re
import time
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from planner import task_planner as tp, terms
from planner.domain import Context, UnknownAction
from planner.task_planner import Plan, PlanningError

ENCODING = Path(__file__).with_name("asp") / "stack_and_push.lp"
ROBOT, TOWER, START, GOAL = "r", "tower", "start", "goal"
PICKUP_PLACES = ("init", "table", "rail")
PLACES = PICKUP_PLACES + (GOAL,)
_BLOCK = re.compile(r"^b([1-9][0-9]*)$")
_ARITY = {"pickup": 3, "stack": 3, "push": 4}


# --------------------------------------------------------------------------- symbols

def parse_term(term: str) -> tuple[str, tuple[str, ...]]:
    """``planner.terms.parse_term``, malformed text being an UnknownAction here."""
    return terms.parse_term(term, "term", UnknownAction)


def block_index(name: str) -> int:
    m = _BLOCK.match(name)
    if m is None:
        raise ValueError(f"{name!r} is not a block (b1, b2, ...)")
    return int(m.group(1))


def _atoms(atoms: Iterable[str] | str) -> list[str]:
    if isinstance(atoms, str):
        atoms = re.split(r"[\s.]+(?![^()]*\))", atoms)
    return [a.replace(" ", "") for a in atoms if a and a.strip()]


def parse_state(atoms: Iterable[str] | str) -> frozenset[str]:
    """A checked state: every block exactly once at a place, in the hand or in the tower
    (one ``on`` chain rooted at ``start``), ``hand_empty(r)`` iff nothing is held.
    ValueError names the offending atom."""
    where: dict[str, str] = {}
    below: dict[str, str] = {}
    held: list[str] = []
    empty = False
    for atom in _atoms(atoms):
        try:
            name, args = parse_term(atom)
        except UnknownAction as exc:
            raise ValueError(f"state: {exc}") from None
        if name == "hand_empty" and args == (ROBOT,):
            empty = True
            continue
        if name == "is_holding" and len(args) == 2 and args[0] == ROBOT:
            block_index(args[1])
            held.append(args[1])
            b = args[1]
        elif name == "is_in" and len(args) == 2 and args[1] in PLACES:
            block_index(args[0])
            b = args[0]
        elif name == "on" and len(args) == 2:
            block_index(args[0])
            if args[1] != START:
                block_index(args[1])
            b = args[0]
            below[b] = args[1]
        else:
            raise ValueError(f"state: unknown atom {atom!r}")
        if b in where:
            raise ValueError(f"state: {atom!r}: block {b} is already {where[b]}")
        where[b] = atom
    if len(held) > 1:
        raise ValueError(f"state: the robot holds {held[0]} and {held[1]}")
    if empty == bool(held):
        raise ValueError("state: hand_empty(r) must hold exactly when no block is held")
    _chain(below)
    blocks = sorted(where, key=block_index)
    if not blocks:
        raise ValueError("state: no blocks")
    missing = [f"b{i}" for i in range(1, block_index(blocks[-1]) + 1) if f"b{i}" not in where]
    if missing:
        raise ValueError(f"state: block {missing[0]} is missing (blocks are b1..bN)")
    return frozenset(where.values()) | ({f"hand_empty({ROBOT})"} if empty else set())


def _chain(below: Mapping[str, str]) -> list[str]:
    """The tower bottom first, from ``on`` atoms; ValueError unless it is one chain on start."""
    above = {}
    for b, under in below.items():
        if under in above:
            raise ValueError(f"state: on({above[under]},{under}) and on({b},{under})")
        above[under] = b
    chain, cur = [], START
    while cur in above:
        cur = above[cur]
        chain.append(cur)
    if len(chain) != len(below):
        loose = sorted(set(below) - set(chain), key=block_index)[0]
        raise ValueError(f"state: on({loose},{below[loose]}) is not in a tower on {START}")
    return chain


def blocks(state: frozenset[str]) -> list[str]:
    out = set()
    for atom in state:
        name, args = parse_term(atom)
        if name in ("is_in", "on"):
            out.add(args[0])
        elif name == "is_holding":
            out.add(args[1])
    return sorted(out, key=block_index)


def tower(state: frozenset[str]) -> list[str]:
    """The tower's blocks, bottom first."""
    below = {}
    for atom in state:
        if atom.startswith("on("):
            _, (b, under) = parse_term(atom)
            below[b] = under
    return _chain(below)


def held_block(state: frozenset[str]) -> str | None:
    for atom in state:
        if atom.startswith("is_holding("):
            return parse_term(atom)[1][1]
    return None


def initial_state(n_blocks: int) -> frozenset[str]:
    if isinstance(n_blocks, bool) or not isinstance(n_blocks, numbers.Integral) or n_blocks < 1:
        raise ValueError(f"n_blocks must be a positive integer, got {n_blocks!r}")
    return frozenset({f"is_in(b{i},init)" for i in range(1, n_blocks + 1)} | {f"hand_empty({ROBOT})"})


def is_goal(state: frozenset[str]) -> bool:
    return f"hand_empty({ROBOT})" in state and all(f"is_in({b},{GOAL})" in state for b in blocks(state))


def check_action(action: str) -> tuple[str, tuple[str, ...]]:
    """(name, args) of a well-formed action; UnknownAction names what is wrong."""
    name, args = parse_term(action)
    if name not in _ARITY:
        raise UnknownAction(f"action {action!r}: unknown action name {name!r} "
                            f"(stack_and_push: {', '.join(_ARITY)})")
    if len(args) != _ARITY[name] or args[0] != ROBOT:
        raise UnknownAction(f"action {action!r}: expected pickup(r,B,L), stack(r,B,tower) "
                            f"or push(r,tower,start,goal)")
    if name == "pickup" and args[2] not in PICKUP_PLACES:
        raise UnknownAction(f"action {action!r}: pickup from {args[2]!r} (expected init, table or rail)")
    if name == "stack" and args[2] != TOWER:
        raise UnknownAction(f"action {action!r}: stack onto {args[2]!r} (expected tower)")
    if name == "push" and args[1:] != (TOWER, START, GOAL):
        raise UnknownAction(f"action {action!r}: expected push(r,tower,start,goal)")
    return name, args


def apply(state: frozenset[str], action: str) -> frozenset[str]:
    """The successor state if the action succeeds; ValueError names an unmet precondition."""
    name, args = check_action(action)
    s = set(state)
    if name == "pickup":
        b, where = args[1], args[2]
        for atom in (f"is_in({b},{where})", f"hand_empty({ROBOT})"):
            if atom not in s:
                raise ValueError(f"{action}: precondition {atom} does not hold")
        s -= {f"is_in({b},{where})", f"hand_empty({ROBOT})"}
        s.add(f"is_holding({ROBOT},{b})")
    elif name == "stack":
        b = args[1]
        if f"is_holding({ROBOT},{b})" not in s:
            raise ValueError(f"{action}: precondition is_holding({ROBOT},{b}) does not hold")
        chain = tower(state)
        s.remove(f"is_holding({ROBOT},{b})")
        s |= {f"on({b},{chain[-1] if chain else START})", f"hand_empty({ROBOT})"}
    else:
        chain = tower(state)
        if f"hand_empty({ROBOT})" not in s:
            raise ValueError(f"{action}: precondition hand_empty({ROBOT}) does not hold")
        if not chain:
            raise ValueError(f"{action}: there is no tower on {START} to push")
        s -= {a for a in s if a.startswith("on(")}
        s |= {f"is_in({b},{GOAL})" for b in chain}
    return frozenset(s)


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
                  model: tp._Model, classes: Mapping[str, str]) -> tuple[float, int | None]:
    c = model.costs
    if name == "pickup":
        p = model.p_pickup[classes[args[1]]]
        return -c["pickup"] - (1.0 - p) * c["fail"], None
    h = len(tower(state))
    if name == "stack":
        p = float(model.p_stack[h])
        return -c["stack"] - (1.0 - p) * c["fail"], None
    p = float(model.p_push[h - 1]) if h else 1.0
    return -c["push"] - (1.0 - p) * c["fail"] + p * c["deliver"] * h, h


def _evaluate(state: frozenset[str], actions: Sequence[str], model: tp._Model,
              classes: Mapping[str, str]) -> tuple[float, tuple[int, ...], frozenset[str]]:
    terms, loads = [], []
    for step, action in enumerate(actions, start=1):
        try:
            name, args = check_action(action)
            value, load = _action_value(name, args, state, model, classes)
            state = apply(state, action)
        except ValueError as exc:
            raise PlanningError(f"step {step}: {exc}") from None
        terms.append(value)
        if load is not None:
            loads.append(load)
    return math.fsum(terms), tuple(loads), state


def _checked_state(state: Iterable[str]) -> frozenset[str]:
    if isinstance(state, str):
        raise PlanningError("state: expected an iterable of atoms, got a string")
    try:
        return parse_state(list(state))
    except ValueError as exc:
        raise PlanningError(str(exc)) from None


def _model(start: frozenset[str], transition: Mapping, costs: Mapping | None,
           block_classes: Mapping[str, str] | None) -> tuple[dict, tp._Model]:
    names = blocks(start)
    classes = tp._block_classes(names, block_classes)
    return classes, tp._validate_transition(transition, len(names), set(classes.values()), costs)


def expected_utility(state: Iterable[str], actions: Sequence[str], transition: Mapping,
                     costs: Mapping | None = None, *,
                     block_classes: Mapping[str, str] | None = None) -> float:
    """The expected utility of the actions from the state, by simulating them."""
    start = _checked_state(state)
    classes, model = _model(start, transition, costs, block_classes)
    return _evaluate(start, list(actions), model, classes)[0]


# --------------------------------------------------------------------------- planning

def _problem(state: frozenset[str]) -> tp._Problem:
    place = {}
    for atom in state:
        if atom.startswith("is_in("):
            _, (b, where) = parse_term(atom)
            if where in PICKUP_PLACES:
                place[b] = where
    # Blocks off their supply slot first (a fallen block blocks the rail), then by index.
    order = sorted(place, key=lambda b: (place[b] == "init", block_index(b)))
    return tp._Problem(tuple(order), place, held_block(state), len(tower(state)), False,
                       return_push=False)


def _name_actions(problem: tp._Problem, steps: Sequence[str]) -> tuple[str, ...]:
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
         time_limit: float = tp.DEFAULT_TIME_LIMIT_S) -> Plan:
    """The plan of maximum expected utility from the state under T (``{pickup, stack[N],
    push[N]}``) and the costs, proven optimal unless the time limit cut the search."""
    started = time.perf_counter()
    start = _checked_state(state)
    classes, model = _model(start, transition, costs, block_classes)
    if max_steps is not None and (isinstance(max_steps, bool) or
                                  not isinstance(max_steps, numbers.Integral) or max_steps < 0):
        raise PlanningError(f"max_steps: expected an integer >= 0, got {max_steps!r}")
    if not tp._is_number(time_limit) or not float(time_limit) > 0:
        raise PlanningError(f"time_limit: expected seconds > 0, got {time_limit!r}")
    problem = _problem(start)
    if problem.units == 0:
        return Plan((), (), 0.0, True, (time.perf_counter() - started) * 1e3)
    shortest = problem.horizon(1)
    if max_steps is not None and max_steps < shortest:
        raise PlanningError(f"goal unreachable within max_steps={max_steps}: the shortest "
                            f"plan from this state has {shortest} actions")
    last_trips = problem.max_trips
    if max_steps is not None:
        last_trips = min(last_trips, max_steps - shortest + 1)
    class_ids = {name: i for i, name in enumerate(sorted(set(classes.values())), start=1)}
    weights = tp._weights(problem, model, classes, class_ids)
    search = tp._optimise(problem, weights, last_trips, started + float(time_limit), ENCODING)
    actions = _name_actions(problem, search.best_steps)
    value, loads, final = _evaluate(start, actions, model, classes)
    if not is_goal(final):
        raise RuntimeError(f"internal error: planned actions do not reach the goal: {actions}")
    return Plan(actions, loads, value, search.proven, (time.perf_counter() - started) * 1e3)


def _random_actions(problem: tp._Problem, rng: np.random.Generator) -> tuple[str, ...]:
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
    classes, model = _model(start, transition or tp.optimistic_transition(n), costs, block_classes)
    actions = _random_actions(_problem(start), rng)
    value, loads, _ = _evaluate(start, actions, model, classes)
    return Plan(actions, loads, value, False, (time.perf_counter() - started) * 1e3)


# --------------------------------------------------------------------------- the protocol

class StackAndPushTask:
    """Blocks stacked into a tower and pushed along a rail to the goal: pickup 15, stack 10,
    push 30, fail 50, +40 per block delivered, +80 once all are; no return push."""

    name = "stack_and_push"
    action_names = ("pickup", "stack", "push")
    default_costs = dict(tp.DEFAULT_COSTS)

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

    def context_of(self, state: frozenset[str], action: str) -> Context:
        return context_of(state, action)

    def optimistic_transition(self, n_blocks: int) -> dict:
        return tp.optimistic_transition(n_blocks)

    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             block_classes: Mapping[str, str] | None = None, max_steps: int | None = None,
             time_limit: float = tp.DEFAULT_TIME_LIMIT_S) -> Plan:
        return plan(state, transition, costs, block_classes=block_classes,
                    max_steps=max_steps, time_limit=time_limit)

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
