"""The stack-and-push domain's symbolic model: its atoms and actions as text, checked
states, the tower, and what an action does (the reference semantics its plans are checked
against, as ``planner.container.symbolic`` is the container's).

Atoms (what Y^-1 in ``sim_workers.stack_and_push`` reads off a configuration):
``is_in(B,init|table|rail|goal)``, ``is_holding(r,B)``, ``hand_empty(r)``, ``on(B,start)``
for the tower's bottom block and ``on(B,B2)`` for a block on B2. Actions:
``pickup(r,B,L)`` (L in init, table, rail), ``stack(r,B,tower)``, ``push(r,tower,start,goal)``.
"""
from __future__ import annotations

import numbers
import re
from typing import Iterable, Mapping

from planner import terms
from planner.domain import UnknownAction

ROBOT, TOWER, START, GOAL = "r", "tower", "start", "goal"
PICKUP_PLACES = ("init", "table", "rail")
PLACES = PICKUP_PLACES + (GOAL,)
_BLOCK = re.compile(r"^b([1-9][0-9]*)$")
_ARITY = {"pickup": 3, "stack": 3, "push": 4}


# --------------------------------------------------------------------------- symbols

def parse_term(term: str) -> tuple[str, tuple[str, ...]]:
    """``planner.terms.parse_term``, malformed text being an UnknownAction here."""
    return terms.parse_term(term, "term", UnknownAction)


def block_index(name: str) -> int:
    m = _BLOCK.match(name)
    if m is None:
        raise ValueError(f"{name!r} is not a block (b1, b2, ...)")
    return int(m.group(1))


def _atoms(atoms: Iterable[str] | str) -> list[str]:
    if isinstance(atoms, str):
        atoms = re.split(r"[\s.]+(?![^()]*\))", atoms)
    return [a.replace(" ", "") for a in atoms if a and a.strip()]


def parse_state(atoms: Iterable[str] | str) -> frozenset[str]:
    """A checked state: every block exactly once at a place, in the hand or in the tower
    (one ``on`` chain rooted at ``start``), ``hand_empty(r)`` iff nothing is held.
    ValueError names the offending atom."""
    where: dict[str, str] = {}
    below: dict[str, str] = {}
    held: list[str] = []
    empty = False
    for atom in _atoms(atoms):
        try:
            name, args = parse_term(atom)
        except UnknownAction as exc:
            raise ValueError(f"state: {exc}") from None
        if name == "hand_empty" and args == (ROBOT,):
            empty = True
            continue
        if name == "is_holding" and len(args) == 2 and args[0] == ROBOT:
            block_index(args[1])
            held.append(args[1])
            b = args[1]
        elif name == "is_in" and len(args) == 2 and args[1] in PLACES:
            block_index(args[0])
            b = args[0]
        elif name == "on" and len(args) == 2:
            block_index(args[0])
            if args[1] != START:
                block_index(args[1])
            b = args[0]
            below[b] = args[1]
        else:
            raise ValueError(f"state: unknown atom {atom!r}")
        if b in where:
            raise ValueError(f"state: {atom!r}: block {b} is already {where[b]}")
        where[b] = terms.format_term(name, args)    # canonical: "on(b1,start)." was kept as sent
    if len(held) > 1:
        raise ValueError(f"state: the robot holds {held[0]} and {held[1]}")
    if empty == bool(held):
        raise ValueError("state: hand_empty(r) must hold exactly when no block is held")
    _chain(below)
    blocks = sorted(where, key=block_index)
    if not blocks:
        raise ValueError("state: no blocks")
    missing = terms.first_missing(block_index(b) for b in blocks)
    if missing is not None:
        raise ValueError(f"state: block b{missing} is missing (blocks are b1..bN)")
    return frozenset(where.values()) | ({f"hand_empty({ROBOT})"} if empty else set())


