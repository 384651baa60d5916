"""The clingo search of a block world's trip planner (part of the block-world toolkit,
``planner.blocks``): the plan of maximum expected utility under T.

A domain's encoding (``planner/asp/<domain>.lp``) works on counts: how many blocks wait,
how many are loaded, which classes come in which order. This module writes the
integer-scaled weights of the trip model (``planner.blocks.model``) as facts, and runs
clingo in multi-shot incremental mode with ``#minimize`` over them, one trip more per
horizon. The domain names the blocks afterwards and
recomputes the expected utility exactly in Python.

Everything returned is plain Python data; a fresh ``clingo.Control`` is made per call
(clingo objects do not pickle and keep their symbols for the process lifetime).
"""
from __future__ import annotations

import numbers
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import clingo
import numpy as np

from planner.blocks.model import Model, PlanningError, attempt_cost, is_number, push_value, redo_costs

DEFAULT_TIME_LIMIT_S = 30.0
# Weights are scaled by at most this much before rounding: the rounding error of a plan's
# value is then below 0.5e-6 per action, far under any difference the planner cares for.
MAX_SCALE = 10**6
# clingo's numbers are 32-bit; keep every weight fact well inside.
_WEIGHT_LIMIT = 2**30
# The tie-break's weights are shares of one in thousandths (``tie_weights``).
TIE_SCALE = 1000


def tie_weights(trials: np.ndarray) -> np.ndarray:
    """The tie-break's weight of a stack or push whose context T estimated from `trials`
    trials: 1 / (1 + n), the share of the estimate that is T's prior pseudo-trial (T's
    estimate is (s + 1) / (n + 1)), in thousandths. The encodings minimise its sum at a
    priority below the expected utility's, so among plans of equal expected utility the
    one whose estimates rest least on the prior wins: 40 successes of 40 and 4 of 4 both
    estimate 1.0, and a tie between them is not a coin toss. It never trades expected
    utility (a lower priority), so the optimistic prior still draws the robot to an
    untried context whenever T values it higher."""
    return np.rint(TIE_SCALE / (1.0 + np.asarray(trials, dtype=np.float64))).astype(np.int64)


def tie_facts(model: Model) -> list[str]:
    """``u_stack(H,U)`` and ``u_push(K,U)``: the tie-break's weights (none without trials)."""
    lines = []
    if model.n_stack is not None:
        lines += [f"u_stack({h},{int(u)})." for h, u in enumerate(tie_weights(model.n_stack))]
    if model.n_push is not None:
        lines += [f"u_push({k},{int(u)})." for k, u in enumerate(tie_weights(model.n_push), start=1)]
    return lines


# --------------------------------------------------------------------------- the problem

@dataclass(frozen=True)
class Problem:
    """The counts the encoding works on, plus the names Python needs to name blocks."""

    order: tuple[str, ...]        # waiting blocks in pick order: table first, then init
    place: dict                   # block -> init | table for the waiting blocks
    held: str | None
    load0: int                    # blocks in the container (standing at init)
    at_goal: bool                 # the container stands at goal
    return_push: bool = True      # a trip ends with a return push (stack-and-push: none)
    # The first `clear_first` blocks of `order` are picked before any push (stack-and-push:
    # blocks lying on the rail, which a push would sweep along with the tower).
    clear_first: int = 0

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


@dataclass(frozen=True)
class Weights:
    """Integer weight facts for the encoding and what the stopping rule needs."""

    facts: str
    constant: int                 # objective part that every complete plan pays
    back: int                     # weight of a return push
    stack: dict                   # (regular trip?, pile height) -> weight
    push: dict                    # (regular trip?, load) -> weight

    def objective(self, problem: "Problem", steps: Sequence[str]) -> int:
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


def trip_values(cum: np.ndarray, push: np.ndarray, start: int,
                 units: int) -> tuple[np.ndarray, np.ndarray]:
    """Final loads k = max(start,1)..units of a trip that starts with ``start`` blocks
    loaded, and G(k): the weights of its stacks plus that of its push."""
    ks = np.arange(max(start, 1), units + 1)
    return ks, cum[ks] - cum[start] + push[ks - 1]


