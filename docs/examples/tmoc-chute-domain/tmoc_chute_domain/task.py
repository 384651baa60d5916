"""The chute's task half: queued and delivered pucks, trains swept by T's context (the
train's length), a clingo encoding of its own (``chute.lp``) that splits the queue into
trains at maximum expected utility.

Written against the public kit only (``planner.domain``, ``planner.terms``).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import clingo
import numpy as np

from planner.domain import Context, Plan, PlanningError, TaskDomain, UnknownAction
from planner.terms import parse_term

ENCODING = Path(__file__).resolve().parent / "chute.lp"
DEFAULT_COSTS = {"sweep": 20.0, "fail": 30.0, "deliver": 20.0, "all_delivered": 50.0}
# A context seen to fail every time still costs a finite amount: 50 attempts.
P_FLOOR = 0.02
SCALE = 1000            # utility to clingo's integers (1e-3 resolution)


def _puck(name: str) -> int:
    if not (name.startswith("p") and name[1:].isdigit() and int(name[1:]) >= 1):
        raise ValueError(f"{name!r}: not a puck (p1, p2, ...)")
    return int(name[1:])


def _parse_sweep(action: str) -> int:
    name, args = parse_term(action, "action", UnknownAction)
    if name != "sweep" or len(args) != 1:
        raise UnknownAction(f"action {action!r}: the chute's one action is sweep(pJ)")
    try:
        return _puck(args[0])
    except ValueError as exc:
        raise UnknownAction(f"action {action!r}: {exc}") from None


def queued(state: Iterable[str]) -> list[int]:
    """The queued pucks' indices, front first."""
    return sorted(_puck(parse_term(a)[1][0]) for a in state if a.startswith("queued("))


def sweep_value(costs: Mapping[str, float], p: float, k: int) -> float:
    """Expected utility of sweeping a train of k until it delivers: 1/p strokes, 1/p - 1 of
    them failed, then deliver * k (p floored at P_FLOOR). A failed stroke leaves the train
    in the lane, short of the line, to be swept again."""
    q = max(float(p), P_FLOOR)
    return costs["deliver"] * k - (costs["sweep"] + (1.0 - q) * costs["fail"]) / q


def _probabilities(transition: Mapping, n: int) -> list[float]:
    ps = transition.get("sweep") if isinstance(transition, Mapping) else None
    if isinstance(ps, (int, float)) and not isinstance(ps, bool):
        ps = [ps] * n
    if not isinstance(ps, (list, tuple)) or len(ps) < n:
        raise PlanningError(f"transition.sweep: expected {n} probabilities, got {ps!r}")
    out = []
    for k, p in enumerate(ps[:n]):
        if isinstance(p, bool) or not isinstance(p, (int, float, np.number)) or not 0.0 <= float(p) <= 1.0:
            raise PlanningError(f"transition.sweep[{k}]: expected a probability, got {p!r}")
        out.append(float(p))
    return out


