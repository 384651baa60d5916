"""Seeded physics trials of one action: does Y with a believed size work in a true world?

Each trial perturbs the true world (block placement by a few mm, friction by about 10 %)
from the seeded generator, takes the action's poses from Y with the believed size, runs the
action in a grounded world and reads the outcome through Y^-1.
"""
from __future__ import annotations

import dataclasses
import inspect
import math
from dataclasses import dataclass

import numpy as np

from .domains import load
from .grounded_world import act  # noqa: F401  (re-exported for the domains' probes)
# The jitter lives with the reality gap; re-exported here for existing callers.
from .reality_gap import (FRICTION_JITTER, PLACEMENT_JITTER_M, YAW_JITTER_RAD,  # noqa: F401
                          jitter_planar, jittered_domain, trial_perception)
from .robots.acting import ArmRefused, trial_arm


@dataclass(frozen=True)
class ProbeResult:
    action: str
    trials: int
    successes: int
    true_size: float
    believed_size: float
    load: int
    true_density: float | None = None       # kg/m^3, when the probe sets or believes one
    believed_density: float | None = None

    @property
    def success_rate(self) -> float:
        return self.successes / self.trials if self.trials else 0.0

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "success_rate": self.success_rate}


def probe_actions(domain_name: str) -> tuple[str, ...]:
    """The action kinds `probe` knows for a domain (empty: the domain has no probe)."""
    domain = load(domain_name)
    return tuple(domain.probe_actions)


def probe_keywords(domain_obj) -> set[str]:
    """The keyword arguments a domain's ``probe_trial`` takes beyond the protocol's
    positional ones ("*" when it takes any): which beliefs and truths its probe can read."""
    params = inspect.signature(domain_obj.probe_trial).parameters.values()
    if any(p.kind is p.VAR_KEYWORD for p in params):
        return {"*"}
    return {p.name for p in params} - {"action", "true_size", "believed_size", "load_k", "rng"}


def by_name(domain_obj) -> bool:
    """Whether the domain's probe is declared by L's names alone,
    ``probe_trial(action, load_k, rng, *, truth, belief)`` (issue 39), rather than with the
    block worlds' ``true_size, believed_size`` positions."""
    return "true_size" not in inspect.signature(domain_obj.probe_trial).parameters


def _named(world_domain, true_size: float, believed_size: float, truth: dict | None,
           belief: dict | None, extra: dict) -> tuple[dict, dict]:
    """The truth and the belief in full, by L's names: L's default truth (the world's
    spec), its size at `true_size` where L has one and it is a number, then `truth`; the
    belief likewise from the truth, `believed_size`, `believed_<name>` keywords and `belief`."""
    L = world_domain.L
    full_truth = dict(zip(L.names, map(float, L.truth)))
    if "size" in full_truth and not math.isnan(true_size):
        full_truth["size"] = float(true_size)
    full_truth.update(truth or {})
    full_belief = dict(full_truth)
    if "size" in full_belief and not math.isnan(believed_size):
        full_belief["size"] = float(believed_size)
    full_belief.update({k.removeprefix("believed_"): float(v) for k, v in extra.items()})
    full_belief.update(belief or {})
    return full_truth, full_belief


def run_trial(action: str, true_size: float, believed_size: float, load_k: int,
              rng: np.random.Generator, n_blocks: int = 8, options: dict | None = None, *,
              domain: str, believed_density: float | None = None, truth: dict | None = None,
              belief: dict | None = None, believed_kw: dict | None = None,
              perception_m: float = 0.0) -> bool:
    """One seeded trial; True when the action had its intended symbolic effect. The world
    is the domain with jittered friction; what the trial does is the domain's
    ``probe_trial`` (each domain knows how to set up its own actions). `truth` and
    `belief` (every property of L by name) reach a probe that takes them. A trial whose
    context was not reached (the probe's None) counts as a failure here, as T* counts it.
    `perception_m` > 0: each action is planned from positions perceived with that std
    (``reality_gap.trial_perception``), as the loop's noisy reality reports them."""
    return bool(_trial(action, true_size, believed_size, load_k, rng, n_blocks, options, domain=domain,
                       believed_density=believed_density, truth=truth, belief=belief, believed_kw=believed_kw,
                       perception_m=perception_m))


def _trial(action: str, true_size: float, believed_size: float, load_k: int,
           rng: np.random.Generator, n_blocks: int = 8, options: dict | None = None, *,
           domain: str, believed_density: float | None = None, truth: dict | None = None,
           belief: dict | None = None, believed_kw: dict | None = None,
           perception_m: float = 0.0) -> bool | None:
    """``run_trial`` with the probe's own answer: True, False, or None where the probe could
    not set its context up (e.g. a tower Y could not build)."""
    world_domain = jittered_domain(rng, domain=domain, n_blocks=n_blocks, **(options or {}))
    extra = {**(believed_kw or {}), **({} if believed_density is None else {"believed_density": believed_density})}
    # The perception's draws come from a child of the trial's generator: without perception
    # (no child spawned) the trial's draws, and outcome, are those of before.
    seen_rng = rng.spawn(1)[0] if perception_m > 0 else rng
    # the trial's own arm, where one acts (robots.acting), and its perception
    with trial_arm(), trial_perception(perception_m, seen_rng):
        try:
            if by_name(world_domain):
                full_truth, full_belief = _named(world_domain, true_size, believed_size, truth, belief, extra)
                return _answer(world_domain.probe_trial(action, load_k, rng, truth=full_truth, belief=full_belief))
            takes = probe_keywords(world_domain)
            for name, value in (("truth", truth), ("belief", belief)):
                if value is not None and ({"*", name} & takes):
                    extra[name] = dict(value)
            return _answer(world_domain.probe_trial(action, true_size, believed_size, load_k, rng, **extra))
        except ArmRefused:
            return False          # a refused action is a failed attempt, as in the loop