def trip_weights(ks: np.ndarray, values: np.ndarray, start: int,
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


def scaled_weights(problem: Problem, model: Model, classes: Mapping[str, str],
                    class_ids: Mapping[str, int], scale: int) -> Weights | None:
    """The facts at one scale, or None if a weight would not fit clingo's 32-bit numbers."""
    c = model.costs
    loads = np.arange(1, len(model.p_push) + 1)
    stack = np.rint(scale * attempt_cost(c["stack"], c["fail"], model.p_stack)).astype(np.int64)
    redo = redo_costs(model, classes, c["push"] if problem.return_push else 0.0)[loads]
    push = np.rint(-scale * push_value(c, model.p_push, loads, redo)).astype(np.int64)
    back = int(round(scale * c["push"]))
    pick = {k: int(round(scale * attempt_cost(c["pickup"], c["fail"], p)))
            for k, p in model.p_pickup.items()}
    cum = np.concatenate([[0], np.cumsum(stack)])
    units = problem.units
    # Trip kinds: regular (starts empty) and, with a loaded container, the first trip.
    trips = {start: trip_values(cum, push, start, units)
             for start in ([0] + ([problem.load0] if problem.load0 > 0 else []))}
    # Shift every trip by `shift` per block it delivers, the least trip value per block
    # (rounded down): every rewritten weight is then >= 0, and as the loads of all trips
    # sum to `units`, the shift adds the same constant to every complete plan.
    shift = min(int(np.min(values // ks)) for ks, values in trips.values())
    per_block = [shift] * units
    for i, block in enumerate(problem.order):
        per_block[i] += pick[classes[block]]            # every waiting block is picked once
    waiting = len(problem.order)
    lines = [f"init_wait({waiting}).", f"init_load({problem.load0}).", f"init_clear({problem.clear_first}).",
             f"init_cpos({'goal' if problem.at_goal else 'init'}).", f"w_back({back})."]
    if problem.held is not None:
        lines.append(f"init_hold({class_ids[classes[problem.held]]}).")
    lines += [f"seq({waiting - i},{class_ids[classes[b]]})." for i, b in enumerate(problem.order)]
    lines += [f"w_const({i},{w})." for i, w in enumerate(per_block)]
    stack_table, push_table = {}, {}
    for start, (ks, values) in trips.items():
        suffix = "0" if start > 0 else ""
        stack_w, push_w = trip_weights(ks, values, start, shift)
        stack_table.update({(start == 0, h): w for h, w in stack_w.items()})
        push_table.update({(start == 0, k): w for k, w in push_w.items()})
        lines += [f"w_stack{suffix}({h},{w})." for h, w in stack_w.items()]
        lines += [f"w_push{suffix}({k},{w})." for k, w in push_w.items()]
    weights = [back, *per_block, *stack_table.values(), *push_table.values()]
    if max(abs(w) for w in weights) >= _WEIGHT_LIMIT:
        return None
    lines += tie_facts(model)
    return Weights("\n".join(lines), sum(per_block), back, stack_table, push_table)


def weights_for(problem: Problem, model: Model, classes: Mapping[str, str],
             class_ids: Mapping[str, int]) -> Weights:
    """Weights at the finest scale (up to MAX_SCALE) whose facts fit 32-bit numbers."""
    scale = MAX_SCALE
    while scale >= 1:
        weights = scaled_weights(problem, model, classes, class_ids, scale)
        if weights is not None:
            return weights
        scale //= 4
    raise PlanningError("costs too large to plan with (weights overflow clingo's numbers)")


# --------------------------------------------------------------------------- solving

@dataclass
class Search:
    """The incremental clingo search over horizons (one per call; never shared)."""

    ctl: clingo.Control
    problem: Problem
    weights: Weights
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


def lower_bound(problem: Problem, weights: Weights, trips: int) -> int:
    """Least objective of any plan with this many trips: the constant, plus the return
    pushes; every other weight in a step is >= 0 (see trip_weights)."""
    if not problem.return_push:
        return weights.constant
    return weights.constant + (trips - 1 + problem.at_goal) * weights.back


def optimise(problem: Problem, weights: Weights, last_trips: int,
             deadline: float, encoding: Path) -> Search:
    """Multi-shot search with the domain's `encoding`: extend the horizon one trip at a
    time until the stopping rule says that no longer plan can be better. The encoding
    keeps only waste-free plans (no empty round trips: with costs >= 0 they never pay),
    so a plan with m trips has exactly ``problem.horizon(m)`` actions; each solve looks
    only for plans strictly better than the best so far (clingo's opt bound). Every step
    weight is >= 0 after ``trip_weights``' rewriting, so a plan with m trips costs at least
    ``lower_bound(m)``, which grows with m: once it reaches the best cost, the search
    stops. Optimality is proven when every solve was exhausted; at `deadline` (perf
    counter) the best plan so far is returned unproven."""
    ctl = clingo.Control(["--opt-mode=opt", "--models=0", "--warn=none"])
    ctl.add("base", [], encoding.read_text())
    ctl.add("base", [], weights.facts)
    ctl.ground([("base", [])])
    search = Search(ctl, problem, weights, deadline)
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
        if trips >= last_trips or lower_bound(problem, weights, trips + 1) >= search.best_cost:
            return search
        if time.perf_counter() >= deadline:
            search.proven = False
            return search
        trips += 1


def check_limits(max_steps, time_limit) -> None:
    """PlanningError naming `max_steps` (an integer >= 0 or None) or `time_limit` (> 0 s)."""
    if max_steps is not None and (isinstance(max_steps, bool) or
                                  not isinstance(max_steps, numbers.Integral) or max_steps < 0):
        raise PlanningError(f"max_steps: expected an integer >= 0, got {max_steps!r}")
    if not is_number(time_limit) or not float(time_limit) > 0:
        raise PlanningError(f"time_limit: expected seconds > 0, got {time_limit!r}")


def search(problem: Problem, model: Model, classes: Mapping[str, str], last_trips: int,
           deadline: float, encoding: Path) -> Search:
    """The weights of `problem` under `model` (block classes numbered in name order) and
    the clingo search over up to `last_trips` trips until `deadline`."""
    class_ids = {name: i for i, name in enumerate(sorted(set(classes.values())), start=1)}
    return optimise(problem, weights_for(problem, model, classes, class_ids), last_trips, deadline, encoding)


# The names stack-and-push used before the toolkit was public (issue 26).
_Problem, _Weights, _weights, _optimise = Problem, Weights, weights_for, optimise
