"""The task half of a domain: what the planner, T and the loop need (no physics here).

A domain is two halves joined by name in ``coordinator.domains``: a physics half in
``sim_workers`` (scene, Y, Y^-1, measurements, the prior over L) that Ray shards import,
and this task half (symbolic model, T's contexts, utility terms, the ASP planner) that
the coordinator imports. ``planner`` and ``sim_workers`` never import each other.

T's contexts are data: a context is ``(action name, integer)`` (e.g. ``("push", 3)``: a
push with three blocks loaded). Every context a domain can return is listed by
``contexts(n_blocks)``; the learned T is a success probability per context, and the
planner receives it grouped by action name: ``{name: p}`` for an action with the single
context index 0, else ``{name: [p for index in order]}``.
"""
from __future__ import annotations

from typing import Iterable, Mapping, Protocol, Sequence

import numpy as np

Context = tuple[str, int]


class TaskDomain(Protocol):
    """The symbolic model, T's contexts, utility terms and planner of one domain."""

    name: str
    action_names: tuple[str, ...]
    default_costs: Mapping[str, float]     # action costs, "fail" and the reward terms

    def initial_state(self, n_blocks: int) -> frozenset[str]: ...
    def parse_state(self, atoms: Iterable[str]) -> frozenset[str]: ...      # ValueError names the atom
    def blocks(self, state: frozenset[str]) -> list[str]: ...
    def apply(self, state: frozenset[str], action: str) -> frozenset[str]: ...  # ValueError: unmet precondition
    def is_goal(self, state: frozenset[str]) -> bool: ...
    def contexts(self, n_blocks: int) -> tuple[Context, ...]: ...
    def context_of(self, state: frozenset[str], action: str) -> Context | None: ...
    def optimistic_transition(self, n_blocks: int) -> dict: ...
    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             max_steps: int | None = None, time_limit: float = 30.0): ...            # -> Plan
    def satisficing(self, state: Iterable[str], *, rng: np.random.Generator,
                    transition: Mapping | None = None, costs: Mapping | None = None): ...  # -> Plan
    def expected_utility(self, state: Iterable[str], actions: Sequence[str], transition: Mapping,
                         costs: Mapping | None = None) -> float: ...
    def step_reward(self, state: frozenset[str], action: str, next_state: frozenset[str],
                    costs: Mapping[str, float]) -> tuple[float, dict]: ...


class UnknownAction(ValueError):
    """An action (or its context) that the domain does not define: never a silent None."""
