"""A session's learning state at an episode boundary, as JSON and back: the belief (with
the reweighting's own state), TMP-RL's bandit, the experience pool (T is derived from it),
the generator, the episode records and the counters. A run resumed from it continues
exactly as the uninterrupted run (tests/coordinator/test_experiment.py); a checkpoint made
before a field existed restores with that field's default."""
from __future__ import annotations

from ..baselines.grounding_bandit import GroundingBandit
from ..domains import spec as domain_spec
from ..particle_filter import Belief
from ..run_config import stored_run_config
from ..transition.experience import ExperiencePool

__all__ = ["CHECKPOINT_VERSION", "session_checkpoint", "restore_session"]

CHECKPOINT_VERSION = 1


def session_checkpoint(session) -> dict:
    """`session`'s whole learning state, JSON-able; only at an episode boundary."""
    if session.pending is not None or (session.observation is not None and not session.episode_done()):
        raise RuntimeError("checkpoint: only at an episode boundary")
    return {
        "version": CHECKPOINT_VERSION,
        "domain_version": domain_spec(session.config.domain).version,
        "config": session.config.model_dump(),
        "belief": session.belief.to_dict() if session.belief is not None else None,
        "reweighting": session.reweighting.to_dict(),
        "bandit": session.bandit.to_dict() if session.bandit is not None else None,
        "experience": session.experience.to_dict(),
        "rng": session.rng.bit_generator.state,
        "episode": session.episode,
        "episodes": session.episodes,
        "particle_actions": session.particle_actions,
        "particle_steps": session.particle_steps,
    }


def restore_session(cls, data: dict, shard_pool=None):
    """A `cls` (Session) built from `data`; refused, naming both, where the installed
    domain's version is not the one the checkpoint was made with."""
    config = stored_run_config(data["config"])
    stored, installed = int(data.get("domain_version", 1)), domain_spec(config.domain)     # absent: version 1
    if stored != installed.version:
        raise ValueError(f"checkpoint: made with {config.domain}-v{stored}; the installed domain is "
                         f"{installed.id}, whose scene or contexts differ: start a new run")
    session = cls(config, shard_pool)
    if data["belief"] is not None:
        session.belief = Belief.from_dict(data["belief"])
        # a belief that has absorbed episodes is no longer the prior (the move's window)
        session.filter.before_window = sum(int(e.get("actions", 1)) for e in data["episodes"])
    session.reweighting.load(data.get("reweighting"), session.dims)     # absent before issue 24
    if session.bandit is not None:                                        # absent before issue 37
        session.bandit = GroundingBandit.from_dict(data.get("bandit"), session.low, session.high)
    session.experience = ExperiencePool.from_dict(data["experience"], session.task.context_of)
    session.transition = session._transition_model()
    session.rng.bit_generator.state = data["rng"]
    session.episode = data["episode"]
    session.episodes = list(data["episodes"])
    session.particle_actions = data["particle_actions"]
    session.particle_steps = data["particle_steps"]
    return session
