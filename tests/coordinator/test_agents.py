"""The agent registry (coordinator.agents), parametrised over every registered agent as the
domains are in test_domains.py: each is accepted wherever a run is configured, runs a short
episode in-process (no Ray: an in-process shard pool) and shows the properties its
`AgentSpec` documents. A new agent is checked without touching this file."""
from __future__ import annotations

import json

import pytest
from pydantic import ValidationError

from coordinator.agents import AGENTS, AgentSpec, agent
from coordinator.cli import main
from coordinator.distributed.fanout import ShardPool
from coordinator.run_config import RunConfig
from coordinator.loop.runner import run

NAMES = list(AGENTS)
# What every episode record carries (result.json's "episodes", the service's /episodes).
RECORD_KEYS = {"episode", "utility", "actions", "failures", "loads", "delivered", "plans",
               "posterior", "ess", "wall_s", "physics_s", "planning_s", "particle_actions",
               "particles_per_action", "transit_fallbacks", "transit_fallback_notes",
               "informative_updates", "uninformative_updates", "rejuvenations", "redrawn_particles",
               "dead_end", "counterfactual_trials", "counterfactual_s", "arm_refusals", "arm_refusal_notes"}
PARTICLES = 4


def test_the_paper_agents_are_registered():
    assert {"tmoc", "tmp_rl", "gp", "toep"} <= set(NAMES)
    with pytest.raises(ValueError, match="unknown agent 'nope'"):
        agent("nope")


@pytest.mark.parametrize("name", NAMES)
def test_every_agent_spec_is_consistent(name):
    spec = agent(name)
    assert isinstance(spec, AgentSpec) and spec.name == name
    assert spec.planner in ("optimal", "satisficing")
    assert spec.grasp in ("belief", "prior_mean", "random", "bandit")
    if not spec.learn_belief:      # no particles: nothing to grasp by, nothing to simulate
        assert spec.grasp != "belief" and not spec.sim_experience


@pytest.mark.parametrize("name", NAMES)
def test_every_agent_is_accepted_by_the_run_config_and_the_cli(name, capsys):
    assert RunConfig(agent=name).agent == name
    assert main(["run", "--agent", name, "--print-config"]) == 0
    assert json.loads(capsys.readouterr().out)["agent"] == name


def test_an_unregistered_agent_is_refused():
    with pytest.raises(ValidationError, match="agent"):
        RunConfig(agent="nope")


@pytest.fixture(scope="module")
def episodes() -> dict[str, tuple[dict, dict]]:
    """(result, sim counts of the experience pool) of one short episode per agent."""
    out = {}
    for name in NAMES:
        # (the paper's loop: a snapshot's record is tests/coordinator/test_cli_run.py's and
        # test_counterfactual.py's; here each agent's own record and properties)
        cfg = RunConfig(agent=name, particles=PARTICLES, episodes=1, max_steps=3, seed=2,
                        particle_budget="fixed", n_objects=4, counterfactual_rows=0)
        sims = {}
        pool = ShardPool(cfg.domain, {"n_blocks": cfg.n_blocks}, n_shards=0)
        try:
            result = run(cfg, pool=pool,
                         on_episode=lambda rec, session, ck: sims.update(session.experience.counts()["sim"]))  # noqa: B023
        finally:
            pool.close()
        out[name] = (result, sims)
    return out


@pytest.mark.parametrize("name", NAMES)
def test_every_agent_runs_an_episode_with_the_record_and_properties_it_documents(name, episodes):
    spec = agent(name)
    result, sims = episodes[name]
    assert result["config"]["agent"] == name
    # the hidden truth in full, the default included (issue 39: `truth: {}`)
    assert result["config"]["truth"] == {"size": result["config"]["true_size"]} == result["summary"]["truth"]
    (record,) = result["episodes"]
    assert set(record) == RECORD_KEYS, set(record) ^ RECORD_KEYS
    assert 1 <= record["actions"] <= 3 and record["plans"]
    n_blocks = result["config"]["n_blocks"]
    assert sum(record["plans"][0]) == n_blocks         # every plan moves every block
    asked = spec.sim_experience and spec.learn_belief and result["config"]["counterfactual_rows"] > 0
    assert (record["counterfactual_trials"] > 0) == asked, record["counterfactual_trials"]
    if spec.planner == "optimal" and not asked:        # optimistic T before any data: one trip
        assert record["plans"][0] == [n_blocks]
    elif spec.planner == "optimal":                    # the prior's worlds: a full load topples
        assert len(record["plans"][0]) > 1, record["plans"][0]
    post = record["posterior"]
    if spec.learn_belief:
        assert record["ess"] is not None and "mean" in post and post["size_std"] > 0
        assert record["particle_actions"] == PARTICLES * record["actions"]
    else:                                              # L stays at the prior mean, no particles
        assert record["ess"] is None and post["size_std"] == 0.0
        assert post["size_mean"] == pytest.approx(0.045)
        assert record["particle_actions"] == 0 and result["runtime"]["particle_actions"] == 0
    assert bool(sims) == spec.sim_experience, sims


def test_tmp_rl_learns_its_grounding_by_trial_and_error():
    """TMP-RL has no model of L (issue 37): a Thompson-sampling bandit per action kind over
    rows of L spread across the prior. Where one row's grasp works and the others' fail, it
    ends choosing that row; the counts round-trip through a checkpoint; every draw is the
    generator's."""
    import numpy as np

    from coordinator.baselines.grounding_bandit import ARMS, GroundingBandit

    def learn(seed: int) -> tuple[list[int], GroundingBandit]:
        rng = np.random.default_rng(seed)
        b = GroundingBandit([0.030], [0.060])
        works = 1                                  # only arm 1 (34.3 mm) grasps a 34 mm block
        chosen = []
        for _ in range(60):
            arm = b.choose("pickup", rng)
            b.observe("pickup", arm, arm == works)
            chosen.append(arm)
        return chosen, b

    chosen, b = learn(0)
    assert b.row(1)[0] == pytest.approx(0.030 + 1.5 / ARMS * 0.030)
    assert chosen[-20:].count(1) >= 18 and chosen[:10].count(1) < 10
    assert learn(0)[0] == chosen and learn(1)[0] != chosen
    again = GroundingBandit.from_dict(b.to_dict(), [0.030], [0.060])
    assert again.counts == b.counts and GroundingBandit.from_dict(None, [0.03], [0.06]).counts == {}
