"""Domain registry: a domain is data plus a few functions, registered by name.

``load("container", n_blocks=8)`` returns a domain object; a second domain is an
addition here (``register``), not a rewrite of the world or the shards.
"""
from __future__ import annotations

from typing import Callable, Protocol

import numpy as np

from .configuration import Configuration


class Domain(Protocol):
    """What the grounded world, the shards and the coordinator need from a domain."""

    name: str
    object_names: list[str]

    def properties(self, props: dict) -> dict: ...                      # validated arrays
    def build(self, client: int, props: dict): ...                      # -> scene handles
    def initial_configuration(self, props: dict) -> Configuration: ...
    def place(self, config: Configuration, props: dict) -> Configuration: ...
    def symbolic_state(self, config: Configuration) -> frozenset[str]: ...   # Y^-1
    def action_pose(self, props: dict, config: Configuration, action: str) -> np.ndarray: ...  # Y
    def action_trajectory(self, config: Configuration, action: str, key: np.ndarray,
                          transit: np.ndarray | None = None) -> np.ndarray: ...
    def after_action(self, config: Configuration, action: str) -> Configuration: ...
    def measurements(self, config: Configuration) -> np.ndarray: ...


_REGISTRY: dict[str, Callable[..., Domain]] = {}


def register(name: str, factory: Callable[..., Domain]) -> None:
    _REGISTRY[name] = factory


def names() -> list[str]:
    _ensure_builtin()
    return sorted(_REGISTRY)


def load(name: str, **options) -> Domain:
    """The domain registered as `name`, built with `options` (e.g. n_blocks=8)."""
    _ensure_builtin()
    if name not in _REGISTRY:
        raise ValueError(f"domain: unknown domain {name!r} (known: {', '.join(sorted(_REGISTRY))})")
    return _REGISTRY[name](**options)


def _ensure_builtin() -> None:
    from . import container  # noqa: F401  (registers itself)
