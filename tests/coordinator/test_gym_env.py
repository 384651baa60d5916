"""The Gymnasium view (issue 28): every registered domain passes Gymnasium's own checker,
its rewards are the loop's utility terms, its truth comes from the seed, and a learner
that knows nothing of TMOC learns on it."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from coordinator.domains import load, names, spec
from coordinator.baselines.gym_baselines import tabular_q
from coordinator.integrations.gym_env import TmocEnv, env_id, register_all

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")   # the checker's advice on Box bounds


def test_every_domain_is_registered_under_its_versioned_id():
    ids = register_all()
    assert ids == [f"tmoc/{n}-v{spec(n).version}" for n in names()]
    env = gym.make("coordinator.integrations.gym_env:tmoc/container-v1", n_blocks=2)
    assert env.unwrapped.domain_name == "container" and len(env.unwrapped.actions) == 2 * 2 + 2 + 2
    env.close()


@pytest.mark.parametrize("name", names())
def test_gymnasium_check_env_passes_for_every_domain(name):
    env = gym.make(f"coordinator.integrations.gym_env:{env_id(name)}", n_blocks=2, max_steps=8)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@pytest.mark.parametrize("name", names())
def test_every_observed_atom_and_planned_action_is_in_the_declared_lists(name):
    """Random allowed actions, grounded anywhere in the prior: every atom Y^-1 reports is
    one of ``task.atoms`` (the observation drops none) and the mask allows what applies."""
    env = TmocEnv(name, n_blocks=3, max_steps=12)
    rng = np.random.default_rng(4)
    obs, info = env.reset(seed=4)
    for _ in range(12):
        assert set(info["state"]) <= set(env.atoms)
        assert int(obs["state"].sum()) == len(info["state"])
        valid = np.flatnonzero(info["action_mask"])
        assert len(valid) > 0                 # (a dead end would have terminated)
        grounding = rng.uniform(env.low, env.high)
        obs, reward, terminated, truncated, info = env.step({"action": int(rng.choice(valid)), "grounding": grounding})
        if terminated or truncated:
            break
    d = load(name, n_blocks=3)
    plan = d.task.plan(d.task.initial_state(3), d.task.optimistic_transition(3))
    assert set(plan.actions) <= set(env.actions)
    env.close()


def test_the_plan_at_the_truth_reaches_the_goal_and_earns_the_loops_utility():
    """The optimistic plan grounded at the truth: every step succeeds, the episode
    terminates, and the return is what the loop's accounting gives (costs, deliveries)."""
    env = TmocEnv("container", n_blocks=3, truth=[0.045])
    obs, info = env.reset(seed=0)
    task = env.task
    plan = task.plan(task.initial_state(3), task.optimistic_transition(3)).actions
    total, state = 0.0, task.initial_state(3)
    expected = 0.0
    for action in plan:
        obs, r, terminated, truncated, info = env.step({"action": env.actions.index(action),
                                                       "grounding": np.array([0.045])})
        assert info["success"], action
        nxt = task.apply(state, action)
        expected += -env.costs[action.split("(")[0]] + task.step_reward(state, action, nxt, env.costs)[0]
        total, state = total + r, nxt
    assert terminated and not truncated
    assert total == pytest.approx(expected) and total == 3 * 40 + 80 - (3 * 25 + 30)


def test_an_action_the_mask_forbids_moves_nothing_and_costs_a_failure():
    env = TmocEnv("container", n_blocks=2)
    obs, info = env.reset(seed=1)
    k = env.actions.index("stack(r,b1,c)")
    assert info["action_mask"][k] == 0
    after, r, terminated, truncated, info2 = env.step({"action": k, "grounding": env.prior_mean()})
    assert r == -(env.costs["stack"] + env.costs["fail"]) and not info2["applicable"]
    assert np.array_equal(after["configuration"], obs["configuration"])
    with pytest.raises(ValueError, match="grounding"):
        env.step({"action": 0, "grounding": np.array([0.04, 0.05])})


def test_the_hidden_truth_comes_from_the_seed_or_is_given():
    env = TmocEnv("stack_and_push", n_blocks=2)
    rows = []
    for seed in (5, 5, 6):
        env.reset(seed=seed)
        rows.append(env.truth_row.copy())
    assert np.array_equal(rows[0], rows[1]) and not np.array_equal(rows[0], rows[2])
    assert np.all(rows[2] >= env.low) and np.all(rows[2] <= env.high)
    fixed = TmocEnv("stack_and_push", n_blocks=2, truth=[0.05])
    fixed.reset(seed=7)
    assert fixed.truth_row.tolist() == [0.05]
    with pytest.raises(ValueError, match="truth"):
        TmocEnv("stack_and_push", n_blocks=2, truth=[0.05, 900.0])


@pytest.mark.slow
def test_tabular_q_learns_the_task_where_the_prior_mean_grounds_it():
    """Q-learning over symbolic states (grounded at the prior's mean, here the truth):
    greedy after 30 episodes it reaches the goal every time at the plan's utility."""
    env = TmocEnv("container", n_blocks=2, truth=[0.045], max_steps=16)
    run = tabular_q(env, 30, np.random.default_rng(0), seed=0, epsilon=0.3)
    assert min(run.returns) < 80.0                      # it explored (and paid for it)
    greedy = tabular_q(env, 3, np.random.default_rng(0), seed=100, greedy=True, table=run.table)
    assert all(greedy.reached_goal) and greedy.returns == [2 * 40 + 80 - (2 * 25 + 30)] * 3


def test_a_dead_end_terminates_the_episode():
    """The container at the goal with a block in the hand: no action applies (no put-down),
    so the episode ends there, as the loop's does."""
    env = TmocEnv("container", n_blocks=2, truth=[0.045])
    env.reset(seed=0)
    for action in ("push(r,c,init,goal)", "pickup(r,b1,init)"):
        obs, r, terminated, truncated, info = env.step({"action": env.actions.index(action),
                                                       "grounding": np.array([0.045])})
    assert info["success"] and terminated and info["dead_end"] and not info["action_mask"].any()
