"""The experience pool: <s, a, s'> from the real world (weight 1) and the particle worlds
(weight w_i), from which T is (re)built.

Storage is aggregated: identical records (same source, s, a, s' and expected effect) are
kept once with their weights summed. T only needs weighted sums per (action, context),
so this loses nothing T uses, and memory is bounded by the number of *distinct* outcomes,
not by N particles times the number of actions. Iteration yields one ``Transition`` per
distinct record, in order of first appearance, its ``weight`` being that sum.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np

__all__ = ["Transition", "ExperiencePool", "SOURCES"]

SOURCES = ("real", "sim")
State = frozenset[str]
_Key = tuple[str, State, str, State, State]  # source, state, action, next_state, expected


@dataclass(frozen=True)
class Transition:
    """One (aggregated) experience; it succeeded iff the observed next state is the expected one."""

    state: State
    action: str
    next_state: State
    expected: State
    weight: float
    source: str  # "real" or "sim"

    @property
    def success(self) -> bool:
        return self.next_state == self.expected

    def context_under(self, context_fn: Callable) -> tuple[str, int] | None:
        """The T context of this record under a domain's ``context_of``."""
        return context_fn(self.state, self.action)


class ExperiencePool:
    """Aggregated real and simulated transitions; ``counts()`` is what T is built from."""

    def __init__(self, context_fn: Callable) -> None:
        # The domain's (state, action) -> context (its task half's context_of); it also
        # validates every action added.
        self.context_fn = context_fn
        self._weights: dict[_Key, float] = {}
        self._context: dict[_Key, tuple[str, int] | None] = {}  # derived, cached per record
        self._counts: dict[str, dict[tuple[str, int], tuple[float, float]]] | None = None
        self.n_real = 0  # real transitions added
        self.n_sim_actions = 0  # add_simulated calls (one per real action)

    # ----------------------------------------------------------------- adding
    def _add(self, key: _Key, weight: float) -> None:
        if key in self._weights:
            self._weights[key] += weight
        else:
            self._context[key] = self.context_fn(key[1], key[2])  # validates the action too
            self._weights[key] = weight
        self._counts = None

    def add_real(self, state: State, action: str, next_state: State, expected: State) -> None:
        """One transition the real world showed, at weight 1."""
        self._add(("real", frozenset(state), action, frozenset(next_state), frozenset(expected)), 1.0)
        self.n_real += 1

    def add_simulated(
        self,
        state: State,
        action: str,
        next_states: Sequence[State],
        expected: State,
        weights: np.ndarray,
    ) -> None:
        """The particle worlds' outcomes of one action, particle i at weight w_i.

        Weights are normalised to sum to 1 (so one action is one unit of simulated
        evidence, scaled later by T's ``sim_weight``); zero-weight particles are dropped.
        Pass the weights the loop wants counted (the paper: after reweighting).
        """
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape[0] != len(next_states):
            raise ValueError(f"weights: {w.shape[0]} entries for {len(next_states)} next_states")
        if np.any(~np.isfinite(w)) or np.any(w < 0):
            raise ValueError("weights: must be finite and >= 0")
        total = float(w.sum())
        if not total > 0:
            raise ValueError("weights: sum to zero")
        # Aggregate within the call first (particle order), then merge into the pool.
        per_outcome: dict[State, float] = {}
        for s_next, wi in zip(next_states, (w / total).tolist()):
            if wi > 0:
                s_next = frozenset(s_next)
                per_outcome[s_next] = per_outcome.get(s_next, 0.0) + wi
        state, expected = frozenset(state), frozenset(expected)
        for s_next, wsum in per_outcome.items():
            self._add(("sim", state, action, s_next, expected), wsum)
        self.n_sim_actions += 1

    # ----------------------------------------------------------------- reading
    def __len__(self) -> int:
        """Number of distinct stored records (bounded by distinct outcomes)."""
        return len(self._weights)

    def __iter__(self) -> Iterator[Transition]:
        for (source, s, a, s_next, expected), w in self._weights.items():
            yield Transition(s, a, s_next, expected, w, source)

    def transitions(self, source: str | None = None) -> list[Transition]:
        """Stored records, optionally of one source only."""
        if source is not None and source not in SOURCES:
            raise ValueError(f"source: {source!r} is not one of {SOURCES}")
        return [t for t in self if source is None or t.source == source]

    def counts(self) -> dict[str, dict[tuple[str, int], tuple[float, float]]]:
        """``{"real": {(name, ctx): (weighted successes, weighted trials)}, "sim": {...}}``.

        Summed in record order, so the result depends only on the pool's content (and is
        identical after a to_dict/from_dict round trip). Unlearned actions are left out.
        """
        if self._counts is None:
            acc: dict[str, dict[tuple[str, int], list[float]]] = {s: {} for s in SOURCES}
            for key, w in self._weights.items():
                ctx = self._context[key]
                if ctx is None:
                    continue
                sn = acc[key[0]].setdefault(ctx, [0.0, 0.0])
                if key[3] == key[4]:  # next_state == expected: a success
                    sn[0] += w
                sn[1] += w
            self._counts = {src: {c: (v[0], v[1]) for c, v in d.items()} for src, d in acc.items()}
        return {src: dict(d) for src, d in self._counts.items()}

    # ----------------------------------------------------------------- checkpoints
    def to_dict(self) -> dict:
        """Exact, JSON-able state. States are stored once in a table (sorted atoms) and
        records refer to them by index, since the same states recur across records."""
        index: dict[State, int] = {}
        table: list[list[str]] = []

        def ref(s: State) -> int:
            if s not in index:
                index[s] = len(table)
                table.append(sorted(s))
            return index[s]

        records = [
            [src, ref(s), a, ref(s_next), ref(expected), w]
            for (src, s, a, s_next, expected), w in self._weights.items()
        ]
        return {"states": table, "records": records,
                "n_real": self.n_real, "n_sim_actions": self.n_sim_actions}

    @classmethod
    def from_dict(cls, data: dict, context_fn: Callable) -> "ExperiencePool":
        pool = cls(context_fn)
        table = [frozenset(atoms) for atoms in data["states"]]
        for src, i, a, j, k, w in data["records"]:
            if src not in SOURCES:
                raise ValueError(f"records: source {src!r} is not one of {SOURCES}")
            w = float(w)
            if not (math.isfinite(w) and w >= 0):
                raise ValueError(f"records: bad weight {w!r}")
            key = (src, table[i], a, table[j], table[k])
            pool._context[key] = pool.context_fn(key[1], key[2])
            pool._weights[key] = w
        pool.n_real = int(data.get("n_real", 0))
        pool.n_sim_actions = int(data.get("n_sim_actions", 0))
        return pool
