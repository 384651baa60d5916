"""Kept for imports from before issue 26: the container's symbolic model is
``planner.container.symbolic`` (this name is the same module)."""
import sys

from planner.container import symbolic as _symbolic

sys.modules[__name__] = _symbolic
