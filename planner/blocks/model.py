"""The trip model of a block world (part of the block-world toolkit, ``planner.blocks``):
T and the costs validated, and what each action of a plan is worth under them
(the paper's container domain). Blocks are picked up, stacked onto a load and the load is pushed
to the goal in trips; the container and stack-and-push are both such worlds.

What a planner optimises is computed exactly, in Python, by simulating a plan on the
domain's symbolic model (``simulate_plan``; the container's ``planner.container.model``,
stack-and-push's ``planner.stack_and_push``); ``planner.blocks.trips`` finds the plan
that maximises it with clingo.

Expected utility of a plan::

    sum over pickups and stacks a of  -attempt_cost(cost(a), fail, p(a))
    + sum over pushes to goal a of    push_value(costs, p(a), k(a), redo_cost(k(a)))
    - cost(push) per return push

with p(a) from T in the action's context (pickup: the block's class; stack: the number of
blocks already in the container; push to goal: its load k; the return push and an empty
push to goal: p = 1, no delivery). A pickup or stack that fails has not happened: the plan
goes on only once it is done, so it costs its expected number of attempts
(``attempt_cost``, issue 24: charging a failure once, as if the action had had its effect
anyway, kept a plan through a context the robot failed 47 times in a row). A push that
fails spills its load, and the episode goes on until the blocks are delivered: the trip is
rebuilt (its blocks picked up and stacked again, the container brought back) and pushed
again, so a push of load k costs 1/p attempts, each failed one the fail cost plus
``redo_cost(k)``, and delivers deliver * k once (``push_value``; issue 24: pricing a failed
push as a lost delivery only kept a plan pushing 8 at p 0.39 at 49 mm).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np


DEFAULT_COSTS: dict[str, float] = {"pickup": 15.0, "stack": 10.0, "push": 30.0, "fail": 50.0,
                                   "deliver": 40.0, "all_delivered": 80.0}
DEFAULT_CLASS = "block"
TRANSITION_FIELDS = ("pickup", "stack", "push")
# Optional: {"stack": [n_0..n_{N-1}], "push": [n_1..n_N]}, the trials T's estimate in each
# context rests on. Among plans of equal expected utility the planner takes the one whose
# stacks and pushes rest least on T's prior (``planner.blocks.trips.tie_weights``).
OPTIONAL_TRANSITION_FIELDS = ("trials",)


# Plan and PlanningError are every domain's (planner.domain); re-exported here.
from planner.domain import Plan, PlanningError  # noqa: E402,F401


# --------------------------------------------------------------------------- validation

@dataclass(frozen=True)
class Model:
    """A validated transition model and cost table for one state's blocks."""

    p_pickup: dict[str, float]    # class -> p
    p_stack: np.ndarray           # [p_0 .. p_{N-1}], index = blocks already in the container
    p_push: np.ndarray            # [p_1 .. p_N], index k-1 = load k
    costs: dict[str, float]
    # the trials behind each estimate (the transition's optional "trials"; None: not given)
    n_stack: np.ndarray | None = None   # [n_0 .. n_{N-1}]
    n_push: np.ndarray | None = None    # [n_1 .. n_N]


# The least success probability an attempt is priced at: a context T has seen fail every
# time still costs a finite amount (50 attempts: ~2950 for a stack at the default costs,
# more than any plan of 16 blocks can gain), so the planner's weights stay finite.
P_ATTEMPT_FLOOR = 0.02


def attempt_cost(cost, fail, p):
    """Expected cost of repeating an action until it succeeds: 1/p attempts at `cost`
    each, 1/p - 1 of them failing at `fail` (p floored at P_ATTEMPT_FLOOR; arrays work).

    >>> attempt_cost(10.0, 50.0, 1.0), attempt_cost(10.0, 50.0, 0.5)
    (10.0, 70.0)
    """
    q = np.maximum(np.asarray(p, dtype=np.float64), P_ATTEMPT_FLOOR)
    out = (cost + (1.0 - q) * fail) / q
    return float(out) if out.ndim == 0 else out


