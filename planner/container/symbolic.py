"""Symbolic simulator of the container domain (Table I of the paper).

States are ``frozenset[str]`` of ground atoms in ASP text without spaces and actions are
ASP terms in text, exactly as every other part of the service exchanges them. This module
is the reference semantics the task planner's plans are checked against; it knows nothing
about probabilities or costs.

Objects: robot ``r``, container ``c``, blocks ``b1..bN``. Block locations: ``init`` (the
start row), ``table`` (fell somewhere), ``goal`` (delivered); container locations:
``init`` and ``goal``. A container that arrives at ``goal`` is unloaded by a helper, so
every ``at_container(B,c)`` becomes ``is_in(B,goal)``.
"""
from __future__ import annotations

import re
from typing import Iterable

from planner.terms import first_missing, format_term, parse_term  # noqa: F401  (format_term: re-exported)

ROBOT = "r"
CONTAINER = "c"
BLOCK_PLACES = ("init", "table", "goal")
CONTAINER_PLACES = ("init", "goal")
PICKUP_PLACES = ("init", "table")

_BLOCK_RE = re.compile(r"b[1-9][0-9]*")
_ATOM_TEXT_RE = re.compile(r"[a-z_][a-zA-Z0-9_]*\s*\([^()]*\)")

# predicate -> arity; the only atoms a container state may hold.
_PREDICATES = {"is_in": 2, "is_holding": 2, "hand_empty": 1, "at_container": 2}
_ACTIONS = {"pickup": 3, "stack": 3, "push": 4}



# --------------------------------------------------------------------------- parsing

def _parse_term(text: str, kind: str) -> tuple[str, tuple[str, ...]]:
    """``planner.terms.parse_term`` plus this model's rule: every term has arguments, none empty."""
    name, args = parse_term(text, kind)
    if not args or any(not a for a in args):
        raise ValueError(f"malformed {kind} {text!r}: empty argument")
    return name, args


def is_block(name: str) -> bool:
    """True for block names ``b1``, ``b2``, ... (no leading zeros)."""
    return _BLOCK_RE.fullmatch(name) is not None


def block_index(name: str) -> int:
    """The number of block ``bK``; used to order blocks naturally (b2 before b10)."""
    return int(name[1:])


def parse_atom(text: str) -> tuple[str, tuple[str, ...]]:
    """Parse and check one state atom; raises ValueError naming the atom if unknown."""
    name, args = _parse_term(text, "atom")
    if _PREDICATES.get(name) != len(args):
        raise ValueError(f"unknown atom {text!r}: predicates are is_in/2, is_holding/2, "
                         f"hand_empty/1, at_container/2")
    bad = f"unknown atom {text!r}"
    if name == "hand_empty":
        if args[0] != ROBOT:
            raise ValueError(f"{bad}: the robot is {ROBOT!r}")
    elif name == "is_holding":
        if args[0] != ROBOT or not is_block(args[1]):
            raise ValueError(f"{bad}: expected is_holding({ROBOT},bK)")
    elif name == "at_container":
        if not is_block(args[0]) or args[1] != CONTAINER:
            raise ValueError(f"{bad}: expected at_container(bK,{CONTAINER})")
    elif args[0] == CONTAINER:
        if args[1] not in CONTAINER_PLACES:
            raise ValueError(f"{bad}: the container is at init or goal")
    elif is_block(args[0]):
        if args[1] not in BLOCK_PLACES:
            raise ValueError(f"{bad}: a block is at init, table or goal")
    else:
        raise ValueError(f"{bad}: objects are {ROBOT}, {CONTAINER} and blocks b1..bN")
    return name, args


