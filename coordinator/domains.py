"""A domain's two halves, joined by name (the registry itself is ``sim_workers.domains``).

A domain is a physics half (``sim_workers``: scene, Y, Y^-1, measurements, the prior over
L; what Ray shards import) and a task half (``planner``: symbolic model, T's contexts,
utility terms, the planner). They never import each other; this module is the one place
that joins them. Like Gymnasium's registry, entries are strings imported on use::

    >>> sorted(names())[:1]
    ['container']
    >>> d = load("container", n_blocks=4)
    >>> d.task.contexts(d.n_objects)[:3]
    (('pickup', 0), ('stack', 0), ('stack', 1))

Built-in domains are listed in ``BUILTIN``; other installed packages add theirs through
the ``tmoc.domains`` entry-point group (see docs/DOMAINS.md): the entry point names a
mapping ``{"physics": "pkg.physics:Cls", "task": "pkg.task:Cls", "description": "...",
"version": 1}``.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any

from planner.domain import TaskDomain
from sim_workers import domains as physics_registry
from sim_workers.base import missing_members
from sim_workers.properties import PropertySpace

# The one registry (sim_workers.domains): the same table, read by shards and coordinator.
DomainSpec = physics_registry.DomainSpec
BUILTIN = physics_registry.BUILTIN
specs = physics_registry.specs
spec = physics_registry.spec
canonical_name = physics_registry.canonical_name
DEFAULT_DOMAIN = physics_registry.DEFAULT_DOMAIN
_log = logging.getLogger("tmoc.domains")


def names() -> list[str]:
    """The usable domains: built-ins and registered ones, and every plugin whose two halves
    import, build at their defaults and implement their protocols (the rest: ``broken``)."""
    return sorted(n for n, s in specs().items() if _halves_problem(s) is None)


# Per plugin spec, why its halves are unusable (None: they are fine); checked once per process.
_HALVES: dict[DomainSpec, str | None] = {}


def _halves_problem(s: DomainSpec) -> str | None:
    if s.source == "builtin" or s.name in physics_registry._REGISTRY:
        return None        # a built-in's broken half is an error when used, never left out
    if s not in _HALVES:
        why = None
        try:
            physics_registry.load(s.name)        # imports, builds at its defaults, checks the protocol
            task_half(s.name)
        except Exception as exc:  # noqa: BLE001 - one plugin's failure stays its own
            why = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ValueError) else str(exc)
        _HALVES[s] = why
        if why is not None:
            _log.warning("domain plugin %r left out: %s", s.name, why)
    return _HALVES[s]


def broken() -> dict[str, str]:
    """Installed plugins left out, with why: entry points that do not load or validate
    (``sim_workers.domains.broken_plugins``) and plugins whose halves do not import."""
    out = physics_registry.broken_plugins()
    for name, s in specs().items():
        why = _halves_problem(s)
        if why is not None:
            out[name] = why
    return dict(sorted(out.items()))


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
    def n_objects(self) -> int:
        """The scene's object count (the physics half's)."""
        return int(self.physics.n_objects)

    @property
    def n_blocks(self) -> int:
        """Old name of ``n_objects``."""
        return self.n_objects


_TASKS: dict[str, Any] = {}


def task_half(name: str):
    """The task half of a domain (one instance per process: it holds no state)."""
    name = spec(name).name
    if name not in _TASKS:
        factory = physics_registry.import_string(spec(name).task)
        task = factory() if isinstance(factory, type) else factory
        if not isinstance(task, TaskDomain):
            raise ValueError(f"domain {name!r}: its task half {type(task).__name__} does not implement "
                             f"planner.domain.TaskDomain (missing: {', '.join(missing_members(type(task), TaskDomain))})")
        _TASKS[name] = task
    return _TASKS[name]


def load(name: str, engine: str | None = None, **options) -> Domain:
    """Both halves of `name` (or ``name-vN``); `options` go to the physics half (e.g.
    n_blocks=8), and `engine` names the engine its worlds are built in (None: the default),
    so a domain whose Y or calibration depends on the engine sees the run's (issue 39)."""
    s = spec(name)
    physics = physics_registry.load(s.name, engine=engine, **options)
    # the engine stays among the options: checks rebuild worlds from them
    return Domain(s, physics, task_half(s.name), {**options, **({"engine": engine} if engine else {})})


def describe(name: str, **options) -> dict:
    """What `tmoc domains` and GET /v1/domains/{name} show: objects, L (names, units,
    prior), measurement channels, actions, T contexts and utility terms."""
    d = load(name, **options)
    phys, task = d.physics, d.task
    L = property_space(phys)
    n_meas = len(phys.measurements(phys.initial_configuration(phys.true_properties())))
    channels = measurement_channels(phys)
    return {
        "name": d.name,
        "version": d.spec.version,
        "id": d.spec.id,
        "description": d.spec.description,
        "source": d.spec.source,
        "physics": d.spec.physics,
        "task": d.spec.task,
        "objects": list(phys.object_names),
        "n_objects": int(phys.n_objects),   # the domain's default object count
        "n_blocks": int(phys.n_objects),    # (its old name)
        "properties": [{"name": n, "unit": u, "prior": {"kind": "uniform", "low": float(lo), "high": float(hi)},
                        "default_truth": float(t)}
                       for n, u, lo, hi, t in zip(L.names, L.units, L.low, L.high, L.truth)],
        "measurements": {"count": n_meas, "weighed": [c for c in channels if c["sigma"] is not None],
                         "channels": channels},
        "actions": list(task.action_names),
        "contexts": [list(c) for c in task.contexts(int(phys.n_objects))],
        "utility": dict(task.default_costs),
        "probe_actions": list(phys.probe_actions),
        "options": options_of(phys),
        # where an arm's base stands (x, y, z, yaw; issue 41); None: the robot's own
        "robot_base": list(phys.robot_base) if phys.robot_base is not None else None,
    }


