"""Domain registry (the physics half): a domain is data plus a few functions, by name.

``load("container", n_blocks=8)`` returns a domain object; a second domain is a line in
``BUILTIN`` (or a ``register`` call), not a rewrite of the world or the shards. Like
Gymnasium's registry, the built-ins are ``"module:Class"`` strings imported on first use:
this module imports no domain, so no domain imports it back to register itself. Domains from
other installed packages are found through the ``tmoc.domains`` entry-point group: each
entry point names a mapping ``{"physics": "module:Class", "task": "module:Class", ...}``
(Gymnasium-style strings, imported only when the domain is used, so a Ray actor imports
just the physics half).
"""
from __future__ import annotations

import importlib
from importlib import metadata
from typing import Any, Callable, Mapping

from .base import PhysicsDomain, missing_members


# What the grounded world, the shards and the coordinator need from a domain: the base
# class is the protocol (sim_workers/base.py).
Domain = PhysicsDomain


# The physics halves shipped with the service (coordinator.domains joins them to their
# task halves). Imported lazily by `load`.
BUILTIN: dict[str, str] = {
    "container": "sim_workers.container:ContainerDomain",
    "stack_and_push": "sim_workers.stack_and_push:StackAndPushDomain",
}

_REGISTRY: dict[str, Callable[..., Domain]] = {}
ENTRY_POINT_GROUP = "tmoc.domains"


def register(name: str, factory: Callable[..., Domain]) -> None:
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


def plugin_entries() -> dict[str, Mapping]:
    """Domains installed by other packages: name -> {"physics": ..., "task": ..., ...}.

    An entry point that cannot be loaded or is not such a mapping is skipped here (and
    reported by name when that domain is asked for)."""
    found: dict[str, Mapping] = {}
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        try:
            spec = ep.load()
        except Exception:  # noqa: BLE001 - a broken plugin must not hide the others
            continue
        if isinstance(spec, Mapping) and "physics" in spec and "task" in spec:
            found[ep.name] = {**spec, "distribution": getattr(ep.dist, "name", None)}
    return found


def is_registered(name: str) -> bool:
    return name in _REGISTRY or name in BUILTIN


def names() -> list[str]:
    return sorted(set(_REGISTRY) | set(BUILTIN) | set(plugin_entries()))


def load(name: str, **options) -> Domain:
    """The domain registered as `name`, built with `options` (e.g. n_blocks=8)."""
    if name not in _REGISTRY:
        if name in BUILTIN:
            register(name, import_string(BUILTIN[name]))
        else:
            plugins = plugin_entries()
            if name not in plugins:
                known = sorted(set(_REGISTRY) | set(BUILTIN) | set(plugins))
                raise ValueError(f"domain: unknown domain {name!r} (known: {', '.join(known)})")
            register(name, import_string(plugins[name]["physics"]))
    domain = _REGISTRY[name](**options)
    if not isinstance(domain, PhysicsDomain):
        # The service calls every member of the protocol directly: a half built some
        # other way fails here, by name, not deep inside a Ray actor.
        missing = ", ".join(missing_members(type(domain)))
        raise ValueError(f"domain {name!r}: its physics half {type(domain).__name__} does not "
                         f"implement sim_workers.base.PhysicsDomain (missing: {missing})")
    return domain
