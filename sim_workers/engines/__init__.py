"""Engine backends: each builds a ``sim_workers.scene.SceneDescription`` in its engine and
drives it as a ``GroundedWorld`` (issue 27).

``pybullet`` (``pybullet_engine``, ``pybullet_world``) is the default where its package is
installed; ``mujoco`` (``mujoco_engine``, ``mujoco_world``) builds the same declarations, so
no domain keeps a hand-written copy of its scene per engine. Where pybullet has no wheel
(CPython 3.12 and newer) it is not installed, and the default falls back to MuJoCo.
"""
from __future__ import annotations

import importlib.util

ENGINES = ("pybullet", "mujoco")
PACKAGES = {"pybullet": "pybullet", "mujoco": "mujoco"}


class EngineError(ValueError):
    """An engine that is not known or not installed (the message names it and the fix)."""


def installed(engine: str) -> bool:
    return importlib.util.find_spec(PACKAGES[engine]) is not None


def default_engine() -> str:
    """pybullet where it is installed (every result in this repository was made with it),
    else MuJoCo."""
    return "pybullet" if installed("pybullet") else "mujoco"


def check_engine(engine: str | None, field: str = "engine") -> str:
    """`engine` (None: the default) as a known, installed engine; EngineError naming
    `field` otherwise."""
    if engine is None or engine == "":
        return default_engine()
    if engine not in ENGINES:
        raise EngineError(f"{field}: unknown engine {engine!r} (known: {', '.join(ENGINES)})")
    if not installed(engine):
        raise EngineError(f"{field}: the {engine} engine needs the Python package {PACKAGES[engine]!r}, "
                          f"which is not installed (pip install {PACKAGES[engine]}; its wheels exist only "
                          "for some CPython versions)")
    return engine


def world_class(engine: str | None):
    """The ``GroundedWorld`` subclass of `engine` (None: the default)."""
    engine = check_engine(engine)
    if engine == "mujoco":
        from .mujoco_world import MujocoWorld
        return MujocoWorld
    from .pybullet_world import PybulletWorld
    return PybulletWorld
