"""T: the probability that an action succeeds, per (action, context), learned from counts.

Contexts (container domain, design section 3):

* ``("pickup", 0)`` for every pickup (one context);
* ``("stack", k)``, k = blocks already in the container, 0 .. n_blocks - 1;
* ``("push", k)`` for a push to ``goal`` carrying k blocks, 1 .. n_blocks;
* ``None`` (not learned, p = 1) for the return push to ``init`` and for a push to goal of
  an empty container: neither can lose a block.

Estimator: a pseudo-count prior of ``prior_successes`` successful trials,

    p = (s + a) / (n + a),     s, n = weighted successes and trials, a = prior_successes.

It is exactly 1 before any data (optimistic, R-max in spirit: every action succeeds until
experience says otherwise) and its bias ``a (1 - rate) / (n + a)`` vanishes as weighted
trials grow, so it converges to the empirical success rate. A smooth estimator was chosen
over the hard R-max rule ("1 until m visits, then s/n") because fractional simulated
evidence has no natural visit count and a jump at m would make plans flip abruptly.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # only for the type hint of from_experience; no import cycle at runtime
    from coordinator.experience import ExperiencePool

__all__ = ["ACTION_NAMES", "TransitionModel", "context_of", "parse_term"]

ACTION_NAMES = ("pickup", "stack", "push")
_TERM = re.compile(r"^\s*([a-z_][A-Za-z0-9_]*)\s*\((.*)\)\s*$")


def parse_term(term: str) -> tuple[str, tuple[str, ...]]:
    """``"push(r,c,init,goal)"`` -> ``("push", ("r", "c", "init", "goal"))`` (flat terms)."""
    m = _TERM.match(term)
    if m is None:
        raise ValueError(f"not a ground term: {term!r}")
    args = tuple(a.strip() for a in m.group(2).split(",")) if m.group(2).strip() else ()
    return m.group(1), args


def _load(state: frozenset[str], container: str) -> int:
    """Number of ``at_container(_, container)`` atoms: blocks in that container."""
    k = 0
    for atom in state:
        if atom.startswith("at_container("):
            _, args = parse_term(atom)
            if len(args) == 2 and args[1] == container:
                k += 1
    return k


def context_of(state: frozenset[str], action: str) -> tuple[str, int] | None:
    """The (name, context) T learns for ``action`` taken in ``state``; None when not learned."""
    name, args = parse_term(action)
    arity = {"pickup": 3, "stack": 3, "push": 4}.get(name)
    if arity is None:
        raise ValueError(f"action {action!r}: unknown action name {name!r}")
    if len(args) != arity:
        raise ValueError(f"action {action!r}: {name} takes {arity} arguments")
    if name == "pickup":
        return ("pickup", 0)
    if name == "stack":
        return ("stack", _load(state, args[2]))
    if args[3] != "goal":  # the return push: always succeeds, not learned
        return None
    k = _load(state, args[1])
    return ("push", k) if k > 0 else None


@dataclass(eq=False)  # arrays inside: element-wise == would be ambiguous
class TransitionModel:
    """Weighted success counts per (action, context) and the probabilities they imply."""

    n_blocks: int
    prior_successes: float = 1.0
    # name -> (weighted successes, weighted trials) per context slot; see _slot for indexing
    successes: dict[str, np.ndarray] = field(default_factory=dict)
    trials: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if int(self.n_blocks) < 1:
            raise ValueError(f"n_blocks: must be >= 1, got {self.n_blocks}")
        self.n_blocks = int(self.n_blocks)
        if not (self.prior_successes >= 0 and math.isfinite(self.prior_successes)):
            raise ValueError(f"prior_successes: must be finite and >= 0, got {self.prior_successes}")
        self.prior_successes = float(self.prior_successes)
        sizes = {"pickup": 1, "stack": self.n_blocks, "push": self.n_blocks}
        for table in (self.successes, self.trials):
            for name, size in sizes.items():
                arr = np.zeros(size) if name not in table else np.array(table[name], dtype=np.float64)
                if arr.shape != (size,):
                    raise ValueError(f"{name}: expected {size} counts, got shape {arr.shape}")
                table[name] = arr

    def _slot(self, action_name: str, context: int) -> int:
        """Index into the count arrays; ValueError naming the bad (action, context)."""
        if action_name not in ACTION_NAMES:
            raise ValueError(f"action {action_name!r}: unknown (expected one of {ACTION_NAMES})")
        k = int(context)
        n = self.n_blocks
        valid = {"pickup": (0, 0), "stack": (0, n - 1), "push": (1, n)}[action_name]
        if not valid[0] <= k <= valid[1]:
            raise ValueError(
                f"context {k} invalid for {action_name!r} with {n} blocks "
                f"(valid {valid[0]}..{valid[1]})"
            )
        return k - 1 if action_name == "push" else k

    def add_counts(self, action_name: str, context: int, successes: float, trials: float) -> None:
        """Add already-weighted evidence (used when rebuilding T from a pool)."""
        if not (0 <= successes <= trials and math.isfinite(trials)):
            raise ValueError(f"counts: need 0 <= successes <= trials, got {successes}, {trials}")
        i = self._slot(action_name, context)
        self.successes[action_name][i] += successes
        self.trials[action_name][i] += trials

    def observe(self, action_name: str, context: int, success: bool, weight: float = 1.0) -> None:
        """One outcome of an action in a context, counted as ``weight`` trials."""
        if not (weight >= 0 and math.isfinite(weight)):
            raise ValueError(f"weight: must be finite and >= 0, got {weight}")
        self.add_counts(action_name, context, weight if success else 0.0, weight)

    def observe_transition(self, state: frozenset[str], action: str, success: bool,
                           weight: float = 1.0) -> None:
        """``observe`` with the context read off the state; unlearned actions are skipped."""
        ctx = context_of(state, action)
        if ctx is not None:
            self.observe(ctx[0], ctx[1], success, weight)

    def probability(self, action_name: str, context: int) -> float:
        """(s + a) / (n + a); 1.0 when there is neither data nor prior."""
        i = self._slot(action_name, context)
        s = float(self.successes[action_name][i])
        n = float(self.trials[action_name][i])
        denom = n + self.prior_successes
        return 1.0 if denom <= 0 else (s + self.prior_successes) / denom

    def probability_of(self, state: frozenset[str], action: str) -> float:
        """p for a concrete action in a concrete state (1.0 for unlearned actions)."""
        ctx = context_of(state, action)
        return 1.0 if ctx is None else self.probability(*ctx)

    def to_planner(self) -> dict:
        """``{"pickup": p, "stack": [p_0..p_{n-1}], "push": [p_1..p_n]}`` for the task planner
        (stack index = blocks already in the container, push index k-1 = load k)."""
        n = self.n_blocks
        return {
            "pickup": self.probability("pickup", 0),
            "stack": [self.probability("stack", k) for k in range(n)],
            "push": [self.probability("push", k) for k in range(1, n + 1)],
        }

    def to_dict(self) -> dict:
        """Exact, JSON-able state (Python floats round-trip bit for bit)."""
        return {
            "n_blocks": self.n_blocks,
            "prior_successes": self.prior_successes,
            "successes": {k: v.tolist() for k, v in self.successes.items()},
            "trials": {k: v.tolist() for k, v in self.trials.items()},
        }

    @classmethod
    def from_dict(cls, data: dict) -> "TransitionModel":
        return cls(
            n_blocks=int(data["n_blocks"]),
            prior_successes=float(data["prior_successes"]),
            successes={k: np.array(v, dtype=np.float64) for k, v in data["successes"].items()},
            trials={k: np.array(v, dtype=np.float64) for k, v in data["trials"].items()},
        )

    @classmethod
    def from_experience(
        cls,
        pool: "ExperiencePool",
        n_blocks: int,
        *,
        sim_weight: float = 1.0,
        prior_successes: float = 1.0,
    ) -> "TransitionModel":
        """T rebuilt from a pool: real evidence at weight 1, simulated at weight * sim_weight.

        One action's simulated outcomes carry particle weights summing to 1, so they count
        as ``sim_weight`` trials in all. ``sim_weight = 0`` learns from real experience
        only (the TMP-RL baseline). Default 1: the belief's predicted outcome distribution
        counts as much as one real trial.
        """
        if not (sim_weight >= 0 and math.isfinite(sim_weight)):
            raise ValueError(f"sim_weight: must be finite and >= 0, got {sim_weight}")
        model = cls(n_blocks=n_blocks, prior_successes=prior_successes)
        counts = pool.counts()
        for (name, ctx), (s, n) in counts["real"].items():
            model.add_counts(name, ctx, s, n)
        if sim_weight > 0:
            for (name, ctx), (s, n) in counts["sim"].items():
                model.add_counts(name, ctx, s * sim_weight, n * sim_weight)
        return model