def parse_action(text: str) -> tuple[str, tuple[str, ...]]:
    """Parse and check one action term; raises ValueError naming it if malformed."""
    name, args = _parse_term(text, "action")
    if _ACTIONS.get(name) != len(args):
        raise ValueError(f"unknown action {text!r}: actions are pickup(R,B,L), "
                         f"stack(R,B,C), push(R,C,L1,L2)")
    bad = f"unknown action {text!r}"
    if args[0] != ROBOT:
        raise ValueError(f"{bad}: the robot is {ROBOT!r}")
    if name == "pickup" and not (is_block(args[1]) and args[2] in PICKUP_PLACES):
        raise ValueError(f"{bad}: expected pickup({ROBOT},bK,init|table)")
    if name == "stack" and not (is_block(args[1]) and args[2] == CONTAINER):
        raise ValueError(f"{bad}: expected stack({ROBOT},bK,{CONTAINER})")
    if name == "push" and not (args[1] == CONTAINER and args[2] in CONTAINER_PLACES
                               and args[3] in CONTAINER_PLACES and args[2] != args[3]):
        raise ValueError(f"{bad}: expected push({ROBOT},{CONTAINER},init,goal) "
                         f"or push({ROBOT},{CONTAINER},goal,init)")
    return name, args


def _split_atoms(text: str) -> list[str]:
    """Atoms of a text separated by whitespace and/or periods; anything else is named."""
    found = _ATOM_TEXT_RE.findall(text)
    rest = _ATOM_TEXT_RE.sub(" ", text)
    leftover = rest.replace(".", " ").split()
    if leftover:
        raise ValueError(f"unknown atom {leftover[0]!r}: expected atoms like is_in(b1,init)")
    return found


def parse_state(atoms: Iterable[str] | str) -> frozenset[str]:
    """Canonical, checked state from atoms (an iterable, or text separated by whitespace,
    newlines or periods, as in a state file)."""
    if isinstance(atoms, str):
        atoms = _split_atoms(atoms)
    canonical = set()
    for atom in atoms:
        name, args = parse_atom(atom)
        canonical.add(format_term(name, args))
    state = frozenset(canonical)
    check_state(state)
    return state


# --------------------------------------------------------------------------- states

def blocks(state: Iterable[str]) -> list[str]:
    """Every block the state mentions, in natural order (b1, b2, ..., b10)."""
    found = set()
    for atom in state:
        _, args = parse_atom(atom)
        found.update(a for a in args if is_block(a))
    return sorted(found, key=block_index)


def initial_state(n_blocks: int) -> frozenset[str]:
    """All blocks in the start row, the container at init, the hand empty."""
    if int(n_blocks) != n_blocks or n_blocks < 1:
        raise ValueError(f"n_blocks must be a positive integer, got {n_blocks!r}")
    atoms = {f"is_in(b{i},init)" for i in range(1, int(n_blocks) + 1)}
    return frozenset(atoms | {f"is_in({CONTAINER},init)", f"hand_empty({ROBOT})"})


def check_state(state: Iterable[str]) -> None:
    """Raise ValueError naming the unknown or inconsistent atom; return None if the state
    is a complete, consistent container state (blocks b1..bN, each in exactly one place,
    the container in one place, the hand either empty or holding one block)."""
    state = frozenset(state)
    where: dict[str, list[str]] = {}
    container: list[str] = []
    hand: list[str] = []
    for atom in sorted(state):
        name, args = parse_atom(atom)
        if name == "hand_empty":
            hand.append(atom)
        elif name == "is_holding":
            hand.append(atom)
            where.setdefault(args[1], []).append(atom)
        elif name == "at_container":
            where.setdefault(args[0], []).append(atom)
        elif args[0] == CONTAINER:
            container.append(atom)
        else:
            where.setdefault(args[0], []).append(atom)
    if not where:
        raise ValueError("state names no blocks: expected is_in(bK,...) atoms for b1..bN")
    for block, atoms in where.items():
        if len(atoms) > 1:
            raise ValueError(f"inconsistent state: block {block} is in several places: "
                             f"{', '.join(atoms)}")
    missing = first_missing(block_index(b) for b in where)
    if missing is not None:
        # The highest block named is not echoed: an atom of 64 characters can name b1e52
        # (issue 38, row 12).
        raise ValueError(f"incomplete state: block b{missing} has no location "
                         f"(blocks must be b1..bN, each in exactly one place)")
    if len(container) != 1:
        raise ValueError("inconsistent state: the container needs exactly one of "
                         f"is_in({CONTAINER},init), is_in({CONTAINER},goal); got "
                         f"{', '.join(container) or 'none'}")
    if len(hand) != 1:
        raise ValueError(f"inconsistent state: the hand needs exactly one of "
                         f"hand_empty({ROBOT}) or one is_holding({ROBOT},B); got "
                         f"{', '.join(hand) or 'none'}")


