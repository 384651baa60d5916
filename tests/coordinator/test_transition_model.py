"""T: contexts, optimistic prior, convergence, planner shape, pool feeding, checkpoints."""
from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.transition.experience import ExperiencePool
from coordinator.transition.transition_model import TransitionModel
from planner.container import TASK, context_of

ON = {"context_fn": TASK.context_of}

S0 = frozenset({"is_in(b1,init)", "is_in(b2,init)", "is_in(b3,init)", "hand_empty(r)",
                "is_in(c,init)"})


def loaded(k: int, holding: str | None = None) -> frozenset[str]:
    atoms = {f"at_container(b{i},c)" for i in range(1, k + 1)} | {"is_in(c,init)"}
    atoms |= {f"is_holding(r,{holding})"} if holding else {"hand_empty(r)"}
    return frozenset(atoms)


def test_contexts():
    assert context_of(S0, "pickup(r,b1,init)") == ("pickup", 0)
    assert context_of(loaded(2), "pickup(r,b3,table)") == ("pickup", 0)
    assert context_of(loaded(0, "b1"), "stack(r,b1,c)") == ("stack", 0)
    assert context_of(loaded(3, "b4"), "stack(r,b4,c)") == ("stack", 3)
    assert context_of(loaded(4), "push(r,c,init,goal)") == ("push", 4)
    assert context_of(loaded(4), "push(r,c,goal,init)") is None  # return push: p = 1
    assert context_of(loaded(0), "push(r,c,init,goal)") is None  # nothing to lose
    # Blocks in another container do not count.
    assert context_of(loaded(2, "b3") | {"at_container(b9,d)"}, "stack(r,b3,c)") == ("stack", 2)
    assert context_of(S0, " pickup( r , b1 , init ) ") == ("pickup", 0)
    with pytest.raises(ValueError, match="fly"):
        context_of(S0, "fly(r,b1)")
    with pytest.raises(ValueError, match="arguments"):
        context_of(S0, "push(r,c,init)")


def test_optimistic_before_data():
    t = TransitionModel.for_task(TASK, 8)
    p = t.to_planner()
    assert p["pickup"] == 1.0
    assert p["stack"] == [1.0] * 8 and p["push"] == [1.0] * 8
    assert TransitionModel.for_task(TASK, 3, prior_successes=0.0).probability("push", 2) == 1.0
    assert t.probability_of(loaded(3), "push(r,c,goal,init)") == 1.0


def test_converges_to_empirical_rate():
    t = TransitionModel.for_task(TASK, 8)
    rng = np.random.default_rng(0)
    outcomes = rng.random(2000) < 0.7
    for ok in outcomes:
        t.observe("push", 8, bool(ok))
    assert t.probability("push", 8) == pytest.approx(outcomes.mean(), abs=0.001)
    assert abs(t.probability("push", 8) - 0.7) < 0.02
    # The estimator: (s + a) / (n + a).
    t2 = TransitionModel.for_task(TASK, 8, prior_successes=2.0)
    t2.observe("stack", 5, False)
    t2.observe("stack", 5, True, weight=0.5)
    assert t2.probability("stack", 5) == pytest.approx((0.5 + 2) / (1.5 + 2))
    assert t2.probability("stack", 4) == 1.0  # other contexts untouched


def test_planner_shape_and_indexing():
    t = TransitionModel.for_task(TASK, 8)
    t.observe("push", 1, False)  # load 1 -> index 0
    t.observe("push", 8, False)  # load 8 -> index 7
    t.observe("stack", 0, False)  # 0 blocks already in -> index 0
    t.observe("stack", 7, False)
    t.observe("pickup", 0, False)
    p = json.loads(json.dumps(t.to_planner()))
    assert set(p) == {"pickup", "stack", "push"}
    assert isinstance(p["pickup"], float)
    assert len(p["stack"]) == 8 and len(p["push"]) == 8
    assert p["push"][0] == 0.5 and p["push"][7] == 0.5 and p["push"][1:7] == [1.0] * 6
    assert p["stack"][0] == 0.5 and p["stack"][7] == 0.5 and p["pickup"] == 0.5


def test_invalid_contexts_raise_naming_them():
    t = TransitionModel.for_task(TASK, 8)
    with pytest.raises(ValueError, match="context 8 invalid for 'stack'"):
        t.observe("stack", 8, True)
    with pytest.raises(ValueError, match="context 9 invalid for 'stack'"):
        t.probability("stack", 9)
    with pytest.raises(ValueError, match="context 0 invalid for 'push'"):
        t.observe("push", 0, True)
    with pytest.raises(ValueError, match="context 9 invalid for 'push'"):
        t.observe("push", 9, True)
    with pytest.raises(ValueError, match="context 1 invalid for 'pickup'"):
        t.observe("pickup", 1, True)
    with pytest.raises(ValueError, match="'lift'"):
        t.observe("lift", 0, True)
    with pytest.raises(ValueError, match="weight"):
        t.observe("pickup", 0, True, weight=-1.0)


