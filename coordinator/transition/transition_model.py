"""T: the probability that an action succeeds, per (action, context), learned from counts.

A context is ``(action name, integer)``; which contexts exist and how a (state, action)
maps to one is the domain's data (``planner.domain.TaskDomain.contexts`` and
``context_of``), passed in as ``contexts`` and ``context_fn``. An action or context the
domain does not list is an error, never a silent None. Without them, T uses the
container's (below), so existing callers and checkpoints keep working.

Contexts of the container domain (docs/BUILTIN_DOMAINS.md, "The container domain"):

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

Simulated evidence where reality disagrees (issue 24). Each real action adds one real
trial and one unit of simulated trials, so where the particle worlds predict success and
the robot fails every time, T would stay near one half for ever. Simulated counts enter
each context discounted by a factor delta in [0, 1], a *power prior* (Ibrahim and Chen
2000): the simulated outcomes are a prior for the real ones, raised to the power delta,
and delta is weighed by how well that prior predicts the real outcomes seen so far (the
posterior mean of delta under a uniform prior, from the beta-binomial marginal likelihood;
``sim_discount``). With no real trial yet delta is 1; where they agree its posterior mean
is about 0.55-0.6, not 1 (the marginal likelihood grows only slowly with delta when both
agree: 0.57 for 5 successes in 5 trials of each, see the doctest), so simulated counts
enter at about half weight; where reality contradicts the worlds delta falls towards 0
within a few real trials (0.12 for 0 in 5 against 5 in 5) and T follows the real rate.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from planner.terms import parse_term   # re-exported: the one parser of ground terms

if TYPE_CHECKING:  # only for the type hint of from_experience; no import cycle at runtime
    from coordinator.transition.experience import ExperiencePool

__all__ = ["TransitionModel", "parse_term", "transition_table"]


@dataclass(eq=False)  # arrays inside: element-wise == would be ambiguous
class TransitionModel:
    """Weighted success counts per (action, context) and the probabilities they imply.

    >>> from planner.container import TASK      # (any domain's task half)
    >>> t = TransitionModel.for_task(TASK, 2)
    >>> t.observe("push", 2, success=False); t.observe("push", 2, success=True)
    >>> t.probability("push", 2), t.probability("push", 1)
    (0.6666666666666666, 1.0)
    >>> t.to_planner()
    {'pickup': 1.0, 'stack': [1.0, 1.0], 'push': [1.0, 0.6666666666666666]}
    """

    n_blocks: int
    prior_successes: float = 1.0
    # name -> (weighted successes, weighted trials) per context slot; see _slot for indexing
    successes: dict[str, np.ndarray] = field(default_factory=dict)
    trials: dict[str, np.ndarray] = field(default_factory=dict)
    # The domain's contexts (its task half's contexts(n_blocks)) and context_of: required
    # (the model knows no domain; ``for_task`` takes both from a task half).
    contexts: Sequence[tuple[str, int]] | None = None
    context_fn: Callable | None = field(default=None, repr=False)
    # (action, context) -> the power prior's delta applied to its simulated counts (only
    # contexts with simulated evidence, and only when built with discount=True)
    discounts: dict = field(default_factory=dict, repr=False)
    # action family -> the power prior's delta applied to its counterfactual counts
    cf_discounts: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if int(self.n_blocks) < 1:
            raise ValueError(f"n_blocks: must be >= 1, got {self.n_blocks}")
        self.n_blocks = int(self.n_blocks)
        if not (self.prior_successes >= 0 and math.isfinite(self.prior_successes)):
            raise ValueError(f"prior_successes: must be finite and >= 0, got {self.prior_successes}")
        self.prior_successes = float(self.prior_successes)
        if self.contexts is None or self.context_fn is None:
            raise ValueError("contexts, context_fn: required, the task half's contexts(n_blocks) "
                             "and context_of (TransitionModel.for_task)")
        self.contexts = tuple((str(a), int(k)) for a, k in self.contexts)
        # name -> sorted context indices; slot i of a name's arrays is its i-th index
        self._index: dict[str, list[int]] = {}
        for name, k in self.contexts:
            self._index.setdefault(name, []).append(k)
        for name in self._index:
            self._index[name] = sorted(set(self._index[name]))
        for table in (self.successes, self.trials):
            for name in list(table):
                if name not in self._index:
                    raise ValueError(f"{name}: not an action with contexts (known: {', '.join(self._index)})")
            for name, ks in self._index.items():
                size = len(ks)
                arr = np.zeros(size) if name not in table else np.array(table[name], dtype=np.float64)
                if arr.shape != (size,):
                    raise ValueError(f"{name}: expected {size} counts, got shape {arr.shape}")
                table[name] = arr

    @property
    def action_names(self) -> tuple[str, ...]:
        return tuple(self._index)

    def _slot(self, action_name: str, context: int) -> int:
        """Index into the count arrays; ValueError naming the bad (action, context)."""
        if action_name not in self._index:
            raise ValueError(f"action {action_name!r}: unknown (expected one of {tuple(self._index)})")
        k = int(context)
        ks = self._index[action_name]
        if k not in ks:
            n = self.n_blocks
            raise ValueError(
                f"context {k} invalid for {action_name!r} with {n} blocks "
                f"(valid {ks[0]}..{ks[-1]})"
            )
        return ks.index(k)

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
        """``observe`` with the context read off the state; unlearned actions are skipped.

        >>> full = frozenset({"at_container(b1,c)", "at_container(b2,c)"})
        >>> from planner.container import TASK
        >>> t = TransitionModel.for_task(TASK, 2)
        >>> t.observe_transition(full, "push(r,c,init,goal)", success=False)   # context push 2
        >>> t.probability_of(full, "push(r,c,init,goal)"), t.probability_of(full, "push(r,c,goal,init)")
        (0.5, 1.0)
        """
        ctx = self.context_fn(state, action)
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
        ctx = self.context_fn(state, action)
        return 1.0 if ctx is None else self.probability(*ctx)

    def to_planner(self) -> dict:
        """T for the task planner, grouped by action name: ``{name: p}`` for an action whose
        only context is 0, else ``{name: [p per context index, in order]}``. For the
        container: ``{"pickup": p, "stack": [p_0..p_{n-1}], "push": [p_1..p_n]}`` (stack
        index = blocks already in the container, push index k-1 = load k)."""
        out: dict = {}
        for name, ks in self._index.items():
            ps = [self.probability(name, k) for k in ks]
            out[name] = ps[0] if ks == [0] else ps
        return out

    def trial_counts(self) -> dict:
        """The (weighted) trials behind each estimate, as ``to_planner`` lays out the
        estimates, for the actions with more than one context: what a task half that
        breaks ties by evidence reads (``TaskDomain.transition_extras``)."""
        return {name: self.trials[name].tolist() for name, ks in self._index.items() if ks != [0]}

    def to_dict(self) -> dict:
        """Exact, JSON-able state (Python floats round-trip bit for bit)."""
        out = {
            "n_blocks": self.n_blocks,
            "prior_successes": self.prior_successes,
            "successes": {k: v.tolist() for k, v in self.successes.items()},
            "trials": {k: v.tolist() for k, v in self.trials.items()},
        }
        out["contexts"] = [list(c) for c in self.contexts]
        return out

    @classmethod
    def for_task(cls, task, n_blocks: int, **kwargs) -> "TransitionModel":
        """An empty T over a task half's contexts (``planner.domain.TaskDomain``)."""
        return cls(n_blocks, contexts=task.contexts(int(n_blocks)), context_fn=task.context_of, **kwargs)

    @classmethod
    def from_dict(cls, data: dict, context_fn: Callable, contexts: Sequence | None = None) -> "TransitionModel":
        """From ``to_dict``; `contexts` for data that does not carry its own."""
        contexts = data.get("contexts", contexts)
        return cls(
            n_blocks=int(data["n_blocks"]),
            prior_successes=float(data["prior_successes"]),
            successes={k: np.array(v, dtype=np.float64) for k, v in data["successes"].items()},
            trials={k: np.array(v, dtype=np.float64) for k, v in data["trials"].items()},
            contexts=None if contexts is None else [tuple(c) for c in contexts],
            context_fn=context_fn,
        )

    @classmethod
    def from_experience(
        cls,
        pool: "ExperiencePool",
        n_blocks: int,
        *,
        sim_weight: float = 1.0,
        prior_successes: float = 1.0,
        contexts: Sequence[tuple[str, int]] | None = None,
        context_fn: Callable | None = None,
        discount: bool = False,
        counterfactual: dict | None = None,
    ) -> "TransitionModel":
        """T rebuilt from a pool: real evidence at weight 1, simulated at weight * sim_weight.

        One action's simulated outcomes carry particle weights summing to 1, so they count
        as ``sim_weight`` trials in all. ``sim_weight = 0`` learns from real experience
        only (the TMP-RL baseline). Default 1: the belief's predicted outcome distribution
        counts as much as one real trial.

        >>> from coordinator.transition.experience import ExperiencePool
        >>> from planner.container import TASK
        >>> full, one = frozenset({"at_container(b1,c)", "at_container(b2,c)"}), frozenset({"at_container(b1,c)"})
        >>> pool = ExperiencePool(TASK.context_of)
        >>> on = dict(contexts=TASK.contexts(2), context_fn=TASK.context_of)
        >>> pool.add_real(full, "push(r,c,init,goal)", one, full)          # a block fell
        >>> pool.add_simulated(full, "push(r,c,init,goal)", [full, one], full, np.array([0.75, 0.25]))
        >>> round(TransitionModel.from_experience(pool, 2, **on).probability("push", 2), 4)   # (0 + 0.75 + 1) / (1 + 1 + 1)
        0.5833
        >>> TransitionModel.from_experience(pool, 2, sim_weight=0, **on).probability("push", 2)
        0.5

        With ``discount`` each context's simulated counts are scaled by ``sim_discount``
        (module docstring): three real failures where the worlds predicted three successes
        leave little of the simulated evidence.

        >>> pool = ExperiencePool(TASK.context_of)
        >>> for _ in range(3):
        ...     pool.add_real(full, "push(r,c,init,goal)", one, full)
        ...     pool.add_simulated(full, "push(r,c,init,goal)", [full], full, np.array([1.0]))
        >>> round(TransitionModel.from_experience(pool, 2, **on).probability("push", 2), 3)
        0.571
        >>> t = TransitionModel.from_experience(pool, 2, discount=True, **on)
        >>> round(t.probability("push", 2), 3), round(t.discounts[("push", 2)], 3)
        (0.367, 0.246)
        """
        if not (sim_weight >= 0 and math.isfinite(sim_weight)):
            raise ValueError(f"sim_weight: must be finite and >= 0, got {sim_weight}")
        model = cls(n_blocks=n_blocks, prior_successes=prior_successes, contexts=contexts,
                    context_fn=context_fn)
        counts = pool.counts()
        for (name, ctx), (s, n) in counts["real"].items():
            model.add_counts(name, ctx, s, n)
        if sim_weight > 0:
            for (name, ctx), (s, n) in counts["sim"].items():
                delta = 1.0
                if discount:
                    delta = sim_discount(*counts["real"].get((name, ctx), (0.0, 0.0)),
                                         s * sim_weight, n * sim_weight)
                    model.discounts[(name, ctx)] = delta
                model.add_counts(name, ctx, s * sim_weight * delta, n * sim_weight * delta)
        if counterfactual:
            model.add_counterfactual(counterfactual, counts["real"], discount)
        return model

    def add_counterfactual(self, counts: dict, real: dict, discount: bool = True) -> None:
        """Add a counterfactual snapshot's (successes, trials) per context
        (``coordinator.transition.counterfactual``), each action family's scaled by its
        power prior's delta against the `real` counts (``family_discount``; 1 without
        `discount`), which ``cf_discounts`` records per family.

        >>> from planner.container import TASK
        >>> t = TransitionModel.for_task(TASK, 2)
        >>> t.add_counterfactual({("push", 1): (4.0, 4.0), ("push", 2): (1.0, 4.0)}, {})
        >>> round(t.probability("push", 2), 2), t.cf_discounts["push"]      # untried, yet 0.4
        (0.4, 1.0)
        >>> t = TransitionModel.for_task(TASK, 2)        # reality failed push 1 five times
        >>> t.add_counts("push", 1, 0.0, 5.0)
        >>> t.add_counterfactual({("push", 1): (4.0, 4.0), ("push", 2): (1.0, 4.0)}, {("push", 1): (0.0, 5.0)})
        >>> round(t.cf_discounts["push"], 2), round(t.probability("push", 2), 2)
        (0.15, 0.72)
        """
        families = sorted({name for name, _ in counts})
        for family in families:
            mine = {c: v for c, v in counts.items() if c[0] == family}
            delta = family_discount(real, mine) if discount else 1.0
            self.cf_discounts[family] = delta
            for (name, k), (cs, cn) in mine.items():
                self.add_counts(name, k, cs * delta, cn * delta)


