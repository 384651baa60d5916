"""Task planner for the container domain: the plan of maximum expected utility under T.

The plan is found by clingo (planner/asp/container.lp) in multi-shot incremental mode with
``#minimize`` over integer-scaled weights written as facts from the transition model T and
the costs (DESIGN.md sections 3 and 7). The encoding counts interchangeable blocks; this
module names them afterwards and recomputes the expected utility exactly in Python.

Expected utility of a plan (DESIGN.md section 3)::

    sum over actions a of  -cost(a) - (1 - p(a)) * fail + p(a) * bonus(a)

with p(a) from T in the action's context (pickup: the block's class; stack: the number of
blocks already in the container; push to goal: its load k, bonus deliver * k; the return
push and an empty push to goal: p = 1, bonus 0).

Everything returned is plain Python data; a fresh ``clingo.Control`` is made per call
(clingo objects do not pickle and keep their symbols for the process lifetime).
"""
from __future__ import annotations

import math
import numbers
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import clingo
import numpy as np

from planner import symbolic

ENCODING = Path(__file__).with_name("asp") / "container.lp"
DEFAULT_COSTS: dict[str, float] = {"pickup": 15.0, "stack": 10.0, "push": 30.0, "fail": 50.0,
                                   "deliver": 40.0, "all_delivered": 80.0}
DEFAULT_CLASS = "block"
TRANSITION_FIELDS = ("pickup", "stack", "push")
DEFAULT_TIME_LIMIT_S = 30.0
# Weights are scaled by at most this much before rounding: the rounding error of a plan's
# value is then below 0.5e-6 per action, far under any difference the planner cares for.
MAX_SCALE = 10**6
# clingo's numbers are 32-bit; keep every weight fact well inside.
_WEIGHT_LIMIT = 2**30


class PlanningError(ValueError):
    """The planner cannot answer: bad T or costs, a malformed state, an unreachable goal."""


@dataclass(frozen=True)
class Plan:
    """A plan and what it is worth under the transition model and costs it was made for."""

    actions: tuple[str, ...]      # ASP terms in text, blocks named
    loads: tuple[int, ...]        # blocks carried by each push to goal, in order
    expected_utility: float       # under T and costs (float, unscaled)
    optimal: bool                 # optimality proven by clingo
    solve_ms: float               # wall time of the call, grounding included

    def to_dict(self) -> dict:
        """JSON-ready form; ``plan`` is the list of actions."""
        return {"plan": list(self.actions), "loads": list(self.loads),
                "expected_utility": float(self.expected_utility),
                "optimal": bool(self.optimal), "solve_ms": float(self.solve_ms)}


# --------------------------------------------------------------------------- validation

@dataclass(frozen=True)
class _Model:
    """A validated transition model and cost table for one state's blocks."""

    p_pickup: dict[str, float]    # class -> p
    p_stack: np.ndarray           # [p_0 .. p_{N-1}], index = blocks already in the container
    p_push: np.ndarray            # [p_1 .. p_N], index k-1 = load k
    costs: dict[str, float]


def optimistic_transition(n_blocks: int) -> dict:
    """T with every action succeeding (how TMOC starts, R-max style)."""
    if isinstance(n_blocks, bool) or not isinstance(n_blocks, numbers.Integral) or n_blocks < 1:
        raise PlanningError(f"n_blocks must be a positive integer, got {n_blocks!r}")
    return {"pickup": 1.0, "stack": [1.0] * int(n_blocks), "push": [1.0] * int(n_blocks)}


def _is_number(value: object) -> bool:
    return isinstance(value, (numbers.Real, np.number)) and not isinstance(value, (bool, np.bool_))


def _probability(value: object, field: str) -> float:
    if not _is_number(value):
        raise PlanningError(f"{field}: expected a probability, got {value!r}")
    p = float(value)
    if not (math.isfinite(p) and 0.0 <= p <= 1.0):
        raise PlanningError(f"{field}: probability {p!r} is not in [0, 1]")
    return p


def _probabilities(value: object, field: str, n: int, meaning: str) -> np.ndarray:
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (Sequence, np.ndarray)):
        raise PlanningError(f"{field}: expected a list of {n} probabilities ({meaning}), "
                            f"got {value!r}")
    values = list(np.asarray(value, dtype=object).ravel()) if isinstance(value, np.ndarray) \
        else list(value)
    if len(values) != n:
        raise PlanningError(f"{field}: expected {n} probabilities ({meaning}), got {len(values)}")
    return np.array([_probability(v, f"{field}[{i}]") for i, v in enumerate(values)])


