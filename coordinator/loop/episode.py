"""Episode accounting: the realised utility of every step and the per-episode record
(what result.json, run files, checkpoints and the HTTP API carry for an episode)."""
from __future__ import annotations

from dataclasses import dataclass, field

from ..run_config import RunConfig


# Appended to a transit fallback's note once the particle worlds replayed its action from
# the trajectory's start (the unchecked transit included), not from the pre-pose.
REPLAYED = "; particle worlds replayed it from the trajectory's start"


@dataclass
class EpisodeStats:
    """What one episode did so far: utility, actions, failures, loads, timings, particle
    worlds per action and the transit fallbacks (actions moved without a checked transit)."""

    utility: float = 0.0
    actions: int = 0
    failures: dict = field(default_factory=dict)
    loads: list = field(default_factory=list)
    delivered: int = 0
    plans: list = field(default_factory=list)
    wall_s: float = 0.0
    physics_s: float = 0.0
    planning_s: float = 0.0
    transit_fallbacks: list = field(default_factory=list)
    particle_counts: list = field(default_factory=list)   # particle worlds per action
    informative_updates: int = 0      # belief updates that moved the weights (KL > 1e-3 nats)
    uninformative_updates: int = 0    # ... and those that did not (every particle alike)
    rejuvenations: int = 0            # unexplained observations that redrew particles from the prior
    redrawn_particles: int = 0        # rows redrawn over them
    dead_end: str | None = None       # why the planner found no way to the goal (episode ended there)
    arm_refusals: list = field(default_factory=list)   # actions the arm could not do, with why
    counterfactual_trials: int = 0    # world trials of the counterfactual snapshot (issue 40)
    counterfactual_s: float = 0.0     # and their wall time

    def count_update(self, informative: bool, redrawn: int) -> None:
        """Tally one belief update: informative or not, and the rows lock-in redrew."""
        if informative:
            self.informative_updates += 1
        else:
            self.uninformative_updates += 1
        if redrawn:
            self.rejuvenations += 1
            self.redrawn_particles += int(redrawn)

    def account(self, costs: dict, task, state, action: str, next_state, success: bool) -> None:
        """Realised utility of a step: -cost - fail if it failed, + the domain's reward terms."""
        name = action.split("(", 1)[0]
        self.actions += 1
        self.utility -= costs[name]
        if not success:
            self.utility -= costs["fail"]
            self.failures[name] = self.failures.get(name, 0) + 1
        reward, metrics = task.step_reward(state, action, next_state, costs)
        if metrics.get("load") is not None:
            self.loads.append(metrics["load"])
        self.delivered += metrics.get("delivered", 0)
        self.utility += reward

    def replayed_fallback(self) -> None:
        """The last transit fallback's action was simulated by the particle worlds from
        the trajectory's start, transit included: its note says so."""
        self.transit_fallbacks[-1] += REPLAYED

    def record(self, episode: int, posterior: dict, ess: float | None) -> dict:
        """The episode's record (JSON-able), given the posterior and ESS at its end."""
        return {
            "episode": episode, "utility": self.utility, "actions": self.actions,
            "failures": dict(self.failures), "loads": list(self.loads), "delivered": self.delivered,
            "plans": self.plans, "posterior": posterior, "ess": ess,
            "wall_s": self.wall_s, "physics_s": self.physics_s, "planning_s": self.planning_s,
            # particle worlds per action (the adaptive budget's choice; constant when fixed)
            "particle_actions": int(sum(self.particle_counts)),
            "particles_per_action": list(self.particle_counts),
            # actions that moved without a checked transit (every strategy failed), and why
            "transit_fallbacks": len(self.transit_fallbacks),
            "transit_fallback_notes": list(self.transit_fallbacks),
            # belief updates that moved the weights, those that did not (issue 24), and the
            # unexplained observations that redrew particles from the prior (rows redrawn)
            "informative_updates": self.informative_updates,
            "uninformative_updates": self.uninformative_updates,
            "rejuvenations": self.rejuvenations,
            "redrawn_particles": self.redrawn_particles,
            # the observed state from which no plan reaches the goal (None: none met)
            "dead_end": self.dead_end,
            # actions the arm could not do (each a failed attempt for T; issue 41), with why
            "arm_refusals": len(self.arm_refusals),
            "arm_refusal_notes": list(self.arm_refusals),
            # the counterfactual snapshot's world trials (rows x contexts) and wall time
            "counterfactual_trials": self.counterfactual_trials,
            "counterfactual_s": self.counterfactual_s,
        }


def utility_terms(task, config: RunConfig) -> dict[str, float]:
    """The domain's utility terms (action costs, "fail", reward terms), with the values a
    run set explicitly in `config.costs` (a term the domain does not have is refused by
    RunConfig's validation)."""
    terms = dict(task.default_costs)
    given = config.costs.model_dump()
    for key in config.costs.model_fields_set | set(config.costs.model_extra or {}):
        if key in terms:        # (a dumped config also carries the block worlds' defaults)
            terms[key] = float(given[key])
    return terms
