"""The domain registry: one table of versioned domain specs, by name (Gymnasium's registry).

A ``DomainSpec`` names a domain's two halves as ``"module:Class"`` strings, imported on
first use: the physics half (``sim_workers.base.PhysicsDomain``: scene, Y, Y^-1,
measurements, the prior over L; all a Ray shard imports) and the task half
(``planner.domain.TaskDomain``: symbolic model, T's contexts, utility, the planner; the
coordinator joins them in ``coordinator.domains``). The table lives in this leaf module so
that shards and coordinator read the same one, and nothing here imports a domain.

Built-in domains are ``BUILTIN``; other installed packages add theirs through the
``tmoc.domains`` entry-point group: each entry point names a mapping ``{"physics":
"module:Class", "task": "module:Class", "description": ..., "version": N}``. A built-in
whose half fails to import is an error when it is used, never left out of the table; a
plugin that does not load or validate is left out, logged once, and listed with its reason
(``broken_plugins``; ``coordinator.domains.broken`` adds plugins whose halves do not
import), never stopping the service or another domain (issue 38).

``version`` (default 1) changes when a domain's scene, Y or T's contexts change in a way
that makes stored learning invalid: it enters checkpoints and the T* cache keys, and a
checkpoint or cache that has none is read as version 1. ``"name-vN"`` names version N
of a domain (an error if the installed one is another).
"""
from __future__ import annotations

import importlib
import logging
import re
from dataclasses import dataclass
from importlib import metadata
from typing import TYPE_CHECKING, Any, Callable, Mapping

if TYPE_CHECKING:
    from .base import PhysicsDomain

# (The registry imports no numpy or domain at import time: `tmoc --help` and the CLI's
# defaults read it.)


def __getattr__(name: str):
    if name == "Domain":      # the protocol of a domain's physics half: its base class
        from .base import PhysicsDomain

        return PhysicsDomain
    raise AttributeError(name)

_log = logging.getLogger("tmoc.domains")

ENTRY_POINT_GROUP = "tmoc.domains"
# The domain a request, a command or a stored record means when it names none: used at the
# edges only (CLI, HTTP, run and experiment configurations, cache keys from before
# domains); the service's own functions take a domain always.
DEFAULT_DOMAIN = "container"
_VERSIONED = re.compile(r"^(?P<name>.+)-v(?P<version>\d+)$")


@dataclass(frozen=True)
class DomainSpec:
    """One registered domain: where its halves live (``module:attribute`` strings)."""

    name: str
    physics: str
    task: str
    description: str = ""
    source: str = "builtin"         # or "plugin (<distribution>)"
    version: int = 1

    @property
    def id(self) -> str:
        """The versioned id, ``name-vN``."""
        return f"{self.name}-v{self.version}"


@dataclass(frozen=True)
class Scene:
    """One scene of a domain as a value: the domain, its object count and its options
    (sorted, so that equal scenes are equal and hash alike: a pool of worlds is shared per
    scene). ``Scene.of`` builds one from the loose values."""

    domain: str
    n_blocks: int
    options: tuple[tuple[str, Any], ...] = ()
    engine: str | None = None        # the particle worlds' engine (None: the default)

    @classmethod
    def of(cls, domain: str, n_blocks: int, options: Mapping | None = None,
           engine: str | None = None) -> "Scene":
        return cls(str(domain), int(n_blocks), tuple(sorted(dict(options or {}).items())), engine)

    @property
    def option_dict(self) -> dict:
        return dict(self.options)

    def physics_options(self) -> dict:
        """What the physics half is built with: the object count, the options and the
        engine (where one is chosen)."""
        engine = {"engine": self.engine} if self.engine else {}
        return {"n_blocks": self.n_blocks, **self.option_dict, **engine}

    def physics(self) -> "PhysicsDomain":
        """The physics half of this scene."""
        return load(self.domain, **self.physics_options())


BUILTIN: dict[str, DomainSpec] = {
    "container": DomainSpec(
        "container", "sim_workers.container:ContainerDomain", "planner.container:ContainerTask",
        "the paper's simulation task: blocks carried to a goal in an open container "
        "(heavier loads topple more often)"),
    "stack_and_push": DomainSpec(
        "stack_and_push", "sim_workers.stack_and_push:StackAndPushDomain",
        "planner.stack_and_push:StackAndPushTask",
        "the paper's real-robot task: blocks stacked into a tower on a rail and pushed to a goal "
        "area (taller towers topple more often)"),
}

# Physics factories registered in-process (tests, notebooks): they take precedence over a
# spec's `physics` string of the same name.
_REGISTRY: dict[str, Callable[..., "PhysicsDomain"]] = {}


def register(name: str, factory: Callable[..., "PhysicsDomain"]) -> None:
    _REGISTRY[name] = factory