def property_space(phys) -> PropertySpace:
    """L of a physics half (its ``L``)."""
    return phys.L


def measurement_channels(phys) -> list[dict]:
    """Every measurement channel (name, index, unit, sigma; sigma None: not weighed)."""
    return [dict(c) for c in phys.measurement_channels()]


_OPTION_TYPES = (bool, int, float, str, type(None))
_NOT_OPTIONS = ("n_blocks", "n_objects", "true_size")


def options_of(phys) -> dict:
    """The options a physics half takes (its spec's scalar fields) with their defaults."""
    values = {f.name: getattr(phys.spec, f.name) for f in dataclasses.fields(phys.spec)}
    # The truth and the block count have their own settings (truth/true_size, n_blocks).
    return {k: v for k, v in values.items() if isinstance(v, _OPTION_TYPES) and k not in _NOT_OPTIONS}


def _option_value(key: str, value: Any, default: Any) -> Any:
    """`value` as the type of the option's default (an integral float for an int option,
    any number for a float or unset option); ValueError naming ``options.KEY`` otherwise."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise ValueError(f"options.{key}: expected true or false, got {value!r}")
    if isinstance(default, (int, float)) or default is None:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"options.{key}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"options.{key}: not a finite number")
        if isinstance(default, int):
            if not float(value).is_integer():
                raise ValueError(f"options.{key}: expected an integer, got {value!r}")
            return int(value)
        return float(value)
    if isinstance(value, type(default)):
        return value
    raise ValueError(f"options.{key}: expected {type(default).__name__}, got {value!r}")


def check_options(name: str, options: dict, n_blocks: int | None = None) -> dict:
    """`options` for domain `name`, each one a scalar option the physics takes with a value
    of its type; ValueError naming ``options.KEY`` otherwise."""
    return checked_options(name, options, n_blocks)[0]


def _option_defaults(name: str) -> dict:
    """The options of `name` with the type-giving defaults (built once per domain spec)."""
    s = spec(name)
    key = (s, physics_registry._REGISTRY.get(s.name))
    if key not in _DEFAULTS:
        base = load(name).physics
        known = options_of(base)
        # An unset option (default None) takes the type its field declares: `bool | None`
        # takes true or false, `float | None` a number.
        declared = {f.name: str(f.type) for f in dataclasses.fields(base.spec)} if known else {}
        _DEFAULTS[key] = {k: (False if v is None and declared.get(k, "").startswith("bool") else v)
                          for k, v in known.items()}
    return _DEFAULTS[key]


_DEFAULTS: dict = {}


def _option_ranges(name: str) -> dict:
    """The closed ranges the domain declares for its numeric options (``option_ranges``)."""
    s = spec(name)
    factory = physics_registry._REGISTRY.get(s.name) or physics_registry.import_string(s.physics)
    return dict(getattr(factory, "option_ranges", {}) or {})


def checked_options(name: str, options: dict, n_blocks: int | None = None) -> tuple[dict, Any]:
    """``check_options``, and the physics half built with them (one build)."""
    known = _option_defaults(name)
    for key, value in list(options.items()):
        if key in _NOT_OPTIONS:
            raise ValueError(f"options.{key}: " + (
                "not an option; the object count has its own setting (--objects N; n_objects over HTTP)"
                if key in ("n_blocks", "n_objects") else "set truth.size (--true-size) instead"))
        if key not in known:
            raise ValueError(f"options.{key}: not an option of domain {name!r} "
                             f"(options: {', '.join(sorted(known))})")
        options = {**options, key: _option_value(key, value, known[key])}
    try:
        physics = load(name, **({"n_blocks": n_blocks} if n_blocks else {}), **options).physics
    except (ValueError, TypeError) as exc:
        raise ValueError(f"options.{exc}") from None
    for key, value in options.items():          # the domain's own messages first, then its bounds
        _check_bounds(name, key, value)
    return dict(options), physics


_CMP = {"ge": (lambda v, b: v >= b, ">="), "gt": (lambda v, b: v > b, ">"),
        "le": (lambda v, b: v <= b, "<="), "lt": (lambda v, b: v < b, "<")}


def _check_bounds(name: str, key: str, value: Any) -> None:
    """An option's value inside what the domain declares: its HTTP field's bounds (the task
    half's ``http_options``: the CLI refuses what a request would) and its physics half's
    ``option_ranges``; ValueError naming ``options.KEY`` otherwise (issue 38)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    decl = dict(task_half(name).http_options).get(key, {})
    for op, (ok, sign) in _CMP.items():
        if op in decl and not ok(value, decl[op]):
            raise ValueError(f"options.{key}: {value!r} must be {sign} {decl[op]:g}")
    bounds = _option_ranges(name).get(key)
    if bounds is not None and not bounds[0] <= value <= bounds[1]:
        raise ValueError(f"options.{key}: {value!r} is outside the domain's range "
                         f"[{bounds[0]:g}, {bounds[1]:g}]")
