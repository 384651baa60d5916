"""The stack-and-push task half: symbolic model, T's contexts, and the clingo planner
proven optimal against an independent check (exact Bellman recursion over the symbolic
model, which shares nothing with the ASP encoding or its weight rewriting)."""
from __future__ import annotations

import functools
import json
import math

import numpy as np
import pytest

from coordinator.cli import main
from planner import stack_and_push as sp
from planner.domain import UnknownAction
from planner.task_planner import DEFAULT_COSTS, PlanningError

PUSH = "push(r,tower,start,goal)"


# -- symbolic model -------------------------------------------------------------------------
def test_initial_state_and_goal():
    s = sp.initial_state(3)
    assert s == {"is_in(b1,init)", "is_in(b2,init)", "is_in(b3,init)", "hand_empty(r)"}
    assert not sp.is_goal(s)
    assert sp.is_goal(frozenset({"is_in(b1,goal)", "is_in(b2,goal)", "hand_empty(r)"}))


def test_apply_builds_a_tower_and_a_push_delivers_it():
    s = sp.initial_state(3)
    for b in ("b2", "b1"):
        s = sp.apply(s, f"pickup(r,{b},init)")
        assert f"is_holding(r,{b})" in s and "hand_empty(r)" not in s
        s = sp.apply(s, f"stack(r,{b},tower)")
    assert {"on(b2,start)", "on(b1,b2)"} <= s and sp.tower(s) == ["b2", "b1"]
    s = sp.apply(s, PUSH)
    assert {"is_in(b1,goal)", "is_in(b2,goal)", "is_in(b3,init)"} <= s
    assert not any(a.startswith("on(") for a in s)


@pytest.mark.parametrize("state, action, message", [
    (["is_in(b1,init)", "hand_empty(r)"], "stack(r,b1,tower)", "is_holding"),
    (["is_in(b1,init)", "hand_empty(r)"], PUSH, "no tower"),
    (["is_holding(r,b1)"], "pickup(r,b1,init)", "precondition"),
    (["is_in(b1,rail)", "hand_empty(r)"], "pickup(r,b1,init)", r"is_in\(b1,init\)"),
])
def test_unmet_preconditions_are_named(state, action, message):
    with pytest.raises(ValueError, match=message):
        sp.apply(sp.parse_state(state), action)


@pytest.mark.parametrize("atoms, message", [
    (["is_in(b1,init)"], "hand_empty"),
    (["is_in(b1,shelf)", "hand_empty(r)"], "is_in\\(b1,shelf\\)"),
    (["is_in(b1,init)", "on(b1,start)", "hand_empty(r)"], "already"),
    (["on(b2,b1)", "is_in(b1,init)", "hand_empty(r)"], "on\\(b2,b1\\)"),
    (["on(b1,start)", "on(b2,start)", "hand_empty(r)"], "on\\(b"),
    (["is_in(b2,init)", "hand_empty(r)"], "b1 is missing"),
    (["at_container(b1,c)", "hand_empty(r)"], "unknown atom"),
])
def test_bad_states_name_the_atom(atoms, message):
    with pytest.raises(ValueError, match=message):
        sp.parse_state(atoms)


def test_atoms_are_kept_canonical_whatever_their_spelling():
    """Issue 25, row 14: "on(b1,start)." passed the parser and was kept as sent, so the
    planner later failed on it (a 409 "cannot plan" for a state that was accepted)."""
    sent = sp.parse_state(["on(b1,start).", " on( b2 , b1 ) ", "is_holding(r,b3)."])
    assert sent == sp.parse_state(["on(b1,start)", "on(b2,b1)", "is_holding(r,b3)"])
    assert sp.StackAndPushTask().context_of(sent, "stack(r,b3,tower)") == ("stack", 2)


def test_contexts_are_tower_heights_and_unknown_actions_raise():
    task = sp.StackAndPushTask()
    assert task.contexts(3) == (("pickup", 0), ("stack", 0), ("stack", 1), ("stack", 2),
                                ("push", 1), ("push", 2), ("push", 3))
    s = sp.parse_state(["on(b1,start)", "on(b2,b1)", "is_holding(r,b3)"])
    assert task.context_of(s, "stack(r,b3,tower)") == ("stack", 2)
    assert task.context_of(s, "pickup(r,b3,init)") == ("pickup", 0)
    s = sp.apply(s, "stack(r,b3,tower)")
    assert task.context_of(s, PUSH) == ("push", 3)
    # The container's action names with the container's arguments are not this domain's:
    # a silent ("stack", 0) at every height is what made them mis-learned before.
    for bad in ("stack(r,b3,c)", "push(r,c,init,goal)", "place(r,b1)", "push(r,tower,goal,start)"):
        with pytest.raises(UnknownAction):
            task.context_of(s, bad)
    with pytest.raises(UnknownAction, match="no tower"):
        task.context_of(sp.initial_state(2), PUSH)