def _validate_costs(costs: Mapping | None) -> dict[str, float]:
    merged = dict(DEFAULT_COSTS)
    if costs is None:
        return merged
    if not isinstance(costs, Mapping):
        raise PlanningError(f"costs: expected a mapping, got {type(costs).__name__}")
    for key, value in costs.items():
        if key not in DEFAULT_COSTS:
            raise PlanningError(f"costs: unknown field {key!r} (fields: "
                                f"{', '.join(DEFAULT_COSTS)})")
        # Non-negative costs make every wasted action a loss, which the encoding's
        # dominance pruning and the stopping rule rely on.
        if not _is_number(value) or not math.isfinite(float(value)) or float(value) < 0:
            raise PlanningError(f"costs: {key!r} must be a finite number >= 0, got {value!r}")
        merged[key] = float(value)
    return merged


def _validate_transition(transition: Mapping, n_blocks: int, classes: set[str],
                         costs: Mapping | None) -> _Model:
    if not isinstance(transition, Mapping):
        raise PlanningError(f"transition: expected a mapping with fields "
                            f"{', '.join(TRANSITION_FIELDS)}, got {type(transition).__name__}")
    for key in transition:
        if key not in TRANSITION_FIELDS:
            raise PlanningError(f"transition: unknown field {key!r} (fields: "
                                f"{', '.join(TRANSITION_FIELDS)})")
    for key in TRANSITION_FIELDS:
        if key not in transition:
            raise PlanningError(f"transition: missing field {key!r}")
    pickup = transition["pickup"]
    if isinstance(pickup, Mapping):
        for name in pickup:
            if name not in classes:
                raise PlanningError(f"pickup: unknown block class {name!r} (classes: "
                                    f"{', '.join(sorted(classes))})")
        missing = sorted(classes - set(pickup))
        if missing:
            raise PlanningError(f"pickup: no probability for block class {missing[0]!r}")
        p_pickup = {name: _probability(p, f"pickup[{name!r}]") for name, p in pickup.items()}
    else:
        p = _probability(pickup, "pickup")
        p_pickup = {name: p for name in classes}
    return _Model(
        p_pickup=p_pickup,
        p_stack=_probabilities(transition["stack"], "stack", n_blocks,
                               f"pile heights 0..{n_blocks - 1}"),
        p_push=_probabilities(transition["push"], "push", n_blocks, f"loads 1..{n_blocks}"),
        costs=_validate_costs(costs))


def _checked_state(state: Iterable[str]) -> frozenset[str]:
    """The canonical, checked and normalised state, or PlanningError naming the atom."""
    if isinstance(state, str):
        raise PlanningError("state: expected an iterable of atoms, got a string")
    try:
        return symbolic.normalize(symbolic.parse_state(list(state)))
    except ValueError as exc:
        raise PlanningError(str(exc)) from None


def _block_classes(blocks: Sequence[str], block_classes: Mapping[str, str] | None) -> dict[str, str]:
    """Class of every block; blocks not listed are of DEFAULT_CLASS."""
    classes = {b: DEFAULT_CLASS for b in blocks}
    if block_classes is None:
        return classes
    if not isinstance(block_classes, Mapping):
        raise PlanningError("block_classes: expected a mapping block -> class name")
    for block, name in block_classes.items():
        if block not in classes:
            raise PlanningError(f"block_classes: unknown block {block!r} (blocks: "
                                f"{blocks[0]}..{blocks[-1]})")
        if not isinstance(name, str) or not name:
            raise PlanningError(f"block_classes[{block!r}]: expected a class name, got {name!r}")
        classes[block] = name
    return classes


# --------------------------------------------------------------------------- utility

def _action_value(name: str, args: tuple[str, ...], state: frozenset[str], model: _Model,
                  classes: Mapping[str, str]) -> tuple[float, int | None]:
    """Expected-utility contribution of an action in a state, and the load of a push to goal."""
    costs = model.costs
    if name == "pickup":
        p = model.p_pickup[classes[args[1]]]
        return -costs["pickup"] - (1.0 - p) * costs["fail"], None
    loaded = sum(1 for atom in state if atom.startswith("at_container("))
    if name == "stack":
        p = float(model.p_stack[loaded])
        return -costs["stack"] - (1.0 - p) * costs["fail"], None
    if args[3] == "init" or loaded == 0:           # return push / empty push: p = 1, no bonus
        return -costs["push"], (0 if args[3] == "goal" else None)
    p = float(model.p_push[loaded - 1])
    return -costs["push"] - (1.0 - p) * costs["fail"] + p * costs["deliver"] * loaded, loaded