def container_place(state: Iterable[str]) -> str:
    """Where the container is (``init`` or ``goal``)."""
    for place in CONTAINER_PLACES:
        if f"is_in({CONTAINER},{place})" in state:
            return place
    raise ValueError("state has no is_in(c,init) or is_in(c,goal)")


def held_block(state: Iterable[str]) -> str | None:
    """The block in the gripper, or None."""
    for atom in state:
        if atom.startswith(f"is_holding({ROBOT},"):
            return parse_atom(atom)[1][1]
    return None


def _unload(atoms: set[str]) -> None:
    """The helper at goal: every block in the container is delivered (in place)."""
    loaded = [a for a in atoms if a.startswith("at_container(")]
    for atom in loaded:
        atoms.discard(atom)
        atoms.add(f"is_in({parse_atom(atom)[1][0]},goal)")


def normalize(state: Iterable[str]) -> frozenset[str]:
    """The state with a container standing at goal unloaded (its blocks delivered)."""
    atoms = set(state)
    if f"is_in({CONTAINER},goal)" in atoms:
        _unload(atoms)
    return frozenset(atoms)


def is_goal(state: Iterable[str]) -> bool:
    """True when every block of the state is delivered."""
    state = normalize(state)
    return all(f"is_in({b},goal)" in state for b in blocks(state))


# --------------------------------------------------------------------------- actions

def _preconditions(name: str, args: tuple[str, ...]) -> list[str]:
    if name == "pickup":
        return [f"is_in({args[1]},{args[2]})", f"hand_empty({ROBOT})"]
    if name == "stack":
        return [f"is_holding({ROBOT},{args[1]})", f"is_in({CONTAINER},init)"]
    return [f"hand_empty({ROBOT})", f"is_in({CONTAINER},{args[2]})"]


def _unmet(state: frozenset[str], action: str) -> str | None:
    name, args = parse_action(action)
    for atom in _preconditions(name, args):
        if atom not in state:
            return atom
    return None


def applicable(state: Iterable[str], action: str) -> bool:
    """True if the action's preconditions hold (ValueError if the action is malformed)."""
    return _unmet(normalize(state), action) is None


def apply(state: Iterable[str], action: str) -> frozenset[str]:
    """The successor state; ValueError naming the unmet precondition if not applicable."""
    state = normalize(state)
    missing = _unmet(state, action)
    if missing is not None:
        raise ValueError(f"{action} is not applicable: precondition {missing} does not hold")
    name, args = parse_action(action)
    atoms = set(state)
    if name == "pickup":
        atoms -= {f"is_in({args[1]},{args[2]})", f"hand_empty({ROBOT})"}
        atoms.add(f"is_holding({ROBOT},{args[1]})")
    elif name == "stack":
        atoms.discard(f"is_holding({ROBOT},{args[1]})")
        atoms |= {f"hand_empty({ROBOT})", f"at_container({args[1]},{CONTAINER})"}
    else:
        atoms.discard(f"is_in({CONTAINER},{args[2]})")
        atoms.add(f"is_in({CONTAINER},{args[3]})")
        if args[3] == "goal":
            _unload(atoms)
    return frozenset(atoms)


def validate_plan(state: Iterable[str], plan: Iterable[str], *,
                  require_goal: bool = True) -> frozenset[str]:
    """Simulate the plan from the (checked) state and return the final state. Raises
    ValueError naming the step and the unmet precondition, or that the goal is not
    reached when ``require_goal``."""
    current = frozenset(state)
    check_state(current)
    current = normalize(current)
    for step, action in enumerate(plan, start=1):
        try:
            current = apply(current, action)
        except ValueError as exc:
            raise ValueError(f"step {step}: {exc}") from None
    if require_goal and not is_goal(current):
        left = [b for b in blocks(current) if f"is_in({b},goal)" not in current]
        raise ValueError(f"plan does not reach the goal: {', '.join(left)} not delivered")
    return current