def _chain(below: Mapping[str, str]) -> list[str]:
    """The tower bottom first, from ``on`` atoms; ValueError unless it is one chain on start."""
    above = {}
    for b, under in below.items():
        if under in above:
            raise ValueError(f"state: on({above[under]},{under}) and on({b},{under})")
        above[under] = b
    chain, cur = [], START
    while cur in above:
        cur = above[cur]
        chain.append(cur)
    if len(chain) != len(below):
        loose = sorted(set(below) - set(chain), key=block_index)[0]
        raise ValueError(f"state: on({loose},{below[loose]}) is not in a tower on {START}")
    return chain


def blocks(state: frozenset[str]) -> list[str]:
    out = set()
    for atom in state:
        name, args = parse_term(atom)
        if name in ("is_in", "on"):
            out.add(args[0])
        elif name == "is_holding":
            out.add(args[1])
    return sorted(out, key=block_index)


def tower(state: frozenset[str]) -> list[str]:
    """The tower's blocks, bottom first."""
    below = {}
    for atom in state:
        if atom.startswith("on("):
            _, (b, under) = parse_term(atom)
            below[b] = under
    return _chain(below)


def held_block(state: frozenset[str]) -> str | None:
    for atom in state:
        if atom.startswith("is_holding("):
            return parse_term(atom)[1][1]
    return None


def initial_state(n_blocks: int) -> frozenset[str]:
    if isinstance(n_blocks, bool) or not isinstance(n_blocks, numbers.Integral) or n_blocks < 1:
        raise ValueError(f"n_blocks must be a positive integer, got {n_blocks!r}")
    return frozenset({f"is_in(b{i},init)" for i in range(1, n_blocks + 1)} | {f"hand_empty({ROBOT})"})


def is_goal(state: frozenset[str]) -> bool:
    return f"hand_empty({ROBOT})" in state and all(f"is_in({b},{GOAL})" in state for b in blocks(state))


def check_action(action: str) -> tuple[str, tuple[str, ...]]:
    """(name, args) of a well-formed action; UnknownAction names what is wrong."""
    name, args = parse_term(action)
    if name not in _ARITY:
        raise UnknownAction(f"action {action!r}: unknown action name {name!r} "
                            f"(stack_and_push: {', '.join(_ARITY)})")
    if len(args) != _ARITY[name] or args[0] != ROBOT:
        raise UnknownAction(f"action {action!r}: expected pickup(r,B,L), stack(r,B,tower) "
                            f"or push(r,tower,start,goal)")
    if name == "pickup" and args[2] not in PICKUP_PLACES:
        raise UnknownAction(f"action {action!r}: pickup from {args[2]!r} (expected init, table or rail)")
    if name == "stack" and args[2] != TOWER:
        raise UnknownAction(f"action {action!r}: stack onto {args[2]!r} (expected tower)")
    if name == "push" and args[1:] != (TOWER, START, GOAL):
        raise UnknownAction(f"action {action!r}: expected push(r,tower,start,goal)")
    return name, args


def apply(state: frozenset[str], action: str) -> frozenset[str]:
    """The successor state if the action succeeds; ValueError names an unmet precondition."""
    name, args = check_action(action)
    s = set(state)
    if name == "pickup":
        b, where = args[1], args[2]
        for atom in (f"is_in({b},{where})", f"hand_empty({ROBOT})"):
            if atom not in s:
                raise ValueError(f"{action}: precondition {atom} does not hold")
        s -= {f"is_in({b},{where})", f"hand_empty({ROBOT})"}
        s.add(f"is_holding({ROBOT},{b})")
    elif name == "stack":
        b = args[1]
        if f"is_holding({ROBOT},{b})" not in s:
            raise ValueError(f"{action}: precondition is_holding({ROBOT},{b}) does not hold")
        chain = tower(state)
        s.remove(f"is_holding({ROBOT},{b})")
        s |= {f"on({b},{chain[-1] if chain else START})", f"hand_empty({ROBOT})"}
    else:
        chain = tower(state)
        if f"hand_empty({ROBOT})" not in s:
            raise ValueError(f"{action}: precondition hand_empty({ROBOT}) does not hold")
        if not chain:
            raise ValueError(f"{action}: there is no tower on {START} to push")
        s -= {a for a in s if a.startswith("on(")}
        s |= {f"is_in({b},{GOAL})" for b in chain}
    return frozenset(s)
