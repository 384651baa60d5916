"""Kept for imports from before issue 26: stack-and-push's symbolic model is
``planner.stack_and_push.symbolic`` (this name is the same module)."""
import sys

from planner.stack_and_push import symbolic as _symbolic

sys.modules[__name__] = _symbolic