# delta's grid: 0, 0.05, ..., 1 (a finer one moves T by under 0.005 in the doctest's cases).
_DELTAS = np.linspace(0.0, 1.0, 21)
_REFERENCE = 0.5      # Jeffreys' Beta(1/2, 1/2): the proper prior the marginal likelihood needs


def _log_beta(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    lg = np.vectorize(math.lgamma, otypes=[float])
    return lg(a) + lg(b) - lg(a + b)


def sim_discount(real_successes: float, real_trials: float, sim_successes: float,
                 sim_trials: float) -> float:
    """The posterior mean of the power prior's delta for one context (module docstring).

    The simulated counts, raised to delta, make the prior Beta(1/2 + delta s, 1/2 + delta f)
    of the real success rate; the real outcomes' marginal likelihood under it weighs each
    delta of a uniform grid. No real trial: 1 (nothing contradicts the worlds yet).

    >>> round(sim_discount(0, 0, 5, 5), 3), round(sim_discount(5, 5, 5, 5), 3)
    (1.0, 0.569)
    >>> round(sim_discount(0, 5, 5, 5), 3), round(sim_discount(4, 5, 4.2, 5), 3)
    (0.118, 0.553)
    """
    return family_discount({0: (real_successes, real_trials)}, {0: (sim_successes, sim_trials)})


def family_discount(real: dict, simulated: dict) -> float:
    """The power prior's delta shared by one action family's contexts: the posterior mean
    of delta under a uniform prior, the real outcomes' marginal likelihood being the product
    over the family's contexts of ``sim_discount``'s (a context without real trials adds
    nothing). One delta per family carries the agreement seen in tried contexts to untried
    ones, where there is no real outcome to judge the worlds by. `real` and `simulated` map
    (action, context) to (successes, trials).

    >>> round(family_discount({}, {("push", 3): (1.0, 8.0)}), 3)
    1.0
    >>> sim = {("push", 1): (8.0, 8.0), ("push", 2): (8.0, 8.0), ("push", 3): (1.0, 8.0)}
    >>> agree, gap = {("push", 1): (3.0, 3.0)}, {("push", 1): (0.0, 3.0)}
    >>> round(family_discount(agree, sim), 3), round(family_discount(gap, sim), 3)
    (0.556, 0.121)
    """
    log_ml = np.zeros_like(_DELTAS)
    seen = False
    for ctx, (cs, cn) in simulated.items():
        rs, rn = real.get(ctx, (0.0, 0.0))
        if rn <= 0:
            continue
        seen = True
        a = _REFERENCE + _DELTAS * cs
        b = _REFERENCE + _DELTAS * (cn - cs)
        log_ml += _log_beta(a + rs, b + rn - rs) - _log_beta(a, b)
    if not seen:
        return 1.0
    w = np.exp(log_ml - log_ml.max())
    return float(np.dot(w, _DELTAS) / w.sum())


def transition_table(T: TransitionModel, experience) -> list[dict]:
    """T per context, for people: the success probability and the weighted counts it comes
    from (all, and the real world's share in `experience`, an ExperiencePool), in the
    domain's context order; ``sim_discount``: the share of the simulated counts T uses
    (None: no simulated ones)."""
    real = experience.counts()["real"]
    rows = []
    for name, k in T.contexts:
        i = T._slot(name, k)
        rs, rn = real.get((name, k), (0.0, 0.0))
        rows.append({"action": name, "context": int(k), "p": T.probability(name, k),
                     "successes": float(T.successes[name][i]), "trials": float(T.trials[name][i]),
                     "real_successes": float(rs), "real_trials": float(rn),
                     "sim_discount": T.discounts.get((name, k)),
                     "counterfactual_discount": T.cf_discounts.get(name)})
    return rows
