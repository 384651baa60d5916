"""The catalogue of experiments: what each one runs (its settings), at which scale, with
which seeds, and the RunConfig of every run.

An experiment is a list of *settings* (an agent, a particle count, a variation) times
``runs`` independent, seeded runs. ``REGISTRY`` holds one ``ExperimentSpec`` per
experiment; ``Spec`` is one call of an experiment with every scale field resolved.

Seeds. Run r of setting k of experiment x gets
``SeedSequence(S, spawn_key=(x, k, r)).generate_state(2)`` folded into 63 bits: fixed by
(S, x, k, r) alone, so independent of how many runs go in parallel, of their order, and of
``--resume``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from sim_workers.domains import DEFAULT_DOMAIN

from ..agents import AGENTS as AGENT_SPECS
from ..run_config import RunConfig
from .spec import (DEFAULT_PROBE_TRIALS, EXPERIMENT_TRUE_SIZE, WEIGHTS_DOMAIN, WEIGHTS_SIGMAS,  # noqa: F401
                   WEIGHTS_TRUE_DENSITY, WEIGHTS_TRUE_SIZE, Setting, Spec)     # (re-exported)

ROBOT_EPISODES = tuple(range(0, 37, 4))            # Table II of the paper: episodes 0, 4, ..., 36
AGENTS = tuple(AGENT_SPECS)    # the agent registry's names, in its order
PARTICLE_FRACTIONS = (0.25, 0.5, 0.75, 1.0)      # paper: N = 50, 100, 150, 200

# Paper scale (a cluster): 15 runs of 5000 episodes, N = 200.
PAPER_SCALE = {"runs": 15, "episodes": 5000, "particles": 200}



@dataclass(frozen=True)
class ExperimentSpec:
    """One experiment of the catalogue.

    ``settings(N)`` lists its settings for the largest particle count N; ``default_scale``
    is its runs, episodes and particles when no flag says otherwise; ``figure`` names the
    figure ``report.plot`` draws: "curves" (utility and posterior error per episode),
    "curves+density" (plus the density's posterior error) or "milestone_bars".
    """

    name: str
    settings: Callable[..., list[Setting]]
    default_scale: dict
    figure: str = "curves"
    domain: str = DEFAULT_DOMAIN
    true_size: float = EXPERIMENT_TRUE_SIZE
    # Settings that depend on the domain and scale: ``settings(N, domain, scale)`` (the sweep).
    per_domain: bool = False
    # Run r's hidden size drawn from bin r of the prior (``prior_truths``) unless --true-size
    # fixes one: no single size decides the comparison (issue 24).
    truths_across_prior: bool = False
    paper_scale: dict | None = None      # its own --scale paper (default: PAPER_SCALE)


def particle_counts(n_max: int) -> list[int]:
    """The `particles` experiment's N: n_max x (1/4, 1/2, 3/4, 1), rounded, at least 1,
    duplicates dropped (200 -> 50, 100, 150, 200; 16 -> 4, 8, 12, 16; 2 -> 1, 2)."""
    return sorted({max(1, int(round(n_max * q))) for q in PARTICLE_FRACTIONS})


def _weights_settings(_particles: int) -> list[Setting]:
    """Density learned with a fine and a coarse wrist sensor, known, and TMP-RL's prior mean."""
    truth = {"density": WEIGHTS_TRUE_DENSITY}
    learned = [Setting(f"weights-sigma{sg:g}", f"density learned, {sg:g} N",
                       {"agent": "tmoc", "truth": truth,
                        "options": {"unknown_density": True, "force_sigma": sg}})
               for sg in WEIGHTS_SIGMAS]
    known = Setting("weights-known", "density known",
                    {"agent": "tmoc", "options": {"density": WEIGHTS_TRUE_DENSITY, "force_from_mass": True}})
    rl = Setting("weights-tmp_rl", "TMP-RL (prior-mean mass)",
                 {"agent": "tmp_rl", "truth": truth,
                  "options": {"unknown_density": True, "force_sigma": WEIGHTS_SIGMAS[0]}})
    return [*learned, known, rl]


# Default scale: each finishes in under 30 minutes on 2 cores. Measured (whole command,
# 2-core machine, truth 34 mm, docs/RESULTS.md): compare 19 min 6 s (T* estimate
# included), particles 17 min 26 s, milestones 14 min 28 s, sizes 15 min 17 s,
# likelihood 14 min 57 s; weights 36 min 30 s (with tests sharing the two cores; a heavy-
# block episode replays pickups that slip and towers that fall). A TMOC episode costs about 1.8 s + 0.45 s per particle on one
# core once learned; GP ~12 s at N = 16 (more trips), TMP-RL ~2 s, TOEP ~1 s.
# Appended, never reordered: a run's seed derives from its experiment's index here.
REGISTRY: dict[str, ExperimentSpec] = {e.name: e for e in (
    ExperimentSpec("compare", lambda n: [Setting(f"compare-{a}", a, {"agent": a}) for a in AGENTS],
                   {"runs": 3, "episodes": 30, "particles": 16}, truths_across_prior=True),
    ExperimentSpec("particles", lambda n: [Setting(f"particles-N{k}", f"N={k}", {"agent": "tmoc", "particles": k})
                                           for k in particle_counts(n)],
                   {"runs": 3, "episodes": 20, "particles": 24}),
    ExperimentSpec("milestones", lambda n: [Setting("milestones-tmoc", "tmoc", {"agent": "tmoc"})],
                   {"runs": 4, "episodes": 50, "particles": 16}, figure="milestone_bars"),
    ExperimentSpec("sizes", lambda n: [
        Setting("sizes-equal", "equal", {"agent": "tmoc", "sizes_variation": False}),
        Setting("sizes-varied", "one 20% larger", {"agent": "tmoc", "sizes_variation": True})],
                   {"runs": 3, "episodes": 30, "particles": 16}),
    ExperimentSpec("likelihood", lambda n: [Setting(f"likelihood-{m}", m, {"agent": "tmoc", "likelihood": m})
                                            for m in ("replay", "paper")],
                   {"runs": 3, "episodes": 30, "particles": 16}),
    # Table II: the real-robot run with the sizes given, and learned
    ExperimentSpec("robot", lambda n: [
        Setting("robot-given", "sizes given", {"agent": "tmoc", "known_properties": True}),
        Setting("robot-learned", "sizes learned", {"agent": "tmoc"})],
                   {"runs": 3, "episodes": 37, "particles": 16}),
    ExperimentSpec("weights", _weights_settings, {"runs": 3, "episodes": 6, "particles": 32},
                   figure="curves+density", domain=WEIGHTS_DOMAIN, true_size=WEIGHTS_TRUE_SIZE),
    # Issue 24: hidden truths across the whole prior (coordinator.experiments.sweep).
    ExperimentSpec("sweep", lambda n, domain="container", scale="default": _sweep_settings(n, domain, scale),
                   {"runs": 1, "episodes": 4, "particles": 16}, figure="sweep", per_domain=True,
                   paper_scale={"runs": 3, "episodes": 8, "particles": 32}),
)}


def _sweep_settings(particles: int, domain: str, scale: str) -> list[Setting]:
    from .sweep import sweep_settings

    return sweep_settings(domain, scale)
EXPERIMENTS = tuple(REGISTRY)
DEFAULT_SCALE = {name: e.default_scale for name, e in REGISTRY.items()}


def prior_truths(domain: str, runs: int, seed: int, experiment: int) -> tuple[float, ...]:
    """One hidden size per run, run r's drawn uniformly from bin r of `runs` equal bins of
    the domain's size prior (rounded to 0.1 mm): the truths span the prior, and each is
    fixed by (seed, experiment, r) alone, like the run seeds.

    >>> [round(s * 1000, 1) for s in prior_truths("container", 3, 0, 0)]
    [35.7, 43.6, 51.3]
    """
    from ..domains import load, property_space

    low, high = (float(v[0]) for v in property_space(load(domain).physics).bounds(1, False))
    out = []
    for r in range(runs):
        u = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(experiment, r))).random()
        out.append(round(low + (r + u) / runs * (high - low), 4))
    return tuple(out)