def _answer(value) -> bool | None:
    return None if value is None else bool(value)


def trial_by_names(action: str, load_k: int, rng: np.random.Generator, *, domain: str, n_blocks: int,
                   options: dict | None, truth: dict, belief: dict, perception_m: float = 0.0) -> bool | None:
    """One seeded trial with the truth and Y's belief given by L's names alone (each a
    number per property): what a counterfactual simulation asks of a world
    (``coordinator.transition.counterfactual``); None where the probe could not reach the
    context (a tower Y at this belief could not build in this world). A probe declared by names gets them as
    they are; one declared with the block worlds' positions gets the size positionally,
    the truth's other properties as the domain options of the same name (the built-in
    probes read the true density from ``density``) and the belief's as
    ``believed_<name>`` where the probe takes that keyword."""
    options = dict(options or {})
    world = load(domain, **{**options, "n_blocks": n_blocks})
    if by_name(world):
        return _trial(action, math.nan, math.nan, load_k, rng, n_blocks, options, domain=domain,
                      truth=dict(truth), belief=dict(belief), perception_m=perception_m)
    fields = {f.name for f in dataclasses.fields(world.spec)}
    options.update({k: float(v) for k, v in truth.items() if k != "size" and k in fields})
    takes = probe_keywords(world)
    believed_kw = {f"believed_{k}": float(v) for k, v in belief.items()
                   if k != "size" and ({"*", f"believed_{k}"} & takes)}
    return _trial(action, float(truth.get("size", math.nan)), float(belief.get("size", math.nan)),
                  load_k, rng, n_blocks, options, domain=domain, believed_kw=believed_kw,
                  perception_m=perception_m)


def probe_loads(domain_obj, action: str) -> range:
    """The loads a probe of `action` accepts: the domain's own (``probe_loads(action)``,
    e.g. stack_and_push stacks onto a tower of 0..n-1) or, by default, 1..n_blocks."""
    return domain_obj.probe_loads(action)


def probe(action: str, true_size: float, believed_size: float | None = None, load_k: int = 4,
          trials: int = 20, seed: int = 0, n_blocks: int = 8, options: dict | None = None, *,
          domain: str, believed_density: float | None = None, truth: dict | None = None,
          belief: dict | None = None, believed_kw: dict | None = None,
          perception_m: float = 0.0) -> ProbeResult:
    """Run `trials` seeded trials of `action` (one of the domain's ``probe_actions``).

    `believed_density` (kg/m^3) is what Y believes; it needs a domain whose Y uses mass
    (its ``force_from_mass``; on by default here when a believed density is given).
    `perception_m`: Y reads object positions with that std (0: exactly)."""
    options = dict(options or {})
    if believed_density is not None:
        options = mass_in_y_options(domain, options)
    actions = probe_actions(domain)
    if not actions:
        raise ValueError(f"domain: {domain!r} has no probe")
    if action not in actions:
        raise ValueError(f"action: {action!r} is not one of {', '.join(actions)}")
    believed = true_size if believed_size is None else believed_size
    world = load(domain, **{**options, "n_blocks": n_blocks})
    loads = probe_loads(world, action)
    if load_k not in loads:
        raise ValueError(f"load: {load_k} is outside [{loads.start}, {loads.stop - 1}]")
    # One child generator per trial: trial t's outcome does not depend on the trial count.
    children = np.random.default_rng(seed).spawn(trials)
    wins = sum(run_trial(action, true_size, believed, load_k, rng, n_blocks, options, domain=domain,
                         believed_density=believed_density, truth=truth, belief=belief, believed_kw=believed_kw,
                         perception_m=perception_m)
               for rng in children)
    fields = {f.name: getattr(world.spec, f.name) for f in dataclasses.fields(world.spec)}
    true_density = fields.get("density") if believed_density is not None or "density" in options else None
    return ProbeResult(action, trials, int(wins), float(true_size), float(believed), int(load_k),
                       None if true_density is None else float(true_density),
                       None if believed_density is None else float(believed_density))


def mass_in_y_options(domain: str, options: dict) -> dict:
    """`options` with mass in Y switched on (``force_from_mass``) unless set; a ValueError
    naming the option when the domain has none or it was switched off (a believed
    density would otherwise be dropped silently)."""
    fields = {f.name for f in dataclasses.fields(load(domain).spec)}
    if "force_from_mass" not in fields:
        raise ValueError(f"believed_density: mass does not enter Y in the {domain} domain")
    if options.get("force_from_mass") is False:
        raise ValueError("believed_density: needs mass in Y (the option force_from_mass is false)")
    return {**options, "force_from_mass": True}