def _costs(costs: Mapping | None) -> dict:
    c = {**DEFAULT_COSTS, **(dict(costs) if costs else {})}
    for key in DEFAULT_COSTS:
        v = c[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
            raise PlanningError(f"costs.{key}: expected a number >= 0, got {v!r}")
    return c


class ChuteTask(TaskDomain):
    """Pucks swept to a line in trains: sweep 20, fail 30, +20 per puck delivered, +50 once
    all are."""

    name = "chute"
    action_names = ("sweep",)
    default_costs = dict(DEFAULT_COSTS)
    http_options = {
        "sweep_force": {"type": float, "gt": 0.5, "le": 60.0,
                        "description": "the wrist's force limit along a stroke (N)"},
        "sweep_time_jitter": {"type": float, "ge": 0.0, "lt": 0.9,
                              "description": "a real arm strokes U(1 +- this) times as fast"},
        # At least 1 mN: a sigma near 0 (1e-300 passed "gt 0") leaves the likelihood no
        # width (issue 38), and no wrist sensor reads finer.
        "force_sigma": {"type": float, "ge": 0.001, "le": 10.0,
                        "description": "the wrist force sensor's noise (N)"},
    }
    http_truth = {"friction": {"type": float, "ge": 0.02, "le": 2.0,
                               "description": "the pucks' friction coefficient on the table"}}

    # -- the symbolic model ---------------------------------------------------------------
    def initial_state(self, n_blocks: int) -> frozenset[str]:
        return frozenset(f"queued(p{i + 1})" for i in range(int(n_blocks)))

    def parse_state(self, atoms: Iterable[str]) -> frozenset[str]:
        seen: dict[int, str] = {}
        for atom in atoms:
            name, args = parse_term(atom, "atom")
            if name not in ("queued", "delivered") or len(args) != 1:
                raise ValueError(f"atom {atom!r}: expected queued(pJ) or delivered(pJ)")
            i = _puck(args[0])
            if i in seen and seen[i] != name:
                raise ValueError(f"atom {atom!r}: p{i} is both queued and delivered")
            seen[i] = name
        return frozenset(f"{n}(p{i})" for i, n in seen.items())

    def blocks(self, state: frozenset[str]) -> list[str]:
        return [f"p{i}" for i in sorted(_puck(parse_term(a)[1][0]) for a in state)]

    def apply(self, state: frozenset[str], action: str) -> frozenset[str]:
        j = _parse_sweep(action)
        if f"queued(p{j})" not in state:
            raise ValueError(f"action {action!r}: p{j} is not queued")
        moved = {i for i in queued(state) if i <= j}
        return frozenset(a for a in state if not any(a == f"queued(p{i})" for i in moved)) \
            | {f"delivered(p{i})" for i in moved}

    def is_goal(self, state: frozenset[str]) -> bool:
        return not any(a.startswith("queued(") for a in state)

    def grounded_actions(self, n_blocks: int) -> tuple[str, ...]:
        return tuple(f"sweep(p{i})" for i in range(1, int(n_blocks) + 1))

    def atoms(self, n_blocks: int) -> tuple[str, ...]:
        return tuple(f"{a}(p{i})" for i in range(1, int(n_blocks) + 1) for a in ("queued", "delivered"))

    # -- T's contexts ---------------------------------------------------------------------
    def contexts(self, n_blocks: int) -> tuple[Context, ...]:
        return tuple(("sweep", k) for k in range(1, int(n_blocks) + 1))

    def context_of(self, state: frozenset[str], action: str) -> Context | None:
        """("sweep", k): a train of the k queued pucks up to and including pj (None: pj
        is not queued, nothing moves)."""
        j = _parse_sweep(action)
        k = sum(1 for i in queued(state) if i <= j)
        return ("sweep", k) if f"queued(p{j})" in state else None

    def optimistic_transition(self, n_blocks: int) -> dict:
        return {"sweep": [1.0] * int(n_blocks)}

    # -- planning -------------------------------------------------------------------------
    def plan(self, state: Iterable[str], transition: Mapping, costs: Mapping | None = None, *,
             max_steps: int | None = None, time_limit: float = 30.0) -> Plan:
        t0 = time.perf_counter()
        state = self.parse_state(state)
        order = queued(state)
        c = _costs(costs)
        if not order:
            return Plan((), (), 0.0, True, 0.0)
        m = len(order)
        ps = _probabilities(transition, max(order))
        values = [sweep_value(c, ps[k - 1], k) for k in range(1, m + 1)]
        ctl = clingo.Control(["--opt-mode=opt", "-t", "1"])
        ctl.load(str(ENCODING))
        facts = [f"queued({i})." for i in range(1, m + 1)] + [f"last({m})."]
        facts += [f"w({k},{-int(round(v * SCALE))})." for k, v in enumerate(values, start=1)]
        ctl.add("base", [], "\n".join(facts))
        ctl.ground([("base", [])])
        found: list[list[int]] = []
        # Each model improves on the last; the last one is optimal once the search is
        # exhausted (12 queued pucks: 2^11 splits, a few ms).
        handle = ctl.solve(on_model=lambda mdl: found.append(
            sorted(s.arguments[0].number for s in mdl.symbols(shown=True))), async_=True)
        done = handle.wait(time_limit)
        if not done:
            handle.cancel()
        proven = bool(done and handle.get().exhausted)
        best = found[-1] if found else None
        if best is None:
            raise PlanningError("chute: no plan found within the time limit")
        loads = tuple(int(b - a) for a, b in zip([0] + best[:-1], best))
        actions = tuple(f"sweep(p{order[i - 1]})" for i in best)
        if max_steps is not None and len(actions) > max_steps:
            raise PlanningError(f"max_steps: the best plan needs {len(actions)} sweeps")
        eu = sum(values[k - 1] for k in loads)
        return Plan(actions, loads, float(eu), bool(proven), (time.perf_counter() - t0) * 1000.0)

    def satisficing(self, state: Iterable[str], *, rng: np.random.Generator,
                    transition: Mapping | None = None, costs: Mapping | None = None) -> Plan:
        """A uniformly random split of the queue into trains (never reads T's values
        unless to report the plan's expected utility)."""
        state = self.parse_state(state)
        order = queued(state)
        cuts = [i for i in range(1, len(order)) if rng.random() < 0.5] + ([len(order)] if order else [])
        loads = tuple(int(b - a) for a, b in zip([0] + cuts[:-1], cuts))
        actions = tuple(f"sweep(p{order[i - 1]})" for i in cuts)
        T = transition if transition is not None else self.optimistic_transition(max(order, default=1))
        eu = self.expected_utility(state, actions, T, costs) if actions else 0.0
        return Plan(actions, loads, eu, False, 0.0)

    def expected_utility(self, state: Iterable[str], actions: Sequence[str], transition: Mapping,
                         costs: Mapping | None = None) -> float:
        state = self.parse_state(state)
        c = _costs(costs)
        ps = _probabilities(transition, max([_puck(b) for b in self.blocks(state)], default=1))
        total = 0.0
        for a in actions:
            ctx = self.context_of(state, a)
            if ctx is not None:
                total += sweep_value(c, ps[ctx[1] - 1], ctx[1])
                state = self.apply(state, a)
        return float(total)

    def actions_for_loads(self, n_blocks: int, loads: Sequence[int]) -> list[str]:
        ends = np.cumsum([int(k) for k in loads])
        return [f"sweep(p{int(j)})" for j in ends]

    def step_reward(self, state: frozenset[str], action: str, next_state: frozenset[str],
                    costs: Mapping[str, float]) -> tuple[float, dict]:
        """+deliver per puck newly delivered, +all_delivered when none is left queued;
        metrics ``delivered`` and ``load`` (the train's length)."""
        ctx = self.context_of(state, action)
        gained = len(queued(state)) - len(queued(next_state))
        reward = costs["deliver"] * max(gained, 0)
        if self.is_goal(next_state) and not self.is_goal(state):
            reward += costs["all_delivered"]
        return reward, {"delivered": max(gained, 0), "load": None if ctx is None else ctx[1]}