def import_string(path: str) -> Any:
    """``"package.module:Attr"`` -> the object (ValueError naming the path if missing)."""
    module, _, attr = str(path).partition(":")
    try:
        obj = importlib.import_module(module)
        for part in attr.split(".") if attr else ():
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as exc:
        raise ValueError(f"entry point {path!r}: {exc}") from None
    return obj


# The installed plugins, scanned once per process (`rescan` reads them again): the entry
# points that gave a domain mapping, and the ones left out with why (issue 38: a broken
# plugin was imported again about three times per request, on the event loop).
_SCANNED: tuple[dict[str, Mapping], dict[str, str]] | None = None


def _scan() -> tuple[dict[str, Mapping], dict[str, str]]:
    global _SCANNED
    if _SCANNED is not None:
        return _SCANNED
    found: dict[str, Mapping] = {}
    broken: dict[str, str] = {}
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = getattr(ep.dist, "name", None)
        try:
            spec = ep.load()
        except Exception as exc:  # noqa: BLE001 - a broken plugin must not hide the others
            broken[ep.name] = f"its entry point {ep.value!r} does not load ({type(exc).__name__}: {exc})"
            continue
        if not (isinstance(spec, Mapping) and "physics" in spec and "task" in spec):
            broken[ep.name] = f"its entry point {ep.value!r} is not a mapping with 'physics' and 'task'"
            continue
        try:
            _version(spec.get("version", 1), ep.name)
        except ValueError as exc:
            broken[ep.name] = str(exc)
            continue
        found[ep.name] = {**spec, "distribution": dist}
    for name, why in sorted(broken.items()):
        _log.warning("domain plugin %r left out: %s", name, why)      # once per process
    _SCANNED = (found, broken)
    return _SCANNED


def rescan() -> None:
    """Read the installed plugins again on next use (after installing one in-process)."""
    global _SCANNED
    _SCANNED = None


def plugin_entries() -> dict[str, Mapping]:
    """Domains installed by other packages: name -> {"physics": ..., "task": ..., ...}.

    An entry point that cannot be loaded, is not such a mapping or declares no positive
    integer version is left out here and named by ``broken_plugins`` with its reason."""
    return dict(_scan()[0])


def broken_plugins() -> dict[str, str]:
    """The installed plugins left out of the registry: name -> why (`tmoc domains` lists them)."""
    return dict(_scan()[1])


def specs() -> dict[str, DomainSpec]:
    """Every registered domain: the built-ins, then installed plugins (built-ins win)."""
    out = dict(BUILTIN)
    for name, entry in plugin_entries().items():
        if name not in out:
            dist = entry.get("distribution")
            out[name] = DomainSpec(name, str(entry["physics"]), str(entry["task"]),
                                   str(entry.get("description", "")),
                                   f"plugin ({dist})" if dist else "plugin",
                                   _version(entry.get("version", 1), name))
    return out


def _version(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"domain {name!r}: version {value!r} is not a positive integer")
    return value


def names() -> list[str]:
    return sorted(set(specs()) | set(_REGISTRY))


def spec(name: str) -> DomainSpec:
    """The spec of a registered domain (``name`` or ``name-vN``); ValueError naming
    ``domain`` otherwise."""
    if name in BUILTIN:             # (no scan of the installed packages on the hot path)
        return BUILTIN[name]
    known = specs()
    if name not in known:
        m = _VERSIONED.match(str(name))
        if m and m["name"] in known:
            found = known[m["name"]]
            if found.version != int(m["version"]):
                raise ValueError(f"domain: {name!r} is not installed ({m['name']} is version "
                                 f"{found.version}: {found.id})")
            return found
        if name in _REGISTRY:
            return DomainSpec(name, f"<registered {name}>", "", source="registered")
        raise ValueError(f"domain: unknown domain {name!r} (known: {', '.join(sorted(known))})")
    return known[name]


def canonical_name(name: str) -> str:
    """The registry's name for ``name`` or ``name-vN`` (ValueError if unknown)."""
    return spec(name).name


def is_registered(name: str) -> bool:
    try:
        spec(name)
    except ValueError:
        return False
    return True


def load(name: str, engine: str | None = None, **options) -> "PhysicsDomain":
    """The physics half of domain `name`, built with `options` (e.g. n_blocks=8); its
    worlds in `engine` (``sim_workers.engines``; None: the default engine)."""
    from .base import PhysicsDomain, missing_members
    from .engines.registry import check_engine

    s = spec(name)
    factory = _REGISTRY.get(s.name) or import_string(s.physics)
    domain = factory(**options)
    if not isinstance(domain, PhysicsDomain):
        # The service calls every member of the protocol directly: a half built some
        # other way fails here, by name, not deep inside a Ray actor.
        missing = ", ".join(missing_members(type(domain)))
        raise ValueError(f"domain {s.name!r}: its physics half {type(domain).__name__} does not "
                         f"implement sim_workers.base.PhysicsDomain (missing: {missing})")
    if engine is not None:
        domain.engine = check_engine(engine)
    return domain
