"""Engine backends: each builds a ``sim_workers.scene.SceneDescription`` in its engine and
drives it as a ``GroundedWorld`` (issue 27).

``pybullet`` (``pybullet_engine``, ``pybullet_world``) is the default where its package is
installed; ``mujoco`` (``mujoco_engine``, ``mujoco_world``) builds the same declarations, so
no domain keeps a hand-written copy of its scene per engine. Where pybullet has no wheel
(CPython 3.12 and newer) it is not installed, and the default falls back to MuJoCo.
"""
from __future__ import annotations

from .registry import (BATCH_ENGINES, ENGINES, PACKAGES, WORLDS, EngineError, batch_class,  # noqa: F401
                       check_engine, default_engine, installed, make_world, world_class)