def settings_for(name: str, particles: int, domain: str | None = None,
                 scale: str = "default") -> list[Setting]:
    """The settings of experiment `name` for the largest particle count `particles` (and,
    for an experiment whose settings depend on them, the domain and scale)."""
    if name not in REGISTRY:
        raise ValueError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})")
    entry = REGISTRY[name]
    if entry.per_domain:
        return entry.settings(particles, domain or entry.domain, scale)
    return entry.settings(particles)


def default_milestones(episodes: int, count: int = 5) -> tuple[int, ...]:
    """`count` evenly spaced episodes (1-based), the last one being `episodes`."""
    return tuple(sorted({max(1, int(round(episodes * i / count))) for i in range(1, count + 1)}))


def run_seed(seed: int, experiment: int, setting: int, run: int) -> int:
    """The seed of run `run` of setting `setting` (SeedSequence; see the module doc)."""
    words = np.random.SeedSequence(seed, spawn_key=(experiment, setting, run)).generate_state(2)
    return int(((int(words[0]) << 32) | int(words[1])) & (2**63 - 1))


def _has_size(domain: str) -> bool:
    from sim_workers.domains import load

    return "size" in load(domain).L.names


def run_config(spec: Spec, k: int, r: int) -> RunConfig:
    """RunConfig of run r of setting k (pydantic ValidationError on bad values)."""
    s = spec.settings[k]
    fields = {"domain": spec.domain, "particles": spec.particles, "episodes": spec.episodes,
              "max_steps": spec.max_steps, "true_size": spec.run_truth(r),
              "seed": run_seed(spec.seed, EXPERIMENTS.index(spec.name),
                               k if s.seed_index is None else s.seed_index, r),
              "particle_budget": spec.particle_budget, "min_particles": spec.min_particles}
    fields.update(spec.run_fields)
    options = {**spec.run_fields.get("options", {}), **s.overrides.get("options", {})}
    fields.update(s.overrides)
    if options:                          # a setting's own options add to `--set options.K=V`
        fields["options"] = options
    for key in ("engine", "reality_engine"):
        if getattr(spec, key) is not None:
            fields.setdefault(key, getattr(spec, key))
    if not _has_size(spec.domain):      # a domain without a size in L takes its truth by name
        fields.pop("true_size")
    if not AGENT_SPECS[fields["agent"]].learn_belief:     # tmp_rl, toep
        fields["particles"] = 1          # they keep no particles; 1 keeps the config honest
    return RunConfig(**fields)


def run_cost(config: RunConfig) -> float:
    """Relative cost, for submitting the most expensive runs first."""
    from ..agents import agent

    per_episode = 0.5 + (0.62 * config.particles if agent(config.agent).learn_belief else 1.5)
    return config.episodes * per_episode