def redo_costs(model: "Model", classes: Mapping[str, str], back: float) -> np.ndarray:
    """What rebuilding a trip of k = 0..N blocks costs after its push failed (index k):
    the return push `back` (0 where the domain has none), k pickups at the mean expected
    pickup cost over the task's blocks (which blocks spill is not known to the plan), and
    the stacks onto 0..k-1 blocks, each at its expected number of attempts."""
    c = model.costs
    picks = [attempt_cost(c["pickup"], c["fail"], model.p_pickup[classes[b]]) for b in sorted(classes)]
    mean_pick = math.fsum(picks) / len(picks) if picks else 0.0
    stacks = attempt_cost(c["stack"], c["fail"], model.p_stack)
    n = len(model.p_stack)
    return back + mean_pick * np.arange(n + 1) + np.concatenate([[0.0], np.cumsum(stacks)])


def push_value(costs: Mapping[str, float], p, load, redo):
    """Expected utility of a push to goal of `load` blocks with success p, repeated until
    it delivers: 1/q attempts at the push cost, 1/q - 1 failing at the fail cost plus
    `redo` (the trip rebuilt), then deliver * load (q = p floored at P_ATTEMPT_FLOOR;
    arrays work).

    >>> push_value({"push": 30.0, "fail": 50.0, "deliver": 40.0}, 1.0, 2, 100.0)
    50.0
    >>> push_value({"push": 30.0, "fail": 50.0, "deliver": 40.0}, 0.5, 2, 100.0)
    -90.0
    """
    q = np.maximum(np.asarray(p, dtype=np.float64), P_ATTEMPT_FLOOR)
    out = (-attempt_cost(costs["push"], costs["fail"], q) - (1.0 / q - 1.0) * redo
           + costs["deliver"] * np.asarray(load, dtype=np.float64))
    return float(out) if np.ndim(out) == 0 else out


def optimistic_transition(n_blocks: int) -> dict:
    """T with every action succeeding (how TMOC starts, R-max style)."""
    if isinstance(n_blocks, bool) or not isinstance(n_blocks, numbers.Integral) or n_blocks < 1:
        raise PlanningError(f"n_blocks must be a positive integer, got {n_blocks!r}")
    return {"pickup": 1.0, "stack": [1.0] * int(n_blocks), "push": [1.0] * int(n_blocks)}


def is_number(value: object) -> bool:
    return isinstance(value, (numbers.Real, np.number)) and not isinstance(value, (bool, np.bool_))


def probability(value: object, field: str) -> float:
    if not is_number(value):
        raise PlanningError(f"{field}: expected a probability, got {value!r}")
    p = float(value)
    if not (math.isfinite(p) and 0.0 <= p <= 1.0):
        raise PlanningError(f"{field}: probability {p!r} is not in [0, 1]")
    return p


def probabilities(value: object, field: str, n: int, meaning: str) -> np.ndarray:
    # One block, one context: T gives an action whose only context is 0 as a number
    # (coordinator.transition.transition_model.to_planner), so a number stands for the list of one.
    if n == 1 and is_number(value):
        return np.array([probability(value, f"{field}[0]")])
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (Sequence, np.ndarray)):
        raise PlanningError(f"{field}: expected a list of {n} probabilities ({meaning}), "
                            f"got {value!r}")
    values = list(np.asarray(value, dtype=object).ravel()) if isinstance(value, np.ndarray) \
        else list(value)
    if len(values) != n:
        raise PlanningError(f"{field}: expected {n} probabilities ({meaning}), got {len(values)}")
    return np.array([probability(v, f"{field}[{i}]") for i, v in enumerate(values)])


def validate_costs(costs: Mapping | None) -> dict[str, float]:
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
        if not is_number(value) or not math.isfinite(float(value)) or float(value) < 0:
            raise PlanningError(f"costs: {key!r} must be a finite number >= 0, got {value!r}")
        merged[key] = float(value)
    return merged


