"""Action terms as the physics half reads them (Y and Y^-1 of every built-in domain).

The twin of ``planner.terms`` for the same text (``"stack(r,b2,c)"``): the layering keeps
sim_workers a leaf that never imports planner (a Ray shard imports the physics half only),
so this half parses on its own, once. Errors are ValueErrors prefixed ``action:``.

>>> parse_action("push(r, c, init, goal)")
('push', ['r', 'c', 'init', 'goal'])
"""
from __future__ import annotations

import re

_ACTION = re.compile(r"^(pickup|stack|push)\(([^()]*)\)$")
_BLOCK = re.compile(r"b\d+")


def parse_action(action: str) -> tuple[str, list[str]]:
    """``"name(a,b)"`` (spaces ignored) of pickup, stack or push -> ``(name, [a, b])``."""
    m = _ACTION.match(action.replace(" ", ""))
    if not m:
        raise ValueError(f"action: cannot parse {action!r}")
    return m.group(1), m.group(2).split(",")


def held_block(state) -> str | None:
    """The block named by ``is_holding(r,bK)`` in a symbolic state (None: none is held)."""
    for atom in state:
        name, _, rest = atom.replace(" ", "").partition("(")
        if name == "is_holding":
            args = rest.rstrip(")").split(",")
            if len(args) == 2 and _BLOCK.fullmatch(args[1]):
                return args[1]
    return None


def block_index(spec, name: str) -> int:
    """Row of block ``bK`` among the blocks (K - 1); ValueError unless 1 <= K <= spec.n_blocks."""
    if not _BLOCK.fullmatch(name) or not 1 <= int(name[1:]) <= spec.n_blocks:
        raise ValueError(f"action: unknown block {name!r}")
    return int(name[1:]) - 1
