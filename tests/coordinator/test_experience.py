"""Experience pool: aggregation, bounded memory, counts per source, checkpoints."""
from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.transition.experience import ExperiencePool, Transition
from planner.container import TASK

S = frozenset({"is_in(b1,init)", "hand_empty(r)", "is_in(c,init)"})
HOLD = frozenset({"is_holding(r,b1)", "is_in(c,init)"})
MISS = S  # the grasp closed on air: nothing changed
A = "pickup(r,b1,init)"


def test_add_real_and_transition_fields():
    pool = ExperiencePool(TASK.context_of)
    pool.add_real(S, A, HOLD, HOLD)
    pool.add_real(S, A, MISS, HOLD)
    ts = list(pool)
    assert len(pool) == 2 and pool.n_real == 2
    assert ts[0] == Transition(S, A, HOLD, HOLD, 1.0, "real")
    assert ts[0].success and not ts[1].success
    assert ts[0].context_under(TASK.context_of) == ("pickup", 0)
    assert pool.counts() == {"real": {("pickup", 0): (1.0, 2.0)}, "sim": {}}


def test_add_simulated_aggregates_per_outcome():
    pool = ExperiencePool(TASK.context_of)
    next_states = [HOLD, MISS, HOLD, HOLD, MISS]
    w = np.array([0.1, 0.2, 0.3, 0.1, 0.3])
    pool.add_simulated(S, A, next_states, HOLD, w)
    sims = pool.transitions("sim")
    assert len(sims) == 2 and pool.n_sim_actions == 1
    by_next = {t.next_state: t.weight for t in sims}
    assert by_next[HOLD] == pytest.approx(0.5) and by_next[MISS] == pytest.approx(0.5)
    s, n = pool.counts()["sim"][("pickup", 0)]
    assert s == pytest.approx(0.5) and n == pytest.approx(1.0)
    # Unnormalised weights are normalised (one action = one unit); zero weights dropped.
    pool2 = ExperiencePool(TASK.context_of)
    pool2.add_simulated(S, A, [HOLD, MISS, MISS], HOLD, np.array([3.0, 1.0, 0.0]))
    assert pool2.counts()["sim"][("pickup", 0)] == pytest.approx((0.75, 1.0))
    with pytest.raises(ValueError, match="weights"):
        pool2.add_simulated(S, A, [HOLD], HOLD, np.array([0.5, 0.5]))
    with pytest.raises(ValueError, match="weights"):
        pool2.add_simulated(S, A, [HOLD], HOLD, np.array([0.0]))


def test_memory_bounded_when_outcomes_repeat():
    pool = ExperiencePool(TASK.context_of)
    rng = np.random.default_rng(0)
    n = 200
    for _ in range(2000):
        nxt = [HOLD if u < 0.8 else MISS for u in rng.random(n)]
        pool.add_simulated(S, A, nxt, HOLD, rng.dirichlet(np.ones(n)))
        pool.add_real(S, A, HOLD, HOLD)
    assert len(pool) == 3  # sim HOLD, sim MISS, real HOLD
    s, n_trials = pool.counts()["sim"][("pickup", 0)]
    assert n_trials == pytest.approx(2000) and 0.75 < s / n_trials < 0.85
    assert pool.counts()["real"][("pickup", 0)] == (2000.0, 2000.0)


def test_counts_skip_unlearned_and_split_by_context():
    pool = ExperiencePool(TASK.context_of)
    two = frozenset({"at_container(b1,c)", "at_container(b2,c)", "is_in(c,init)", "hand_empty(r)"})
    at_goal = two - {"is_in(c,init)"} | {"is_in(c,goal)"}
    pool.add_real(two, "push(r,c,init,goal)", at_goal, at_goal)
    pool.add_real(at_goal, "push(r,c,goal,init)", two, two)  # return push: not counted
    assert pool.counts()["real"] == {("push", 2): (1.0, 1.0)}
    with pytest.raises(ValueError, match="unknown action"):
        pool.add_real(S, "teleport(r,b1)", S, S)


def test_round_trip_exact():
    pool = ExperiencePool(TASK.context_of)
    rng = np.random.default_rng(3)
    for i in range(20):
        pool.add_real(S, A, HOLD if i % 3 else MISS, HOLD)
        pool.add_simulated(S, A, [HOLD, MISS, HOLD], HOLD, rng.random(3) + 0.01)
    text = json.dumps(pool.to_dict(), allow_nan=False)
    back = ExperiencePool.from_dict(json.loads(text), TASK.context_of)
    assert list(back) == list(pool)
    assert back.counts() == pool.counts()
    assert back.to_dict() == pool.to_dict()
    assert (back.n_real, back.n_sim_actions) == (20, 20)
    # States are stored once in a table.
    assert len(pool.to_dict()["states"]) == 2
