"""The container domain's task half (``planner.domain.TaskDomain``): its symbolic model
(``symbolic``), T's contexts, utility terms, its expected utility (``model``) and the
clingo planner (``planner``, on the block-world toolkit ``planner.blocks``), behind the
one protocol the loop speaks."""
from __future__ import annotations

from typing import Iterable, Mapping, Sequence

import numpy as np

from planner.container import model as task_model, planner as task_planner, symbolic
from planner.domain import DENSITY_BOUNDS, Context, TaskDomain, UnknownAction
from planner.terms import parse_term

_ARITY = {"pickup": 3, "stack": 3, "push": 4}


def _parse_term(term: str) -> tuple[str, tuple[str, ...]]:
    return parse_term(term, "action", UnknownAction)


def _load(state: frozenset[str], container: str) -> int:
    """Number of ``at_container(_, container)`` atoms: blocks in that container."""
    k = 0
    for atom in state:
        if atom.startswith("at_container("):
            _, args = _parse_term(atom)
            if len(args) == 2 and args[1] == container:
                k += 1
    return k


def context_of(state: frozenset[str], action: str) -> Context | None:
    """The (name, context) T learns for ``action`` taken in ``state``.

    pickup -> ("pickup", 0); stack -> ("stack", blocks already in the container); push to
    goal with k > 0 blocks -> ("push", k). None (p = 1, not learned) only for the return
    push and an empty push, which cannot lose a block. Any other action raises.
    """
    name, args = _parse_term(action)
    arity = _ARITY.get(name)
    if arity is None:
        raise UnknownAction(f"action {action!r}: unknown action name {name!r}")
    if len(args) != arity:
        raise UnknownAction(f"action {action!r}: {name} takes {arity} arguments")
    if name == "pickup":
        return ("pickup", 0)
    if name == "stack":
        return ("stack", _load(state, args[2]))
    if args[3] != "goal":  # the return push: always succeeds, not learned
        return None
    k = _load(state, args[1])
    return ("push", k) if k > 0 else None


def load_actions(loads: Sequence[int]) -> list[str]:
    """The plan that carries `loads` blocks per trip (blocks in order)."""
    actions, b = [], 1
    for i, k in enumerate(loads):
        for _ in range(int(k)):
            actions += [f"pickup(r,b{b},init)", f"stack(r,b{b},c)"]
            b += 1
        actions.append("push(r,c,init,goal)")
        if i < len(loads) - 1:
            actions.append("push(r,c,goal,init)")
    return actions


class ContainerTask(TaskDomain):
    """Blocks carried to the goal in an open container: pickup 15, stack 10, push 30, fail
    50, +40 per block delivered, +80 once all are."""

    name = "container"
    action_names = ("pickup", "stack", "push")
    default_costs = dict(task_model.DEFAULT_COSTS)
    transition_extras = ("trials",)       # ties between equal plans broken by evidence
    # Over HTTP: the density is known to the agent (L is the size alone).
    http_truth = {"density": {"type": float, **DENSITY_BOUNDS,
                              "description": "the blocks' density (kg/m^3), known to the agent"}}

    def initial_state(self, n_blocks: int) -> frozenset[str]:
        return symbolic.initial_state(n_blocks)

    def parse_state(self, atoms: Iterable[str]) -> frozenset[str]:
        return symbolic.parse_state(atoms)

    def blocks(self, state: frozenset[str]) -> list[str]:
        return symbolic.blocks(state)

    def apply(self, state: frozenset[str], action: str) -> frozenset[str]:
        return symbolic.apply(state, action)

    def is_goal(self, state: frozenset[str]) -> bool:
        return symbolic.is_goal(state)

    def contexts(self, n_blocks: int) -> tuple[Context, ...]:
        n = int(n_blocks)
        return (("pickup", 0),) + tuple(("stack", k) for k in range(n)) \
            + tuple(("push", k) for k in range(1, n + 1))

    def grounded_actions(self, n_blocks: int) -> tuple[str, ...]:
        bs = [f"b{i}" for i in range(1, int(n_blocks) + 1)]
        return tuple(f"pickup(r,{b},{p})" for b in bs for p in symbolic.PICKUP_PLACES) \
            + tuple(f"stack(r,{b},c)" for b in bs) + ("push(r,c,init,goal)", "push(r,c,goal,init)")

    def atoms(self, n_blocks: int) -> tuple[str, ...]:
        bs = [f"b{i}" for i in range(1, int(n_blocks) + 1)]
        return tuple(f"is_in({b},{p})" for b in bs for p in symbolic.BLOCK_PLACES) \
            + tuple(f"is_holding(r,{b})" for b in bs) + tuple(f"at_container({b},c)" for b in bs) \
            + tuple(f"is_in(c,{p})" for p in symbolic.CONTAINER_PLACES) + ("hand_empty(r)",)

    def context_of(self, state: frozenset[str], action: str) -> Context | None:
        return context_of(state, action)

    def optimistic_transition(self, n_blocks: int) -> dict:
        return task_model.optimistic_transition(n_blocks)

    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             block_classes: Mapping[str, str] | None = None, max_steps: int | None = None,
             time_limit: float = task_planner.DEFAULT_TIME_LIMIT_S):
        return task_planner.plan(state, transition, costs, block_classes=block_classes,
                                 max_steps=max_steps, time_limit=time_limit)

    def satisficing(self, state: Iterable[str], *, rng: np.random.Generator,
                    transition: Mapping | None = None, costs: Mapping | None = None):
        return task_planner.satisficing(state, rng=rng, transition=transition, costs=costs)

    def expected_utility(self, state: Iterable[str], actions: Sequence[str], transition: Mapping,
                         costs: Mapping | None = None) -> float:
        return task_model.expected_utility(state, actions, transition, costs)

    def actions_for_loads(self, n_blocks: int, loads: Sequence[int]) -> list[str]:
        return load_actions(loads)

    def step_reward(self, state: frozenset[str], action: str, next_state: frozenset[str],
                    costs: Mapping[str, float]) -> tuple[float, dict]:
        """Realised reward terms of a step: +deliver per block newly at goal, +all_delivered
        when the goal is reached; metrics `delivered` (blocks newly at goal) and `load`
        (blocks in the container on a push to goal, else None)."""
        load = None
        if action.startswith("push") and action.endswith("goal)"):
            load = sum(a.startswith("at_container(") for a in state)
        delivered = lambda st: sum(a.startswith("is_in(b") and a.endswith(",goal)") for a in st)  # noqa: E731
        gained = delivered(next_state) - delivered(state)
        reward = costs["deliver"] * gained
        if symbolic.is_goal(next_state):
            reward += costs["all_delivered"]
        return reward, {"delivered": gained, "load": load}


TASK = ContainerTask()
