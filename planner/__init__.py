"""planner package of the TMOC service: the task half of each domain (``planner.<domain>``,
on the protocol ``planner.domain.TaskDomain``), the block-world toolkit (``planner.blocks``)
and the motion planner (``planner.motion``).

The names below are the container's planner, kept for existing callers; they load on first
use (PEP 562), so ``import planner.domain`` (or the motion planner) does not load any
domain's task half."""
from __future__ import annotations

import importlib

_LAZY = {"Plan": "planner.blocks.model", "PlanningError": "planner.blocks.model",
         "optimistic_transition": "planner.blocks.model", "expected_utility": "planner.container.model",
         "plan": "planner.container.planner", "satisficing": "planner.container.planner"}

__all__ = sorted(_LAZY)


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'planner' has no attribute {name!r}")
