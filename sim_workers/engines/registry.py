"""The engine registry: which engines exist, which are installed, the default, and the
check every ``engine`` field goes through. It imports no engine, so the domain registry
(``sim_workers.domains``) checks a name without loading a world."""
from __future__ import annotations

import importlib
import importlib.util

ENGINES = ("pybullet", "mujoco")
# Engines that step a shard's particle worlds as one batch (issue 42): an optional extra.
# Not in ENGINES, whose engines are bit-identical across shards and splits (and which every
# per-engine check runs over); a batch engine is judged by the probe tables instead.
BATCH_ENGINES = ("mujoco_warp",)
PACKAGES = {"pybullet": "pybullet", "mujoco": "mujoco", "mujoco_warp": "mujoco_warp"}
# Each engine's GroundedWorld subclass, by import path (as Gymnasium's entry points): the
# base class resolves its engine's world here without importing every engine, and no
# engine module imports the registry back.
WORLDS = {"pybullet": "sim_workers.engines.pybullet_world:PybulletWorld",
          "mujoco": "sim_workers.engines.mujoco_world:MujocoWorld",
          # a single world of the batch engine (a simulated reality, a probe) is its CPU twin
          "mujoco_warp": "sim_workers.engines.mujoco_world:MujocoWorld"}
# A batch engine's batch class, by import path.
BATCHES = {"mujoco_warp": "sim_workers.engines.warp_batch:WarpBatch"}


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
    if engine not in ENGINES + BATCH_ENGINES:
        raise EngineError(f"{field}: unknown engine {engine!r} (known: {', '.join(ENGINES + BATCH_ENGINES)})")
    if not installed(engine):
        if engine in BATCH_ENGINES:
            raise EngineError(f"{field}: the {engine} engine needs the Python package {PACKAGES[engine]!r}, "
                              "which is not installed (pip install 'tmoc-service[warp]')")
        raise EngineError(f"{field}: the {engine} engine needs the Python package {PACKAGES[engine]!r}, "
                          f"which is not installed (pip install {PACKAGES[engine]}; its wheels exist only "
                          "for some CPython versions)")
    return engine


def batch_class(engine: str | None):
    """The batch class of a batch engine (``BATCHES``), or None for a per-world engine."""
    engine = check_engine(engine)
    if engine not in BATCHES:
        return None
    module, name = BATCHES[engine].split(":")
    return getattr(importlib.import_module(module), name)


def world_class(engine: str | None):
    """The ``GroundedWorld`` subclass of `engine` (None: the default)."""
    module, name = WORLDS[check_engine(engine)].split(":")
    return getattr(importlib.import_module(module), name)


def make_world(domain, *, leave_out: bool = False, engine: str | None = None):
    """A grounded world of `domain` in `engine` (None: the domain's ``engine``, else the
    default): the factory of every engine's ``GroundedWorld`` subclass."""
    return world_class(engine or getattr(domain, "engine", None))(domain, leave_out=leave_out)