def _evaluate(state: frozenset[str], actions: Sequence[str], model: _Model,
              classes: Mapping[str, str]) -> tuple[float, tuple[int, ...], frozenset[str]]:
    """Simulate the actions: (expected utility, loads of the pushes to goal, final state)."""
    terms, loads = [], []
    for step, action in enumerate(actions, start=1):
        try:
            name, args = symbolic.parse_action(action)
            value, load = _action_value(name, args, state, model, classes)
            state = symbolic.apply(state, action)
        except ValueError as exc:
            raise PlanningError(f"step {step}: {exc}") from None
        terms.append(value)
        if load is not None:
            loads.append(load)
    return math.fsum(terms), tuple(loads), state


def expected_utility(state: Iterable[str], actions: Sequence[str], transition: Mapping,
                     costs: Mapping | None = None, *,
                     block_classes: Mapping[str, str] | None = None) -> float:
    """The expected utility of the actions from the state under T and the costs, by
    simulating them (PlanningError names the step whose action is not applicable)."""
    start = _checked_state(state)
    blocks = symbolic.blocks(start)
    classes = _block_classes(blocks, block_classes)
    model = _validate_transition(transition, len(blocks), set(classes.values()), costs)
    return _evaluate(start, list(actions), model, classes)[0]


# --------------------------------------------------------------------------- the problem

@dataclass(frozen=True)
class _Problem:
    """The counts the encoding works on, plus the names Python needs to name blocks."""

    order: tuple[str, ...]        # waiting blocks in pick order: table first, then init
    place: dict                   # block -> init | table for the waiting blocks
    held: str | None
    load0: int                    # blocks in the container (standing at init)
    at_goal: bool                 # the container stands at goal
    return_push: bool = True      # a trip ends with a return push (stack-and-push: none)

    @property
    def units(self) -> int:
        """Blocks still to deliver."""
        return len(self.order) + (self.held is not None) + self.load0

    @property
    def max_trips(self) -> int:
        """Most trips a waste-free plan can make: one per block still to stack, plus one
        for a container that is already loaded."""
        return len(self.order) + (self.held is not None) + (self.load0 > 0)

    def horizon(self, trips: int) -> int:
        """Length of every waste-free plan with that many trips: a pickup per waiting block,
        a stack per block not yet in the container, a push to goal per trip and a return
        push between trips (and first, if the container stands at goal)."""
        if not self.return_push:
            return 2 * len(self.order) + (self.held is not None) + trips
        return 2 * len(self.order) + (self.held is not None) + 2 * trips - 1 + self.at_goal


def _problem(state: frozenset[str]) -> _Problem:
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
    return _Problem(tuple(order), place, held, load0, at_goal)


@dataclass(frozen=True)
class _Weights:
    """Integer weight facts for the encoding and what the stopping rule needs."""

    facts: str
    constant: int                 # objective part that every complete plan pays
    back: int                     # weight of a return push
    stack: dict                   # (regular trip?, pile height) -> weight
    push: dict                    # (regular trip?, load) -> weight

    def objective(self, problem: "_Problem", steps: Sequence[str]) -> int:
        """The plan's objective, recomputed here: clingo's Model.cost is 32-bit in the
        Python API while the solver sums in 64 bits."""
        total, load, regular = self.constant, problem.load0, problem.load0 == 0
        for step in steps:
            if step == "stack":
                total += self.stack[regular, load]
                load += 1
            elif step == "push_goal":
                total += self.push[regular, load]
                load, regular = 0, True
            elif step == "push_back":
                total += self.back
        return total


def _trip_values(cum: np.ndarray, push: np.ndarray, start: int,
                 units: int) -> tuple[np.ndarray, np.ndarray]:
    """Final loads k = max(start,1)..units of a trip that starts with ``start`` blocks
    loaded, and G(k): the weights of its stacks plus that of its push."""
    ks = np.arange(max(start, 1), units + 1)
    return ks, cum[ks] - cum[start] + push[ks - 1]


def _trip_weights(ks: np.ndarray, values: np.ndarray, start: int,
                  shift: int) -> tuple[dict, dict]:
    """Stack weights by pile height (start..units-1) and push weights by load (ks) of a
    trip that starts with ``start`` blocks loaded, rewritten so that each is >= 0 and the
    trip ending with load k still totals G'(k) = G(k) - shift*k (see container.lp):
    S(start) = 0, S(k) = min_{k' >= k} G'(k'), a stack onto j blocks weighs S(j+1) - S(j),
    a push with load k weighs G'(k) - S(k)."""
    shifted = values - shift * ks                                  # G'(k) >= 0
    suffix_min = np.minimum.accumulate(shifted[::-1])[::-1]        # min over k' >= k
    s = np.concatenate([[0], suffix_min[1:] if start > 0 else suffix_min])  # S(start..units)
    stack = {int(h): int(w) for h, w in zip(range(start, int(ks[-1])), np.diff(s))}
    push = {int(k): int(w) for k, w in zip(ks, shifted - (s[1:] if start == 0 else s))}
    return stack, push


