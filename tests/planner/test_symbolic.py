"""The symbolic container simulator: parsing, checks, preconditions, effects, goal."""
from __future__ import annotations

import pytest

from planner import symbolic as sy


def state(*atoms: str) -> frozenset[str]:
    return frozenset(atoms)


def test_initial_state():
    s = sy.initial_state(3)
    assert s == {"is_in(b1,init)", "is_in(b2,init)", "is_in(b3,init)", "is_in(c,init)",
                 "hand_empty(r)"}
    sy.check_state(s)
    assert sy.blocks(s) == ["b1", "b2", "b3"]
    assert not sy.is_goal(s)
    with pytest.raises(ValueError, match="positive integer"):
        sy.initial_state(0)


def test_blocks_are_ordered_naturally():
    assert sy.blocks(sy.initial_state(12))[-3:] == ["b10", "b11", "b12"]


def test_parse_atom_and_action():
    assert sy.parse_atom("is_in(b3, init)") == ("is_in", ("b3", "init"))
    assert sy.parse_atom("hand_empty(r)") == ("hand_empty", ("r",))
    assert sy.parse_action("push(r,c,goal,init)") == ("push", ("r", "c", "goal", "init"))
    assert sy.parse_action("pickup(r,b12,table)") == ("pickup", ("r", "b12", "table"))


@pytest.mark.parametrize("atom", ["is_on(b1,init)", "is_in(b1,moon)", "is_in(c,table)",
                                  "is_in(x1,init)", "hand_empty(s)", "is_holding(r,c)",
                                  "at_container(b1,d)", "is_in(b01,init)", "is_in(b1)", "b1",
                                  "is_in(b1,,init)"])
def test_unknown_atoms_are_named(atom):
    with pytest.raises(ValueError, match="atom") as info:
        sy.parse_atom(atom)
    assert atom in str(info.value)


@pytest.mark.parametrize("action", ["drop(r,b1)", "pickup(r,b1,goal)", "pickup(q,b1,init)",
                                    "stack(r,b1,init)", "push(r,c,init,init)",
                                    "push(r,c,init,table)", "push(r,b1,init,goal)"])
def test_malformed_actions_are_named(action):
    with pytest.raises(ValueError, match="action") as info:
        sy.parse_action(action)
    assert action in str(info.value)


def test_parse_state_from_text_with_periods_and_spaces():
    s = sy.parse_state("is_in(b1, init). is_in(b2,table)\n hand_empty(r).\nis_in(c,init).")
    assert s == {"is_in(b1,init)", "is_in(b2,table)", "hand_empty(r)", "is_in(c,init)"}
    with pytest.raises(ValueError, match="'junk'"):
        sy.parse_state("is_in(b1,init) junk hand_empty(r) is_in(c,init)")


@pytest.mark.parametrize("atoms, message", [
    ((), "no blocks"),
    (("is_in(b1,init)", "is_in(b1,goal)", "hand_empty(r)", "is_in(c,init)"), "b1"),
    (("is_in(b1,init)", "is_holding(r,b1)", "is_in(c,init)"), "b1"),
    (("is_in(b1,init)", "is_in(b3,init)", "hand_empty(r)", "is_in(c,init)"), "b2 has no location"),
    (("is_in(b1,init)", "hand_empty(r)"), "container"),
    (("is_in(b1,init)", "hand_empty(r)", "is_in(c,init)", "is_in(c,goal)"), "container"),
    (("is_in(b1,init)", "is_in(c,init)"), "hand"),
    (("is_holding(r,b1)", "is_holding(r,b2)", "is_in(c,init)"), "hand"),
    (("is_in(b1,init)", "hand_empty(r)", "is_in(c,init)", "is_in(b2,mars)"), "is_in(b2,mars)"),
])
def test_check_state_names_the_problem(atoms, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        sy.check_state(state(*atoms))


def test_pickup_stack_push_effects():
    s = sy.initial_state(2)
    s = sy.apply(s, "pickup(r,b2,init)")
    assert "is_holding(r,b2)" in s and "hand_empty(r)" not in s and "is_in(b2,init)" not in s
    s = sy.apply(s, "stack(r,b2,c)")
    assert {"at_container(b2,c)", "hand_empty(r)"} <= s and "is_holding(r,b2)" not in s
    s = sy.apply(s, "push(r,c,init,goal)")
    # the helper unloads the container at goal
    assert {"is_in(c,goal)", "is_in(b2,goal)"} <= s
    assert "at_container(b2,c)" not in s and "is_in(c,init)" not in s
    s = sy.apply(s, "push(r,c,goal,init)")
    assert "is_in(c,init)" in s and "is_in(b2,goal)" in s
    sy.check_state(s)


def test_pickup_from_table():
    s = state("is_in(b1,table)", "hand_empty(r)", "is_in(c,init)")
    assert sy.applicable(s, "pickup(r,b1,table)")
    assert not sy.applicable(s, "pickup(r,b1,init)")
    assert "is_holding(r,b1)" in sy.apply(s, "pickup(r,b1,table)")


@pytest.mark.parametrize("atoms, action, missing", [
    (("is_in(b1,init)", "hand_empty(r)", "is_in(c,init)"), "stack(r,b1,c)", "is_holding(r,b1)"),
    (("is_holding(r,b1)", "is_in(b2,init)", "is_in(c,init)"), "pickup(r,b2,init)", "hand_empty(r)"),
    (("is_holding(r,b1)", "is_in(c,init)"), "push(r,c,init,goal)", "hand_empty(r)"),
    (("is_in(b1,init)", "hand_empty(r)", "is_in(c,init)"), "push(r,c,goal,init)", "is_in(c,goal)"),
    (("is_holding(r,b1)", "is_in(c,goal)"), "stack(r,b1,c)", "is_in(c,init)"),
])
def test_unmet_precondition_is_named(atoms, action, missing):
    s = state(*atoms)
    assert not sy.applicable(s, action)
    with pytest.raises(ValueError, match=missing.replace("(", r"\(").replace(")", r"\)")):
        sy.apply(s, action)


def test_normalize_unloads_a_container_at_goal():
    s = state("at_container(b1,c)", "at_container(b2,c)", "is_in(b3,init)", "hand_empty(r)",
              "is_in(c,goal)")
    n = sy.normalize(s)
    assert {"is_in(b1,goal)", "is_in(b2,goal)"} <= n and not any(a.startswith("at_") for a in n)
    # a loaded container at init stays loaded
    at_init = state("at_container(b1,c)", "hand_empty(r)", "is_in(c,init)")
    assert sy.normalize(at_init) == at_init
    assert sy.is_goal(state("at_container(b1,c)", "hand_empty(r)", "is_in(c,goal)"))
    assert not sy.is_goal(at_init)


def test_validate_plan():
    plan = ["pickup(r,b1,init)", "stack(r,b1,c)", "pickup(r,b2,init)", "stack(r,b2,c)",
            "push(r,c,init,goal)"]
    final = sy.validate_plan(sy.initial_state(2), plan)
    assert sy.is_goal(final)
    with pytest.raises(ValueError, match="step 2: stack"):
        sy.validate_plan(sy.initial_state(2), ["pickup(r,b1,init)", "stack(r,b2,c)"])
    with pytest.raises(ValueError, match="b2 not delivered"):
        sy.validate_plan(sy.initial_state(2), plan[:2] + ["push(r,c,init,goal)"])
    partial = sy.validate_plan(sy.initial_state(2), plan[:2], require_goal=False)
    assert "at_container(b1,c)" in partial
