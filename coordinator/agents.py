"""One loop, four agents: TMOC and its baselines are switches of the same code."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class AgentSpec:
    """What an agent learns and how it chooses plans and grasp poses.

    learn_belief:   keep particles over L and reweight them (learns L and so Y)
    sim_experience: feed the particles' simulated transitions into T
    planner:        "optimal" (max expected utility under T) or "satisficing" (random valid)
    grasp:          "belief" (Y at the real pose x of the belief), "prior_mean" (Y at the
                    prior mean, never updated), "random" (a grasp action, the domain's
                    ``grasp_actions``, grounded at L drawn uniformly from the prior each time,
                    every other action at the prior mean: a random grasp within a reasonable
                    range) or "bandit" (L chosen per action kind by trial and error:
                    ``coordinator.baselines.grounding_bandit``)
    """

    name: str
    learn_belief: bool
    sim_experience: bool
    planner: str
    grasp: str


AGENTS: dict[str, AgentSpec] = {
    "tmoc": AgentSpec("tmoc", learn_belief=True, sim_experience=True, planner="optimal", grasp="belief"),
    # TMP-RL: no model of L; its grounding learned by trial and error per action kind
    # (issue 37: at the prior mean it could not learn where that grasp fails); T from real
    # experience only.
    "tmp_rl": AgentSpec("tmp_rl", learn_belief=False, sim_experience=False, planner="optimal",
                        grasp="bandit"),
    # GP: learns L like TMOC but picks a random satisficing plan (no task-level learning).
    "gp": AgentSpec("gp", learn_belief=True, sim_experience=True, planner="satisficing", grasp="belief"),
    # TOEP: no Y learning; a random grasp in a reasonable range (grasps only, issue 37; the
    # rest at the prior mean); T from real experience.
    "toep": AgentSpec("toep", learn_belief=False, sim_experience=False, planner="optimal", grasp="random"),
}


def agent_spec(name: str) -> AgentSpec:
    """The agent registered as `name`; ValueError naming the known agents otherwise."""
    if name not in AGENTS:
        raise ValueError(f"agent: unknown agent {name!r} (known: {', '.join(AGENTS)})")
    return AGENTS[name]


agent = agent_spec   # the old name (api, experiments and users import it)
