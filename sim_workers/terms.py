"""Kept for imports from before issue 26: the block worlds' action terms are
``sim_workers.blocks.terms``."""
from .blocks.terms import block_index, parse_action  # noqa: F401