# -- optimality against an independent check -----------------------------------------------
def attempt(cost: float, fail: float, p: float) -> float:
    """A pickup or stack repeated until it succeeds: 1/p attempts, 1/p - 1 failing (p >= 0.02)."""
    q = max(p, 0.02)
    return (cost + (1 - q) * fail) / q


def _pushed(T: dict, h: int, c: dict) -> float:
    """A push of a tower of h repeated until it delivers: 1/q pushes, 1/q - 1 of them
    failing, each failure rebuilding the tower (h pickups, stacks onto 0..h-1; no return
    push in this domain), then +deliver per block (q = p >= 0.02)."""
    q = max(T["push"][h - 1], 0.02)
    rebuild = h * attempt(c["pickup"], c["fail"], T["pickup"]) + sum(
        attempt(c["stack"], c["fail"], T["stack"][j]) for j in range(h))
    return -c["push"] / q - (1 / q - 1) * (c["fail"] + rebuild) + c["deliver"] * h


def _bellman(state: frozenset[str], T: dict, costs: dict = DEFAULT_COSTS) -> float:
    """Max expected utility over every action sequence to the goal, by exact recursion over
    the symbolic model (each action's value as the task's utility defines it)."""
    c = costs

    @functools.lru_cache(maxsize=None)
    def best(s: frozenset[str]) -> float:
        if sp.is_goal(s):
            return 0.0
        values = []
        for action in _moves(s):
            h = len(sp.tower(s))
            if action.startswith("pickup"):
                p = T["pickup"]
                v = -attempt(c["pickup"], c["fail"], p)
            elif action.startswith("stack"):
                p = T["stack"][h]
                v = -attempt(c["stack"], c["fail"], p)
            else:
                v = _pushed(T, h, c)
            values.append(v + best(sp.apply(s, action)))
        return max(values)

    return best(frozenset(state))


def _moves(s: frozenset[str]) -> list[str]:
    held = sp.held_block(s)
    if held is not None:
        return [f"stack(r,{held},tower)"]
    moves = [f"pickup(r,{a[6:-1].split(',')[0]},{a[6:-1].split(',')[1]})" for a in s
             if a.startswith("is_in(") and not a.endswith(",goal)")]
    # a push sweeps what lies on the rail: the planner pushes only with the rail clear
    rail_clear = not any(a.startswith("is_in(") and a.endswith(",rail)") for a in s)
    return moves + ([PUSH] if sp.tower(s) and rail_clear else [])


def _random_T(rng: np.random.Generator, n: int) -> dict:
    return {"pickup": float(rng.uniform(0.6, 1.0)), "stack": rng.uniform(0.5, 1.0, n).tolist(),
            "push": np.sort(rng.uniform(0.0, 1.0, n))[::-1].tolist()}


def _random_state(rng: np.random.Generator, n: int) -> frozenset[str]:
    """Blocks spread over init, table, rail, goal, the hand and a tower of any height."""
    names = [f"b{i}" for i in range(1, n + 1)]
    rng.shuffle(names)
    atoms, k = [], 0
    h = int(rng.integers(0, n))
    for i, b in enumerate(names[:h]):
        atoms.append(f"on({b},{'start' if i == 0 else names[i - 1]})")
    k = h
    if k < n and rng.random() < 0.4:
        atoms.append(f"is_holding(r,{names[k]})")
        k += 1
    else:
        atoms.append("hand_empty(r)")
    for b in names[k:]:
        atoms.append(f"is_in({b},{rng.choice(['init', 'init', 'table', 'rail', 'goal'])})")
    return sp.parse_state(atoms)


def test_plan_equals_the_bellman_optimum_from_random_states():
    rng = np.random.default_rng(13)
    checked = 0
    for _ in range(60):
        n = int(rng.integers(1, 6))
        state, T = _random_state(rng, n), _random_T(rng, n)
        if sp.is_goal(state):
            continue
        plan = sp.plan(state, T)
        assert plan.optimal
        assert plan.expected_utility == pytest.approx(_bellman(state, T), abs=1e-6), (sorted(state), T)
        assert sp.expected_utility(state, plan.actions, T) == pytest.approx(plan.expected_utility)
        final = state
        for a in plan.actions:
            final = sp.apply(final, a)
        assert sp.is_goal(final)
        checked += 1
    assert checked >= 40


def _best_split(n: int, T: dict, c: dict = DEFAULT_COSTS) -> tuple[float, list[int]]:
    """From all blocks at init: the best split of n blocks into towers, by enumerating
    every composition of n (2^(n-1) of them)."""
    best = (-math.inf, [])
    for mask in range(2 ** (n - 1)):
        loads, cur = [], 1
        for i in range(n - 1):
            if mask >> i & 1:
                loads.append(cur)
                cur = 1
            else:
                cur += 1
        loads.append(cur)
        v = n * -attempt(c["pickup"], c["fail"], T["pickup"])
        for k in loads:
            v += sum(-attempt(c["stack"], c["fail"], T["stack"][h]) for h in range(k))
            v += _pushed(T, k, c)
        best = max(best, (v, sorted(loads, reverse=True)))
    return best


