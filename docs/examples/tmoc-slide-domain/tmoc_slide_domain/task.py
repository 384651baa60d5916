"""Slide's task half: each puck waiting, placed on the line or lost past it.

There is one context, ("push", 0): T learns how often a push places its puck. Every plan
pushes each waiting puck once, so there is no choice to optimise and no solver is needed:
``plan`` lists them and says what they are worth under T. (A domain whose plans differ in
value hands the choice to clingo, as the chute does.)
"""
from __future__ import annotations

import time
from typing import Iterable, Mapping, Sequence

import numpy as np

from planner.domain import Context, Plan, PlanningError, TaskDomain, UnknownAction
from planner.terms import parse_term

DEFAULT_COSTS = {"push": 10.0, "fail": 20.0, "place": 30.0, "all_placed": 40.0}
STATES = ("waiting", "placed", "lost")


def _puck(action: str) -> str:
    name, args = parse_term(action, "action", UnknownAction)
    if name != "push" or len(args) != 1 or not args[0].startswith("p") or not args[0][1:].isdigit():
        raise UnknownAction(f"action {action!r}: slide's one action is push(pJ)")
    return args[0]


def pucks_in(state: Iterable[str], kind: str) -> list[str]:
    """The pucks whose atom in `state` is `kind` (waiting, placed or lost), in order."""
    found = [parse_term(a)[1][0] for a in state if a.startswith(kind + "(")]
    return sorted(found, key=lambda p: int(p[1:]))


def _p_push(transition: Mapping) -> float:
    p = transition.get("push") if isinstance(transition, Mapping) else None
    p = p[0] if isinstance(p, (list, tuple)) and len(p) == 1 else p
    if isinstance(p, bool) or not isinstance(p, (int, float, np.number)) or not 0.0 <= float(p) <= 1.0:
        raise PlanningError(f"transition.push: expected a probability, got {p!r}")
    return float(p)


class SlideTask(TaskDomain):
    """Push 10, a failed push 20 more, +30 per puck placed, +40 once all are."""

    name = "slide"
    action_names = ("push",)
    default_costs = dict(DEFAULT_COSTS)
    http_truth = {"friction": {"type": float, "ge": 0.02, "le": 2.0,
                               "description": "the pucks' friction coefficient on the table"}}

    # -- the symbolic model ---------------------------------------------------------------
    def initial_state(self, n_blocks: int) -> frozenset[str]:
        return frozenset(f"waiting(p{i + 1})" for i in range(int(n_blocks)))

    def parse_state(self, atoms: Iterable[str]) -> frozenset[str]:
        seen: dict[str, str] = {}
        for atom in atoms:
            kind, args = parse_term(atom, "atom")
            if kind not in STATES or len(args) != 1:
                raise ValueError(f"atom {atom!r}: expected waiting(pJ), placed(pJ) or lost(pJ)")
            if seen.setdefault(args[0], kind) != kind:
                raise ValueError(f"atom {atom!r}: {args[0]} is also {seen[args[0]]}")
        return frozenset(f"{k}({p})" for p, k in seen.items())

    def blocks(self, state: frozenset[str]) -> list[str]:
        return sorted((parse_term(a)[1][0] for a in state), key=lambda p: int(p[1:]))

    def apply(self, state: frozenset[str], action: str) -> frozenset[str]:
        p = _puck(action)
        if f"waiting({p})" not in state:
            raise ValueError(f"action {action!r}: {p} is not waiting")
        return (state - {f"waiting({p})"}) | {f"placed({p})"}

    def is_goal(self, state: frozenset[str]) -> bool:
        return not pucks_in(state, "waiting")

    def grounded_actions(self, n_blocks: int) -> tuple[str, ...]:
        return tuple(f"push(p{i + 1})" for i in range(int(n_blocks)))

    def atoms(self, n_blocks: int) -> tuple[str, ...]:
        return tuple(f"{k}(p{i + 1})" for i in range(int(n_blocks)) for k in STATES)

    # -- T's contexts ---------------------------------------------------------------------
    def contexts(self, n_blocks: int) -> tuple[Context, ...]:
        return (("push", 0),)

    def context_of(self, state: frozenset[str], action: str) -> Context | None:
        return ("push", 0) if f"waiting({_puck(action)})" in state else None

    def optimistic_transition(self, n_blocks: int) -> dict:
        return {"push": 1.0}

    # -- planning -------------------------------------------------------------------------
    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             max_steps: int | None = None, time_limit: float = 30.0) -> Plan:
        t0 = time.perf_counter()
        state = self.parse_state(state)
        actions = tuple(f"push({p})" for p in pucks_in(state, "waiting"))
        if max_steps is not None and len(actions) > max_steps:
            raise PlanningError(f"max_steps: {len(actions)} pucks wait to be pushed")
        eu = self.expected_utility(state, actions, transition, costs)
        return Plan(actions, (1,) * len(actions), eu, True, (time.perf_counter() - t0) * 1000.0)

    def satisficing(self, state: Iterable[str], *, rng: np.random.Generator,
                    transition: Mapping | None = None, costs: Mapping | None = None) -> Plan:
        """The waiting pucks in a random order (every order is worth the same)."""
        state = self.parse_state(state)
        waiting = pucks_in(state, "waiting")
        actions = tuple(f"push({waiting[i]})" for i in rng.permutation(len(waiting)))
        eu = self.expected_utility(state, actions, transition or self.optimistic_transition(len(waiting)), costs)
        return Plan(actions, (1,) * len(actions), eu, False, 0.0)

    def expected_utility(self, state: Iterable[str], actions: Sequence[str], transition: Mapping,
                         costs: Mapping | None = None) -> float:
        """Each push: -push - (1 - p) fail + p place; + p^n all_placed for n pushes that
        must all succeed (none placed or lost before)."""
        c = {**DEFAULT_COSTS, **(dict(costs) if costs else {})}
        state, p = self.parse_state(state), _p_push(transition)
        n = sum(1 for a in actions if self.context_of(state, a) is not None)
        total = n * (p * c["place"] - c["push"] - (1.0 - p) * c["fail"])
        if n and n == len(pucks_in(state, "waiting")) and not pucks_in(state, "lost"):
            total += p ** n * c["all_placed"]
        return float(total)

    def step_reward(self, state: frozenset[str], action: str, next_state: frozenset[str],
                    costs: Mapping[str, float]) -> tuple[float, dict]:
        """+place per puck newly placed, +all_placed when every puck is; metric
        ``delivered``: the pucks placed."""
        gained = len(pucks_in(next_state, "placed")) - len(pucks_in(state, "placed"))
        reward = costs["place"] * max(gained, 0)
        if not pucks_in(next_state, "waiting") and not pucks_in(next_state, "lost") and pucks_in(state, "waiting"):
            reward += costs["all_placed"]
        return reward, {"delivered": max(gained, 0), "load": 1}
