"""The domain registry of the service: a domain's two halves, joined by name.

A domain is a physics half (``sim_workers``: scene, Y, Y^-1, measurements, the prior over
L; what Ray shards import) and a task half (``planner``: symbolic model, T's contexts,
utility terms, the planner). They never import each other; this module is the one place
that joins them. Like Gymnasium's registry, entries are strings imported on use::

    >>> sorted(names())[:1]
    ['container']
    >>> d = load("container", n_blocks=4)
    >>> d.task.contexts(d.n_blocks)[:3]
    (('pickup', 0), ('stack', 0), ('stack', 1))

Built-in domains are listed in ``BUILTIN``; other installed packages add theirs through
the ``tmoc.domains`` entry-point group (see docs/DOMAINS.md): the entry point names a
mapping ``{"physics": "pkg.physics:Cls", "task": "pkg.task:Cls", "description": "..."}``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sim_workers import domains as physics_registry


@dataclass(frozen=True)
class DomainSpec:
    """Where a domain's halves live (``module:attribute`` strings)."""

    name: str
    physics: str
    task: str
    description: str = ""
    source: str = "builtin"         # or "plugin (<distribution>)"


BUILTIN: dict[str, DomainSpec] = {
    "container": DomainSpec(
        "container", "sim_workers.container:ContainerDomain", "planner.container:ContainerTask",
        "the paper's simulation task: blocks carried to a goal in an open container "
        "(heavier loads topple more often)"),
}


def _optional_builtin(name: str, physics: str, task: str, description: str) -> None:
    """Register a built-in domain whose halves import (a half being built is left out)."""
    try:
        physics_registry.import_string(physics)
        physics_registry.import_string(task)
    except ValueError:
        return
    BUILTIN[name] = DomainSpec(name, physics, task, description)


_optional_builtin(
    "stack_and_push", "sim_workers.stack_and_push:StackAndPushDomain",
    "planner.stack_and_push:StackAndPushTask",
    "the paper's real-robot task: blocks stacked into a tower on a rail and pushed to a goal "
    "area (taller towers topple more often)")


def specs() -> dict[str, DomainSpec]:
    """Every registered domain: the built-ins, then installed plugins (built-ins win)."""
    out = dict(BUILTIN)
    for name, entry in physics_registry.plugin_entries().items():
        if name not in out:
            dist = entry.get("distribution")
            out[name] = DomainSpec(name, str(entry["physics"]), str(entry["task"]),
                                   str(entry.get("description", "")),
                                   f"plugin ({dist})" if dist else "plugin")
    return out


def names() -> list[str]:
    return sorted(specs())


def spec(name: str) -> DomainSpec:
    """The spec of a registered domain; ValueError naming `domain` otherwise."""
    known = specs()
    if name not in known:
        raise ValueError(f"domain: unknown domain {name!r} (known: {', '.join(sorted(known))})")
    return known[name]


@dataclass
class Domain:
    """One domain, both halves built: `physics` for worlds and Y, `task` for planning and T."""

    spec: DomainSpec
    physics: Any
    task: Any
    options: dict

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def n_blocks(self) -> int:
        return int(self.physics.spec.n_blocks)


_TASKS: dict[str, Any] = {}


def task_half(name: str):
    """The task half of a domain (one instance per process: it holds no state)."""
    if name not in _TASKS:
        factory = physics_registry.import_string(spec(name).task)
        _TASKS[name] = factory() if isinstance(factory, type) else factory
    return _TASKS[name]


def load(name: str, **options) -> Domain:
    """Both halves of `name`; `options` go to the physics half (e.g. n_blocks=8)."""
    s = spec(name)
    if not physics_registry.is_registered(name):
        physics_registry.register(name, physics_registry.import_string(s.physics))
    physics = physics_registry.load(name, **options)
    return Domain(s, physics, task_half(name), dict(options))


def describe(name: str) -> dict:
    """What `tmoc domains` and GET /v1/domains/{name} show: objects, L (names, units,
    prior), measurement channels, actions, T contexts and utility terms."""
    d = load(name)
    phys, task = d.physics, d.task
    sp = phys.spec
    names_, units, low, high, truth = _properties(phys)
    idx, sigma = phys.measurement_model()
    n_meas = len(phys.measurements(phys.initial_configuration(phys.true_properties())))
    channels = [{"name": "finger_opening" if i == 0 else f"channel_{i}", "index": int(i),
                 "unit": "m", "sigma": float(sg)} for i, sg in zip(idx, sigma)]
    return {
        "name": d.name,
        "description": d.spec.description,
        "source": d.spec.source,
        "physics": d.spec.physics,
        "task": d.spec.task,
        "objects": list(phys.object_names),
        "n_blocks": int(sp.n_blocks),
        "properties": [{"name": n, "unit": u, "prior": {"kind": "uniform", "low": lo, "high": hi},
                        "default_truth": t}
                       for n, u, lo, hi, t in zip(names_, units, low, high, truth)],
        "measurements": {"count": n_meas, "weighed": channels},
        "actions": list(task.action_names),
        "contexts": [list(c) for c in task.contexts(int(sp.n_blocks))],
        "utility": dict(task.default_costs),
        "probe_actions": list(getattr(phys, "probe_actions", ())),
    }


def _properties(phys) -> tuple[list[str], list[str], list[float], list[float], list[float]]:
    """L of a physics half: its own `L` description when it has one, else block sizes."""
    desc = getattr(phys, "L", None)
    if desc is not None:
        return (list(desc.names), list(desc.units), [float(v) for v in desc.low],
                [float(v) for v in desc.high], [float(v) for v in desc.truth])
    sp = phys.spec
    return ["size"], ["m"], [float(sp.prior_low)], [float(sp.prior_high)], [float(sp.true_size)]
