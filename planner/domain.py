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

import abc
from dataclasses import dataclass
from typing import ClassVar, Iterable, Mapping, Sequence

import numpy as np

Context = tuple[str, int]


class PlanningError(ValueError):
    """The planner cannot answer: bad T or costs, a malformed state, an unreachable goal."""


@dataclass(frozen=True)
class Plan:
    """A plan and what it is worth under the transition model and costs it was made for."""

    actions: tuple[str, ...]      # ASP terms in text, objects named
    loads: tuple[int, ...]        # objects each trip moves to the goal, in order
    expected_utility: float       # under T and costs (float, unscaled)
    optimal: bool                 # optimality proven by clingo
    solve_ms: float               # wall time of the call, grounding included

    def to_dict(self) -> dict:
        """JSON-ready form; ``plan`` is the list of actions."""
        return {"plan": list(self.actions), "loads": list(self.loads),
                "expected_utility": float(self.expected_utility),
                "optimal": bool(self.optimal), "solve_ms": float(self.solve_ms)}


# A solid object's density (kg/m^3) as a request may set it: the bounds of
# ``sim_workers.properties`` (MIN_DENSITY, MAX_DENSITY), which the physics half checks
# again (tests/coordinator/test_domain_kit.py compares them).
DENSITY_BOUNDS = {"gt": 1.0, "le": 25000.0}


class TaskDomain(abc.ABC):
    """The symbolic model, T's contexts, utility terms and planner of one domain.

    A domain's task half subclasses this, sets the class attributes and implements the
    abstract methods; the others have defaults. ``http_options`` and ``http_truth`` say
    what a task or session request may set over HTTP (``api.schemas`` builds the domain's
    request model from them): ``{name: {type, description, ge/gt/le/lt}}``, each valid on
    its own whatever the others say.
    """

    name: ClassVar[str]
    action_names: ClassVar[tuple[str, ...]]
    default_costs: ClassVar[Mapping[str, float]]     # action costs, "fail" and the reward terms
    http_options: ClassVar[Mapping[str, dict]] = {}
    http_truth: ClassVar[Mapping[str, dict]] = {}
    # Optional transition fields `plan` reads besides the success rates: "trials" (the trials
    # behind each estimate, per context, as ``TransitionModel.trial_counts`` gives them)
    # breaks ties between plans of equal expected utility by evidence (planner.blocks).
    transition_extras: ClassVar[tuple[str, ...]] = ()

    @abc.abstractmethod
    def initial_state(self, n_blocks: int) -> frozenset[str]: ...

    @abc.abstractmethod
    def parse_state(self, atoms: Iterable[str]) -> frozenset[str]:
        """The state these atoms name (ValueError naming the first bad atom)."""

    @abc.abstractmethod
    def blocks(self, state: frozenset[str]) -> list[str]: ...

    @abc.abstractmethod
    def apply(self, state: frozenset[str], action: str) -> frozenset[str]:
        """The state after `action` succeeds (ValueError: an unmet precondition)."""

    @abc.abstractmethod
    def is_goal(self, state: frozenset[str]) -> bool: ...

    @abc.abstractmethod
    def contexts(self, n_blocks: int) -> tuple[Context, ...]:
        """Every context T learns, in order."""

    @abc.abstractmethod
    def context_of(self, state: frozenset[str], action: str) -> Context | None:
        """The context of `action` in `state` (None: certain, not learned; UnknownAction
        for an action the domain does not define)."""

    @abc.abstractmethod
    def optimistic_transition(self, n_blocks: int) -> dict:
        """T before any experience, in the planner's form."""

    @abc.abstractmethod
    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             max_steps: int | None = None, time_limit: float = 30.0):
        """The maximum-expected-utility plan from `state` under `transition` (a Plan)."""

    @abc.abstractmethod
    def satisficing(self, state: Iterable[str], *, rng: np.random.Generator,
                    transition: Mapping | None = None, costs: Mapping | None = None):
        """A plan that reaches the goal without optimising (the baselines' planner)."""

    @abc.abstractmethod
    def expected_utility(self, state: Iterable[str], actions: Sequence[str], transition: Mapping,
                         costs: Mapping | None = None) -> float: ...

    @abc.abstractmethod
    def step_reward(self, state: frozenset[str], action: str, next_state: frozenset[str],
                    costs: Mapping[str, float]) -> tuple[float, dict]:
        """The realised reward terms of one step and its metrics."""

    def grounded_actions(self, n_blocks: int) -> tuple[str, ...]:
        """Every grounded action of a task of `n_blocks` objects, in a fixed order (the
        discrete actions of the Gymnasium view, ``coordinator.integrations.gym_env``)."""
        raise NotImplementedError(f"domain {self.name!r} does not list its grounded actions")

    def atoms(self, n_blocks: int) -> tuple[str, ...]:
        """Every atom a state of `n_blocks` objects can hold, planned or observed by Y^-1,
        in a fixed order (the Gymnasium view's symbolic observation)."""
        raise NotImplementedError(f"domain {self.name!r} does not list its atoms")

    def actions_for_loads(self, n_blocks: int, loads: Sequence[int]) -> list[str]:
        """The plan that moves `loads` objects per trip in turn (the experiments judge a
        plan's split against T*'s optimum with it)."""
        raise NotImplementedError(f"domain {self.name!r} does not describe plans by loads")


class UnknownAction(ValueError):
    """An action (or its context) that the domain does not define: never a silent None."""