def test_plan_at_eight_blocks_equals_the_best_split():
    rng = np.random.default_rng(5)
    for _ in range(25):
        T = _random_T(rng, 8)
        plan = sp.plan(sp.initial_state(8), T)
        value, _ = _best_split(8, T)
        assert plan.optimal and plan.expected_utility == pytest.approx(value, abs=1e-6)


def test_graded_push_curve_gives_two_towers_of_four():
    """The probe's curve (push 16,16,16,16,15,9,0,0 of 16): two towers of four beat one of
    five plus three, and a single tower of eight is worst."""
    T = {"pickup": 1.0, "stack": [1.0] * 8, "push": [1, 1, 1, 1, 15 / 16, 9 / 16, 0, 0]}
    plan = sp.plan(sp.initial_state(8), T)
    assert plan.loads == (4, 4) and plan.expected_utility == pytest.approx(60.0)
    assert plan.actions.count(PUSH) == 2 and "push(r,c,goal,init)" not in plan.actions
    optimistic = sp.plan(sp.initial_state(8), sp.StackAndPushTask().optimistic_transition(8))
    assert optimistic.loads == (8,)


def test_no_push_before_the_rail_is_clear():
    """A push sweeps the blocks lying on the rail in front of the tower, a load T's context
    (the tower's height) does not see: the plan picks them up before its first push, even
    where T would rather push the standing tower first."""
    state = sp.parse_state(["on(b1,start)", "on(b2,b1)", "is_in(b3,rail)", "is_in(b4,init)",
                            "is_in(b5,init)", "hand_empty(r)"])
    # a tower of 3 topples: the unconstrained best pushes the standing two at once
    T = {"pickup": 1.0, "stack": [1.0] * 5, "push": [1.0, 1.0, 0.0, 0.0, 0.0]}
    plan = sp.plan(state, T)
    first_push = plan.actions.index(PUSH)
    assert "pickup(r,b3,rail)" in plan.actions[:first_push], plan.actions
    assert plan.optimal and plan.expected_utility == pytest.approx(_bellman(state, T), abs=1e-6)
    clear = sp.parse_state(["on(b1,start)", "on(b2,b1)", "is_in(b3,init)", "is_in(b4,init)",
                            "is_in(b5,init)", "hand_empty(r)"])
    assert sp.plan(clear, T).actions[0] == PUSH          # with the rail clear it pushes the two first


def test_max_steps_and_bad_transition_are_refused_by_name():
    s = sp.initial_state(3)
    with pytest.raises(PlanningError, match="max_steps"):
        sp.plan(s, sp.StackAndPushTask().optimistic_transition(3), max_steps=5)
    with pytest.raises(PlanningError, match="push"):
        sp.plan(s, {"pickup": 1.0, "stack": [1, 1, 1], "push": [1, 1]})
    with pytest.raises(PlanningError, match="stack\\[1\\]"):
        sp.plan(s, {"pickup": 1.0, "stack": [1, 2, 1], "push": [1, 1, 1]})


def test_satisficing_is_a_valid_seeded_random_plan():
    task = sp.StackAndPushTask()
    s = sp.parse_state(["on(b1,start)", "is_in(b2,rail)", "is_in(b3,init)", "is_in(b4,init)",
                        "hand_empty(r)"])
    plans = [task.satisficing(s, rng=np.random.default_rng(i)) for i in range(30)]
    assert plans[0].actions == task.satisficing(s, rng=np.random.default_rng(0)).actions
    assert len({p.loads for p in plans}) >= 4
    for p in plans:
        final = s
        for a in p.actions:
            final = sp.apply(final, a)
        assert sp.is_goal(final) and sum(p.loads) == 4
        assert p.expected_utility <= task.plan(s, task.optimistic_transition(4)).expected_utility + 1e-9


# -- tmoc plan --domain stack_and_push ---------------------------------------------------------
def test_cli_plan_json(capsys, tmp_path):
    code = main(["plan", "--domain", "stack_and_push", "--blocks", "8", "--p-push",
                 "1,1,1,1,0.94,0.56,0,0", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    data = json.loads(out)
    assert data["domain"] == "stack_and_push" and data["loads"] == [4, 4] and data["optimal"]
    assert data["expected_utility"] == pytest.approx(60.0)
    state = tmp_path / "state.lp"
    state.write_text("on(b1,start). on(b2,b1). is_in(b3,rail). hand_empty(r).\n")
    assert main(["plan", "--domain", "stack_and_push", "--state", str(state), "--json"]) == 0
    data = json.loads(capsys.readouterr()[0])
    assert data["blocks"] == 3 and data["plan"] == ["pickup(r,b3,rail)", "stack(r,b3,tower)", PUSH]
    assert main(["plan", "--domain", "stack_and_push", "--blocks", "3", "--p-stack", "1,1"]) == 2
    assert "--p-stack" in capsys.readouterr()[1]
