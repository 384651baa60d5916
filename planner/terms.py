"""Ground ASP terms as text: the one parser of the task half (and of the coordinator).

States and actions travel as text (``"push(r,c,init,goal)"``). Every module of ``planner``
and ``coordinator`` splits them here; ``sim_workers`` (which may not import planner: the
physics half is a leaf of the layering) has its own twin, ``sim_workers.terms``, for the
same grammar.

>>> parse_term("push(r, c, init, goal).")
('push', ('r', 'c', 'init', 'goal'))
>>> format_term("stack", ["r", "b2", "c"])
'stack(r,b2,c)'
"""
from __future__ import annotations

import re
from typing import Iterable

# A flat ground term: name(arg,...) with no nested parentheses; whitespace is ignored.
_TERM_RE = re.compile(r"([a-z_][a-zA-Z0-9_]*)\(([^()]*)\)")


def parse_term(text: str, kind: str = "term", error: type[ValueError] = ValueError) -> tuple[str, tuple[str, ...]]:
    """``"name(a, b)"`` (whitespace and one trailing period tolerated) -> ``("name", ("a", "b"))``.

    ``"name()"`` has no arguments; an empty argument (``"f(a,,b)"``) is returned as ``""``
    for the caller to judge. Raises `error` (a ValueError) naming `kind` and the text.
    """
    if not isinstance(text, str):
        raise error(f"{kind} must be a string, got {text!r}")
    compact = "".join(text.split()).rstrip(".")
    match = _TERM_RE.fullmatch(compact)
    if match is None:
        raise error(f"malformed {kind} {text!r}: expected name(arg,...)")
    return match.group(1), tuple(match.group(2).split(",")) if match.group(2) else ()


def format_term(name: str, args: Iterable[str]) -> str:
    """The canonical text of a term: ``name(a,b)`` without spaces."""
    return f"{name}({','.join(args)})"


def first_missing(indices: Iterable[int]) -> int | None:
    """The least k >= 1 missing from `indices` up to their largest (None: 1..max all
    there), in O(m log m) for m indices, however large they are: a state naming block
    b5000000 costs what its atoms cost, not five million checks (issue 25).

    >>> first_missing([3, 1, 2]), first_missing([1, 10 ** 40]), first_missing([])
    (None, 2, None)
    """
    k = 1
    for i in sorted(set(indices)):
        if i != k:
            return k
        k += 1
    return None