def _scaled_weights(problem: _Problem, model: _Model, classes: Mapping[str, str],
                    class_ids: Mapping[str, int], scale: int) -> _Weights | None:
    """The facts at one scale, or None if a weight would not fit clingo's 32-bit numbers."""
    c = model.costs
    loads = np.arange(1, len(model.p_push) + 1)
    stack = np.rint(scale * (c["stack"] + (1.0 - model.p_stack) * c["fail"])).astype(np.int64)
    push = np.rint(scale * (c["push"] + (1.0 - model.p_push) * c["fail"]
                            - model.p_push * c["deliver"] * loads)).astype(np.int64)
    back = int(round(scale * c["push"]))
    pick = {k: int(round(scale * (c["pickup"] + (1.0 - p) * c["fail"])))
            for k, p in model.p_pickup.items()}
    cum = np.concatenate([[0], np.cumsum(stack)])
    units = problem.units
    # Trip kinds: regular (starts empty) and, with a loaded container, the first trip.
    trips = {start: _trip_values(cum, push, start, units)
             for start in ([0] + ([problem.load0] if problem.load0 > 0 else []))}
    # Shift every trip by `shift` per block it delivers, the least trip value per block
    # (rounded down): every rewritten weight is then >= 0, and as the loads of all trips
    # sum to `units`, the shift adds the same constant to every complete plan.
    shift = min(int(np.min(values // ks)) for ks, values in trips.values())
    per_block = [shift] * units
    for i, block in enumerate(problem.order):
        per_block[i] += pick[classes[block]]            # every waiting block is picked once
    waiting = len(problem.order)
    lines = [f"init_wait({waiting}).", f"init_load({problem.load0}).",
             f"init_cpos({'goal' if problem.at_goal else 'init'}).", f"w_back({back})."]
    if problem.held is not None:
        lines.append(f"init_hold({class_ids[classes[problem.held]]}).")
    lines += [f"seq({waiting - i},{class_ids[classes[b]]})." for i, b in enumerate(problem.order)]
    lines += [f"w_const({i},{w})." for i, w in enumerate(per_block)]
    stack_table, push_table = {}, {}
    for start, (ks, values) in trips.items():
        suffix = "0" if start > 0 else ""
        stack_w, push_w = _trip_weights(ks, values, start, shift)
        stack_table.update({(start == 0, h): w for h, w in stack_w.items()})
        push_table.update({(start == 0, k): w for k, w in push_w.items()})
        lines += [f"w_stack{suffix}({h},{w})." for h, w in stack_w.items()]
        lines += [f"w_push{suffix}({k},{w})." for k, w in push_w.items()]
    weights = [back, *per_block, *stack_table.values(), *push_table.values()]
    if max(abs(w) for w in weights) >= _WEIGHT_LIMIT:
        return None
    return _Weights("\n".join(lines), sum(per_block), back, stack_table, push_table)


def _weights(problem: _Problem, model: _Model, classes: Mapping[str, str],
             class_ids: Mapping[str, int]) -> _Weights:
    """Weights at the finest scale (up to MAX_SCALE) whose facts fit 32-bit numbers."""
    scale = MAX_SCALE
    while scale >= 1:
        weights = _scaled_weights(problem, model, classes, class_ids, scale)
        if weights is not None:
            return weights
        scale //= 4
    raise PlanningError("costs too large to plan with (weights overflow clingo's numbers)")


# --------------------------------------------------------------------------- solving

@dataclass
class _Search:
    """The incremental clingo search over horizons (one per call; never shared)."""

    ctl: clingo.Control
    problem: _Problem
    weights: _Weights
    deadline: float
    grounded: int = 0             # steps grounded so far
    query: int | None = None      # horizon of the active query
    best_cost: int | None = None
    best_steps: list | None = None  # the best plan's action kinds in time order
    proven: bool = True

    def extend(self, horizon: int) -> None:
        """Ground step(t) up to the horizon (in one call: clingo's per-call overhead
        dominates for small programs) and move the goal query there."""
        parts = [("step", [clingo.Number(t)]) for t in range(self.grounded + 1, horizon + 1)]
        self.ctl.ground(parts + [("check", [clingo.Number(horizon)])])
        self.grounded = horizon
        if self.query is not None:
            self.ctl.release_external(clingo.Function("query", [clingo.Number(self.query)]))
        self.ctl.assign_external(clingo.Function("query", [clingo.Number(horizon)]), True)
        self.query = horizon

    def solve(self) -> None:
        """Optimise at the current horizon, only for plans better than the best so far."""
        if self.best_cost is not None:
            self.ctl.configuration.solve.opt_mode = f"opt,{self.best_cost - 1}"
        found: list = []

        def on_model(model: clingo.Model) -> None:
            found[:] = [s.name for _, s in sorted((s.arguments[-1].number, s)
                                                  for s in model.symbols(shown=True))]

        with self.ctl.solve(on_model=on_model, async_=True) as handle:
            finished = handle.wait(max(0.0, self.deadline - time.perf_counter()))
            if not finished:
                handle.cancel()
            result = handle.get()
        # A finished, exhausted search proves that no better plan exists at this horizon.
        self.proven = self.proven and finished and result.exhausted
        if found:
            self.best_steps = found
            self.best_cost = self.weights.objective(self.problem, found)


def _lower_bound(problem: _Problem, weights: _Weights, trips: int) -> int:
    """Least objective of any plan with this many trips: the constant, plus the return
    pushes; every other weight in a step is >= 0 (see _trip_weights)."""
    if not problem.return_push:
        return weights.constant
    return weights.constant + (trips - 1 + problem.at_goal) * weights.back


def _name_actions(problem: _Problem, steps: Sequence[str]) -> tuple[str, ...]:
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


def _optimise(problem: _Problem, weights: _Weights, last_trips: int,
              deadline: float, encoding: Path = ENCODING) -> _Search:
    """Multi-shot search: extend the horizon one trip at a time until the stopping rule
    (see ``plan``) says that no longer plan can be better."""
    ctl = clingo.Control(["--opt-mode=opt", "--models=0", "--warn=none"])
    ctl.add("base", [], encoding.read_text())
    ctl.add("base", [], weights.facts)
    ctl.ground([("base", [])])
    search = _Search(ctl, problem, weights, deadline)
    # Without a return push the lower bound does not grow with the trips, so one solve at
    # the longest horizon (which holds every waste-free plan, noop after the goal) proves
    # optimality at once.
    trips = 1 if problem.return_push else last_trips
    while True:
        search.extend(problem.horizon(trips))
        search.solve()
        if search.best_cost is None:      # a checked, live state always has a one-trip plan
            raise PlanningError("no plan found within the time limit" if not search.proven
                                else "goal unreachable from this state")
        if trips >= last_trips or _lower_bound(problem, weights, trips + 1) >= search.best_cost:
            return search
        if time.perf_counter() >= deadline:
            search.proven = False
            return search
        trips += 1


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
    classes = _block_classes(blocks, block_classes)
    model = _validate_transition(transition, len(blocks), set(classes.values()), costs)
    if max_steps is not None and (isinstance(max_steps, bool) or
                                  not isinstance(max_steps, numbers.Integral) or max_steps < 0):
        raise PlanningError(f"max_steps: expected an integer >= 0, got {max_steps!r}")
    if not _is_number(time_limit) or not float(time_limit) > 0:
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
        last_trips = min(last_trips, (max_steps - shortest) // 2 + 1)

    class_ids = {name: i for i, name in enumerate(sorted(set(classes.values())), start=1)}
    weights = _weights(problem, model, classes, class_ids)
    search = _optimise(problem, weights, last_trips, started + float(time_limit))
    actions = _name_actions(problem, search.best_steps)
    value, loads, final = _evaluate(start, actions, model, classes)
    if not symbolic.is_goal(final):       # the encoding and symbolic.py disagree: a bug
        raise RuntimeError(f"internal error: planned actions do not reach the goal: {actions}")
    return Plan(actions, loads, value, search.proven, (time.perf_counter() - started) * 1e3)


# --------------------------------------------------------------------------- GP baseline

def _random_actions(problem: _Problem, rng: np.random.Generator) -> tuple[str, ...]:
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
    classes = _block_classes(blocks, block_classes)
    if transition is None:
        transition = optimistic_transition(len(blocks))
    model = _validate_transition(transition, len(blocks), set(classes.values()), costs)
    problem = _problem(start)
    actions = _random_actions(problem, rng) if problem.units else ()
    value, loads, _ = _evaluate(start, actions, model, classes)
    return Plan(actions, loads, value, False, (time.perf_counter() - started) * 1e3)