def validate_transition(transition: Mapping, n_blocks: int, classes: set[str],
                         costs: Mapping | None) -> Model:
    if not isinstance(transition, Mapping):
        raise PlanningError(f"transition: expected a mapping with fields "
                            f"{', '.join(TRANSITION_FIELDS)}, got {type(transition).__name__}")
    for key in transition:
        if key not in TRANSITION_FIELDS + OPTIONAL_TRANSITION_FIELDS:
            raise PlanningError(f"transition: unknown field {key!r} (fields: "
                                f"{', '.join(TRANSITION_FIELDS + OPTIONAL_TRANSITION_FIELDS)})")
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
        p_pickup = {name: probability(p, f"pickup[{name!r}]") for name, p in pickup.items()}
    else:
        p = probability(pickup, "pickup")
        p_pickup = {name: p for name in classes}
    return Model(
        p_pickup=p_pickup,
        p_stack=probabilities(transition["stack"], "stack", n_blocks,
                               f"pile heights 0..{n_blocks - 1}"),
        p_push=probabilities(transition["push"], "push", n_blocks, f"loads 1..{n_blocks}"),
        costs=validate_costs(costs),
        **trial_counts(transition.get("trials"), n_blocks))


def trial_counts(trials: object, n_blocks: int) -> dict:
    """The optional ``trials`` field as Model's n_stack and n_push (PlanningError naming
    the field): a mapping with "stack" and/or "push", each n_blocks counts >= 0 ("pickup"
    is accepted and unused: every plan picks each block once)."""
    if trials is None:
        return {}
    if not isinstance(trials, Mapping):
        raise PlanningError(f"trials: expected a mapping with 'stack' and 'push', got {type(trials).__name__}")
    out = {}
    for key, field in (("stack", "n_stack"), ("push", "n_push")):
        if key not in trials:
            continue
        values = trials[key]
        if (isinstance(values, (str, bytes)) or not isinstance(values, Sequence) and not isinstance(values, np.ndarray)
                or len(values) != n_blocks):
            raise PlanningError(f"trials.{key}: expected {n_blocks} trial counts")
        if not all(is_number(v) and math.isfinite(float(v)) and float(v) >= 0 for v in values):
            raise PlanningError(f"trials.{key}: counts must be finite numbers >= 0")
        out[field] = np.asarray(values, dtype=np.float64)
    unknown = sorted(set(trials) - set(TRANSITION_FIELDS))
    if unknown:
        raise PlanningError(f"trials: unknown field {unknown[0]!r} (fields: {', '.join(TRANSITION_FIELDS)})")
    return out


def classes_of(blocks: Sequence[str], block_classes: Mapping[str, str] | None) -> dict[str, str]:
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


def simulate_plan(state: frozenset[str], actions: Sequence[str],
                  parse: Callable[[str], tuple[str, tuple[str, ...]]],
                  apply: Callable[[frozenset[str], str], frozenset[str]],
                  value: Callable[[str, tuple[str, ...], frozenset[str]], tuple[float, int | None]],
                  ) -> tuple[float, tuple[int, ...], frozenset[str]]:
    """A domain's plan simulated on its symbolic model: (the sum of each action's expected
    value, the loads the values report, the final state). `parse` checks an action,
    `apply` is its effect, `value(name, args, state)` its (expected value, load or None);
    an invalid step raises PlanningError naming it."""
    terms, loads = [], []
    for step, action in enumerate(actions, start=1):
        try:
            name, args = parse(action)
            term, load = value(name, args, state)
            state = apply(state, action)
        except ValueError as exc:
            raise PlanningError(f"step {step}: {exc}") from None
        terms.append(term)
        if load is not None:
            loads.append(load)
    return math.fsum(terms), tuple(loads), state


# The names stack-and-push and older callers used before the toolkit was public (issue 26).
_Model = Model
_is_number, _validate_transition, _block_classes = is_number, validate_transition, classes_of