def test_from_experience_weights_real_one_and_sim_by_factor():
    pool = ExperiencePool(TASK.context_of)
    s = loaded(4)
    ok, fell = loaded(4) - {"is_in(c,init)"} | {"is_in(c,goal)"}, frozenset({"is_in(c,goal)"})
    pool.add_real(s, "push(r,c,init,goal)", fell, ok)  # one real failure
    # 10 particles: 7 keep the load (weights 0.07 each... normalised to 0.7 in all).
    pool.add_simulated(s, "push(r,c,init,goal)", [ok] * 7 + [fell] * 3, ok, np.full(10, 0.1))
    pool.add_real(s, "push(r,c,goal,init)", s, s)  # not learned: ignored by T
    t = TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON, sim_weight=4.0, prior_successes=1.0)
    # real: s = 0, n = 1; sim: s = 0.7 * 4, n = 1 * 4.
    assert t.successes["push"][3] == pytest.approx(2.8)
    assert t.trials["push"][3] == pytest.approx(5.0)
    assert t.probability("push", 4) == pytest.approx((2.8 + 1) / (5 + 1))
    real_only = TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON, sim_weight=0.0)
    assert real_only.probability("push", 4) == pytest.approx(0.5)
    assert real_only.to_planner()["push"][:3] == [1.0] * 3
    with pytest.raises(ValueError, match="sim_weight"):
        TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON, sim_weight=-1.0)


def test_from_experience_matches_incremental_observe():
    pool, t = ExperiencePool(TASK.context_of), TransitionModel.for_task(TASK, 3)
    rng = np.random.default_rng(1)
    for step in range(30):
        k = step % 3
        s = loaded(k, "b9")
        ok = s - {"is_holding(r,b9)"} | {"hand_empty(r)", "at_container(b9,c)"}
        got = ok if rng.random() < 0.6 else s
        pool.add_real(s, "stack(r,b9,c)", got, ok)
        t.observe_transition(s, "stack(r,b9,c)", got == ok)
    rebuilt = TransitionModel.from_experience(pool, 3, contexts=TASK.contexts(3), **ON, sim_weight=1.0)
    for k in range(3):
        assert rebuilt.probability("stack", k) == pytest.approx(t.probability("stack", k))


def test_round_trip_exact():
    t = TransitionModel.for_task(TASK, 5, prior_successes=0.7)
    rng = np.random.default_rng(2)
    for _ in range(50):
        t.observe("push", int(rng.integers(1, 6)), bool(rng.random() < 0.5), float(rng.random()))
        t.observe("stack", int(rng.integers(0, 5)), bool(rng.random() < 0.8), 1 / 3)
    u = TransitionModel.from_dict(json.loads(json.dumps(t.to_dict())), TASK.context_of)
    assert u.to_dict() == t.to_dict()
    assert u.to_planner() == t.to_planner()
    for name in ("pickup", "stack", "push"):
        assert np.array_equal(u.successes[name], t.successes[name])
        assert np.array_equal(u.trials[name], t.trials[name])


# -- simulated evidence where reality disagrees (issue 24) ---------------------------------
def _contradicted(pool: ExperiencePool, k: int, real_ok: bool, sim_ok: float, times: int) -> None:
    """`times` real stacks onto k blocks (all succeeding or all failing) beside particle
    worlds that predicted success with weight `sim_ok`."""
    s = loaded(k, "b9")
    ok = s - {"is_holding(r,b9)"} | {"hand_empty(r)", "at_container(b9,c)"}
    for _ in range(times):
        pool.add_real(s, "stack(r,b9,c)", ok if real_ok else s, ok)
        pool.add_simulated(s, "stack(r,b9,c)", [ok, s], ok, np.array([sim_ok, 1 - sim_ok]))


def test_a_context_reality_contradicts_is_learned_from_the_real_outcomes():
    """Worlds sure of success, the robot failing every time: without the discount T stays
    above one half for ever; with it T follows the real rate within a few trials, while a
    context where the two agree keeps its simulated evidence."""
    for trials in (3, 5, 10, 40):
        pool = ExperiencePool(TASK.context_of)
        _contradicted(pool, 2, real_ok=False, sim_ok=1.0, times=trials)
        _contradicted(pool, 1, real_ok=True, sim_ok=1.0, times=trials)
        plain = TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON)
        t = TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON, discount=True)
        assert plain.probability("stack", 2) > 0.5
        real_only = 1 / (trials + 1)                 # (0 + a) / (n + a)
        assert t.probability("stack", 2) < 0.4 and t.probability("stack", 2) - real_only < 0.15
        if trials >= 5:
            assert t.probability("stack", 2) < 0.25
        assert t.probability("stack", 1) == 1.0 and t.discounts[("stack", 1)] > 0.5
        assert t.discounts[("stack", 2)] < 0.3
    # No real trial yet: the worlds' evidence counts whole (what makes TMOC learn fast).
    pool = ExperiencePool(TASK.context_of)
    s = loaded(3, "b9")
    pool.add_simulated(s, "stack(r,b9,c)", [s], s - {"x"} | {"y"}, np.array([1.0]))
    t = TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON, discount=True)
    assert t.discounts[("stack", 3)] == 1.0 and t.probability("stack", 3) == pytest.approx(0.5)


def test_the_discount_tracks_a_partial_disagreement():
    """Reality at 50 %, the worlds at 95 %: T moves from the worlds' rate towards the
    real one as real trials accumulate, and never past it."""
    ps = []
    for trials in (2, 6, 20, 60):
        pool = ExperiencePool(TASK.context_of)
        s = loaded(2, "b9")
        ok = s - {"is_holding(r,b9)"} | {"hand_empty(r)", "at_container(b9,c)"}
        for i in range(trials):
            pool.add_real(s, "stack(r,b9,c)", ok if i % 2 == 0 else s, ok)
            pool.add_simulated(s, "stack(r,b9,c)", [ok, s], ok, np.array([0.95, 0.05]))
        ps.append(TransitionModel.from_experience(pool, 8, contexts=TASK.contexts(8), **ON, discount=True).probability("stack", 2))
    assert all(a > b for a, b in zip(ps, ps[1:])) and ps[-1] < 0.6 and ps[-1] > 0.5
