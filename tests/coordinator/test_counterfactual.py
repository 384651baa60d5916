"""Counterfactual simulated experience (issue 40): the worlds predict contexts the robot has
not tried, T takes them before the first trial, and a reality that contradicts them wins."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.distributed.fanout import ShardPool
from coordinator.loop.reality import Observation
from coordinator.loop.session import Session
from coordinator.run_config import RunConfig, stored_run_config
from coordinator.transition.counterfactual import REFRESH_ESS_FRACTION, context_counts, draw_rows, ess_fraction
from coordinator.transition.transition_model import TransitionModel, family_discount
from planner.container import TASK

# Four 55 mm blocks: the container's push of 1 or 2 arrives, of 3 mostly and of 4 always
# topples (`tmoc probe --domain container --action push --true-size 0.055 --load 4`).
SIZE, N = 0.055, 4


def _session(rows: int, pool, particles: int = 4, known: bool = True) -> Session:
    n = pool.options["n_blocks"]
    config = RunConfig(n_blocks=n, particles=particles, true_size=SIZE, known_properties=known,
                       counterfactual_rows=rows, seed=3)
    s = Session(config, pool)
    physics = s.domain
    start = physics.initial_configuration(physics.true_properties())
    s.start_episode(Observation(start, TASK.initial_state(n), np.zeros(0)))
    return s


@pytest.fixture(scope="module")
def local_pool():
    pool = ShardPool("container", {"n_blocks": N}, n_shards=0)
    yield pool
    pool.close()


@pytest.fixture(scope="module")
def small_pool():
    """Two blocks: where the claim is about when a snapshot is made, not what it predicts
    (a snapshot's trials grow with the block count)."""
    pool = ShardPool("container", {"n_blocks": 2}, n_shards=0)
    yield pool
    pool.close()


def test_an_untried_load_is_predicted_before_the_first_trial(local_pool):
    on = _session(3, local_pool)
    step = on.next_step()                       # the first plan: the snapshot is made before it
    assert step is not None and on.experience.n_real == 0
    T = on.transition
    # Every push is untried, yet T knows the tall loads topple and the light ones arrive.
    assert T.probability("push", 4) < 0.3 and T.probability("push", 1) > 0.9, T.to_planner()
    assert on.counterfactual.trials == 3 * len(on.domain.counterfactual_jobs(N))
    assert on.stats.counterfactual_trials == on.counterfactual.trials
    assert max(on.stats.plans[0]) <= 2                   # so the first plan never carries 3 or 4
    off = _session(0, local_pool)
    off.next_step()
    assert off.counterfactual is None and off.transition.probability("push", 4) == 1.0
    assert max(off.stats.plans[0]) == N                  # optimistic T: all four in one trip


def test_the_snapshot_is_made_once_per_episode_and_depends_on_the_seed_alone(small_pool):
    a, b = _session(1, small_pool), _session(1, small_pool)
    a.next_step()
    b.next_step()
    assert a.counterfactual.counts == b.counterfactual.counts
    first = a.counterfactual
    a._replan()                                  # a replan within the episode reuses it
    assert a.counterfactual is first


def test_a_replan_redraws_the_snapshot_once_the_belief_has_moved_from_it(small_pool):
    s = _session(2, small_pool, particles=8, known=False)
    s.next_step()
    first = s.counterfactual
    assert first.refresh == 0 and first.mean is not None
    s.belief.update(np.where(np.arange(8) == 0, 0.0, -30.0))   # the belief now sits on one row
    s._replan()
    again = s.counterfactual
    assert again is not first and again.refresh == 1 and again.episode == first.episode
    assert s.stats.counterfactual_trials == first.trials + again.trials
    assert again.std[0] < 1e-6 < first.std[0]
    s._replan()                                   # not moved since: kept
    assert s.counterfactual is again


def test_the_snapshot_is_stale_when_its_rows_stand_for_less_than_half_of_the_belief():
    mean, std = np.array([0.045, 2400.0]), np.array([0.004, 300.0])
    assert ess_fraction(mean, std, mean, std) == 1.0
    # Moved by 0.8 of its std: the rows still stand for half (exp(-0.8^2) = 0.53); by 0.9 not.
    assert ess_fraction(mean, std, mean + [0.8 * 0.004, 0.0], std) > REFRESH_ESS_FRACTION
    assert ess_fraction(mean, std, mean + [0.9 * 0.004, 0.0], std) < REFRESH_ESS_FRACTION
    # Narrowed 2x: kept; 3x: redrawn (the draws spread too wide to stand for it).
    assert ess_fraction(mean, std, mean, std / [2.0, 1.0]) > REFRESH_ESS_FRACTION
    assert ess_fraction(mean, std, mean, std / [3.0, 1.0]) < REFRESH_ESS_FRACTION
    # Widened past sqrt(2): the draws cannot cover it.
    assert ess_fraction(mean, std, mean, std * [1.5, 1.0]) == 0.0
    # A known property (a point) that stays put costs nothing, rounding of its mean included.
    assert ess_fraction(mean, np.array([0.004, 0.0]), mean + [0.0, 1e-12], np.array([0.004, 0.0])) == 1.0


@pytest.mark.slow
def test_the_snapshot_is_the_same_on_any_split_over_shards(ray_cluster, local_pool):
    pool = ShardPool("container", {"n_blocks": N}, n_shards=2)
    try:
        remote = _session(3, pool)
        remote.next_step()
        local = _session(3, local_pool)
        local.next_step()
        assert remote.counterfactual.counts == local.counterfactual.counts
    finally:
        pool.close()


def test_a_reality_that_contradicts_the_worlds_overrides_them():
    # The worlds say a push of 1 always arrives and of 2 mostly; reality fails every push.
    sim = context_counts({"pickup": 1.0, "stack": [1.0] * 2, "push": [1.0, 0.75]}, TASK.contexts(2), 8)
    trusted = TransitionModel.for_task(TASK, 2)
    trusted.add_counterfactual(sim, {})
    assert trusted.probability("push", 2) == pytest.approx((6 + 1) / (8 + 1))
    gap = TransitionModel.for_task(TASK, 2)
    real = {("push", 1): (0.0, 4.0)}
    gap.add_counts("push", 1, 0.0, 4.0)
    gap.add_counterfactual(sim, real)
    # One delta for the push family: the untried push of 2 loses its simulated evidence too.
    assert gap.cf_discounts["push"] < 0.2 and gap.cf_discounts["stack"] == 1.0
    assert gap.probability("push", 1) < 0.35 and gap.probability("push", 2) < trusted.probability("push", 2) + 0.15
    # Where reality agrees, the worlds keep most of their weight.
    assert family_discount({("push", 1): (4.0, 4.0)}, sim) > 0.5


def test_rows_are_drawn_in_proportion_to_the_weights():
    rng = np.random.default_rng(0)
    picked = draw_rows(np.array([0.7, 0.0, 0.3]), 10, rng)
    assert np.bincount(picked, minlength=3).tolist() == [7, 0, 3]


def test_a_stored_config_without_the_field_keeps_the_papers_loop():
    # On by default (docs/LOOP.md: measured to pay in every built-in domain); a stored
    # setting from before the field keeps the paper's loop it ran.
    assert RunConfig().counterfactual_rows == 4
    fields = RunConfig().model_dump()
    del fields["counterfactual_rows"]
    assert stored_run_config(fields).counterfactual_rows == 0
    with pytest.raises(ValueError, match="counterfactual_rows"):
        RunConfig(counterfactual_rows=-1)


def test_a_context_the_belief_cannot_reach_is_left_out_not_failed():
    # Stack-and-push's push probes build their tower with Y at the belief: where Y (35 mm)
    # cannot grasp a row's blocks (58 mm) no tower stands, and that trial says nothing
    # about pushing one. Only the row whose tower stood counts for the pushes.
    from planner.stack_and_push import TASK as SP_TASK
    from sim_workers.domains import load as load_world
    from coordinator.transition.counterfactual import simulate

    physics = load_world("stack_and_push", n_blocks=3)
    pool = ShardPool("stack_and_push", {"n_blocks": 3}, n_shards=0)
    try:
        snap = simulate(pool, physics, ["size"], 1, np.array([[0.035], [0.058]]), np.array([0.5, 0.5]),
                        {"size": 0.035}, 2, 3, SP_TASK.contexts(3), np.random.SeedSequence(0), 0)
    finally:
        pool.close()
    assert snap.counts[("pickup", 0)][1] == 2.0 and snap.counts[("pickup", 0)][0] <= 1.0
    for k in (1, 2, 3):
        assert snap.counts[("push", k)][1] == 1.0, snap.counts


@pytest.mark.slow
def test_a_stop_during_the_snapshot_takes_effect_between_its_contexts():
    """A snapshot is tens of seconds of physics at 8 blocks (one uninterruptible step, a
    cancel waited 21 s for one): with a stop to poll, the contexts go to the shards one at a
    time and the stop is polled before each; the counts do not change."""
    from coordinator.loop.runner import run

    cfg = RunConfig(n_blocks=N, particles=4, true_size=SIZE, counterfactual_rows=2, seed=3, episodes=1,
                    max_steps=3, particle_budget="fixed")
    pool = ShardPool(cfg.domain, {"n_blocks": N}, n_shards=0)
    polls: list[int] = []

    def stop_at_the_fourth_poll() -> bool:     # the run's, the episode's, before context 1, 2
        polls.append(1)
        return len(polls) >= 4

    try:
        stopped = run(cfg, pool=pool, should_stop=stop_at_the_fourth_poll)
        assert stopped["episodes"] == [] and len(polls) == 4
        assert pool.timings["calls"] == 1          # one context's trials of the 9 ran
        polled = run(cfg, pool=pool, should_stop=lambda: False)
        plain = run(cfg, pool=pool)
    finally:
        pool.close()
    (a,), (b,) = polled["episodes"], plain["episodes"]
    assert a["counterfactual_trials"] == b["counterfactual_trials"] > 0
    for key in ("utility", "plans", "failures", "posterior"):
        assert a[key] == b[key], key


def test_the_runs_arm_does_the_snapshots_trials():
    """Issue 41: a context the run's arm cannot do is failed in the snapshot, so T knows it
    before the robot is asked. Stack-and-push's push with the fingers closed: the UR5e's
    wrist meets the tower on every branch, the floating gripper pushes it (the trials of
    ``test_arm_trials``); the snapshot's pushes say so for each robot."""
    from functools import partial

    from planner.stack_and_push import TASK as SP_TASK
    from sim_workers.domains import load as load_world
    from coordinator.loop.arm_trials import ArmForTrials
    from coordinator.transition.counterfactual import simulate

    physics = load_world("stack_and_push", n_blocks=3, push_open=False)
    pool = ShardPool("stack_and_push", {"n_blocks": 3, "push_open": False}, n_shards=0)
    try:
        def snapshot(arm):
            return simulate(pool, physics, ["size"], 1, np.array([[0.045]]), np.array([1.0]), {"size": 0.045},
                            1, 3, SP_TASK.contexts(3), np.random.SeedSequence(0), 0, arm=arm).counts
        gripper, ur5e = snapshot(None), snapshot(partial(ArmForTrials, "ur5e"))
    finally:
        pool.close()
    assert gripper[("push", 3)] == (1.0, 1.0)
    assert ur5e[("push", 3)] == (0.0, 1.0)
    assert ur5e[("pickup", 0)] == (1.0, 1.0)         # what the arm can do, it does


def test_a_session_with_an_arm_gives_its_snapshot_the_arm():
    pool = ShardPool("container", {"n_blocks": 2}, n_shards=0)
    try:
        arm = Session(RunConfig(n_blocks=2, particles=2, robot="ur5e", seed=1), pool)._trial_arm()
        gripper = Session(RunConfig(n_blocks=2, particles=2, seed=1), pool)._trial_arm()
    finally:
        pool.close()
    assert gripper is None and arm.func.__name__ == "ArmForTrials" and arm.args == ("ur5e",)
