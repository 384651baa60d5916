"""The physics engines as the service sees them: the registry's list, which are installed
on this machine, and the default. ``api/`` reaches physics only through ``coordinator/``
(issue 39); the registry itself is ``sim_workers.engines.registry``."""
from __future__ import annotations

from sim_workers.engines.registry import ENGINES, EngineError, check_engine, default_engine, installed

__all__ = ["ENGINES", "EngineError", "check_engine", "default_engine", "installed"]
