"""The clingo task planner: maximum expected utility, checked against brute force over all
load splits, valid plans from mid-episode states, errors, and the GP baseline."""
from __future__ import annotations

import itertools
import json
import time

import numpy as np
import pytest

from planner import symbolic as sy
from planner import task_planner as tp

COSTS = {"pickup": 15.0, "stack": 10.0, "push": 30.0, "fail": 50.0, "deliver": 40.0}


def attempt(cost: float, fail: float, p: float) -> float:
    """A pickup or stack repeated until it succeeds: 1/p attempts, 1/p - 1 failing (p >= 0.02)."""
    q = max(p, 0.02)
    return (cost + (1 - q) * fail) / q


# --------------------------------------------------------------------------- brute force

def compositions(n: int):
    """Every ordered split of n stacks into trips (2**(n-1) of them)."""
    for cuts in itertools.product((False, True), repeat=max(n - 1, 0)):
        parts, size = [], 1
        for cut in cuts:
            if cut:
                parts.append(size)
                size = 0
            size += 1
        yield parts + [size]


def pushed_until_delivered(p: float, load: int, rebuild: float, costs: dict) -> float:
    """A push of `load` repeated until it succeeds: 1/q pushes, 1/q - 1 failing, each
    failure also rebuilding the trip (`rebuild`), then the delivery (q = p >= 0.02)."""
    q = max(p, 0.02)
    failures = 1 / q - 1
    return -costs["push"] / q - failures * (costs["fail"] + rebuild) + costs["deliver"] * load


def trip_value(load: int, n_stacks: int, T: dict, costs: dict, mean_pick: float) -> float:
    """One trip: n_stacks stacks onto a container already holding `load` blocks, then its
    push until delivered (a failed push rebuilds the trip: the container brought back, its
    blocks picked up at `mean_pick` each and stacked from 0)."""
    fail = costs["fail"]
    value = 0.0
    for _ in range(n_stacks):
        value += -attempt(costs["stack"], fail, T["stack"][load])
        load += 1
    rebuild = costs["push"] + load * mean_pick + sum(
        attempt(costs["stack"], fail, T["stack"][j]) for j in range(load))
    return value + pushed_until_delivered(T["push"][load - 1], load, rebuild, costs)


def split_value(first_load: int, stacks: list[int], waiting: int, at_goal: bool,
                T: dict, costs: dict = COSTS, mean_pick: float | None = None, trip=None) -> float:
    """The expected-utility formula for a plan given by the stacks of each trip, written out
    independently of the planner: the first trip starts with first_load blocks loaded. A
    failed push's trip is rebuilt: the container brought back, its blocks picked up (at
    `mean_pick` each, by default the one class's expected pickup) and stacked from 0.
    `trip(load, n_stacks)` may stand in for `trip_value` (a memo of it)."""
    fail = costs["fail"]
    p_pick = T["pickup"] if not isinstance(T["pickup"], dict) else None
    if mean_pick is None:
        mean_pick = attempt(costs["pickup"], fail, p_pick)
    if trip is None:
        def trip(load, n):
            return trip_value(load, n, T, costs, mean_pick)
    value = 0.0 if p_pick is None else waiting * -attempt(costs["pickup"], fail, p_pick)
    returns = len(stacks) - 1 + at_goal
    value -= returns * costs["push"]
    for i, n_stacks in enumerate(stacks):
        value += trip(first_load if i == 0 else 0, n_stacks)
    return value


def best_split(T: dict, waiting: int, held: bool = False, preloaded: int = 0,
               at_goal: bool = False, costs: dict = COSTS, max_trips: int | None = None,
               mean_pick: float | None = None):
    """Best value over every way to split the remaining work into trips (every split is
    valued; a trip's value depends only on its first load and its stacks, so it is memoised:
    16 blocks are 2**15 splits)."""
    stacks = waiting + held
    candidates = []
    for parts in compositions(stacks) if stacks else [[0]]:
        candidates.append(parts)
        if preloaded and not held and stacks:      # the loaded container may leave at once
            candidates.append([0] + parts)
    if mean_pick is None and not isinstance(T["pickup"], dict):
        mean_pick = attempt(costs["pickup"], costs["fail"], T["pickup"])
    memo: dict[tuple[int, int], float] = {}

    def trip(load: int, n: int) -> float:
        if (load, n) not in memo:
            memo[(load, n)] = trip_value(load, n, T, costs, mean_pick)
        return memo[(load, n)]

    best = None
    for parts in candidates:
        if max_trips is not None and len(parts) > max_trips:
            continue
        value = split_value(preloaded, parts, waiting, at_goal, T, costs, mean_pick, trip)
        if best is None or value > best[0]:
            best = (value, parts)
    return best


def transition(n: int, push=lambda k: 1.0, stack=lambda j: 1.0, pickup=1.0) -> dict:
    return {"pickup": pickup, "stack": [float(stack(j)) for j in range(n)],
            "push": [float(push(k)) for k in range(1, n + 1)]}


def assert_valid_and_consistent(state, result: tp.Plan, T: dict, costs=None, **kw) -> None:
    final = sy.validate_plan(state, result.actions)
    assert sy.is_goal(final)
    assert result.expected_utility == pytest.approx(
        tp.expected_utility(state, result.actions, T, costs, **kw), rel=1e-12, abs=1e-9)
    assert all(type(x) is str for x in result.actions)
    assert all(type(k) is int for k in result.loads)
    assert type(result.expected_utility) is float and type(result.optimal) is bool


# --------------------------------------------------------------------------- optimality

def test_optimistic_T_loads_everything_in_one_trip():
    state = sy.initial_state(8)
    result = tp.plan(state, tp.optimistic_transition(8))
    assert result.loads == (8,)
    assert result.optimal
    assert result.expected_utility == pytest.approx(8 * -15 + 8 * -10 - 30 + 8 * 40)
    assert result.actions[:2] == ("pickup(r,b1,init)", "stack(r,b1,c)")
    assert result.actions[-1] == "push(r,c,init,goal)"
    assert_valid_and_consistent(state, result, tp.optimistic_transition(8))


PUSH_SHAPES = {
    "linear": lambda k: 1 - 0.08 * k,
    "step": lambda k: 1.0 if k <= 4 else 0.3,
    "steep": lambda k: 1.0 if k <= 2 else 0.1,
    "quadratic": lambda k: max(0.0, 1 - 0.015 * k * k),
}


@pytest.mark.parametrize("shape", sorted(PUSH_SHAPES))
def test_push_success_falling_with_load_splits_the_blocks_optimally(shape):
    T = transition(8, push=PUSH_SHAPES[shape])
    state = sy.initial_state(8)
    result = tp.plan(state, T)
    best, parts = best_split(T, waiting=8)
    assert result.optimal
    assert result.expected_utility == pytest.approx(best, rel=1e-6)
    assert result.loads != (8,) and sum(result.loads) == 8
    assert sorted(result.loads) == sorted(parts) or \
        split_value(0, list(result.loads), 8, False, T) == pytest.approx(best, rel=1e-6)
    assert_valid_and_consistent(state, result, T)


def test_stack_success_falling_with_pile_height_splits_the_blocks():
    T = transition(8, stack=lambda j: 1 - 0.1 * j)
    result = tp.plan(sy.initial_state(8), T)
    assert result.loads != (8,)
    assert result.expected_utility == pytest.approx(best_split(T, waiting=8)[0], rel=1e-6)
    assert result.optimal


def test_sixteen_blocks():
    T = transition(16, push=lambda k: max(0.0, 1 - 0.05 * k), stack=lambda j: 1 - 0.01 * j,
                   pickup=0.95)
    result = tp.plan(sy.initial_state(16), T)
    assert result.optimal
    assert result.expected_utility == pytest.approx(best_split(T, waiting=16)[0], rel=1e-6)
    assert_valid_and_consistent(sy.initial_state(16), result, T)


def test_free_pushes_still_terminate_and_stay_optimal():
    # With push cost 0 the return push is free, so the stopping bound never bites early.
    costs = dict(COSTS, push=0.0)
    T = transition(6, push=lambda k: 1 - 0.1 * k)
    result = tp.plan(sy.initial_state(6), T, costs)
    assert result.optimal
    assert result.expected_utility == pytest.approx(best_split(T, 6, costs=costs)[0], rel=1e-6)


def test_large_costs_are_scaled_to_fit_clingo_numbers():
    costs = {"pickup": 1e4, "stack": 1e4, "push": 1e4, "fail": 1e4, "deliver": 1e4}
    T = transition(16, push=lambda k: 1 - 0.05 * k)
    result = tp.plan(sy.initial_state(16), T, costs)
    assert result.expected_utility == pytest.approx(best_split(T, 16, costs=costs)[0], rel=1e-6)


def test_sizes_variation_counts_blocks_per_class():
    classes = {"b5": "large"}
    T = transition(8, push=PUSH_SHAPES["linear"])
    T["pickup"] = {"block": 0.9, "large": 0.6}
    result = tp.plan(sy.initial_state(8), T, block_classes=classes)
    # pickups are paid once per block whatever the split: add them to the split's value
    picks = 7 * -attempt(15, 50, 0.9) - attempt(15, 50, 0.6)
    # a spilled trip's blocks are priced at the mean pickup of the task's 8 blocks
    best = best_split(T, 8, mean_pick=-picks / 8)[0]
    assert result.expected_utility == pytest.approx(best + picks, rel=1e-6)
    assert_valid_and_consistent(sy.initial_state(8), result, T, block_classes=classes)
    assert result.optimal


def test_max_steps_limits_the_number_of_trips():
    T = transition(8, push=PUSH_SHAPES["steep"])
    result = tp.plan(sy.initial_state(8), T, max_steps=21)        # at most 3 trips
    assert len(result.actions) <= 21 and len(result.loads) <= 3
    assert result.expected_utility == pytest.approx(best_split(T, 8, max_trips=3)[0], rel=1e-6)
    assert result.optimal


# --------------------------------------------------------------------------- mid-episode

MID_EPISODE = {
    "block on the table": ["is_in(b1,goal)", "is_in(b2,table)", "is_in(b3,init)",
                           "is_in(b4,init)", "hand_empty(r)", "is_in(c,init)"],
    "holding a block": ["is_holding(r,b3)", "is_in(b1,init)", "is_in(b2,init)",
                        "is_in(b4,table)", "is_in(c,init)"],
    "container at goal with blocks": ["at_container(b1,c)", "at_container(b2,c)",
                                      "is_in(b3,init)", "is_in(b4,init)", "is_in(b5,init)",
                                      "hand_empty(r)", "is_in(c,goal)"],
    "some delivered, container back": ["is_in(b1,goal)", "is_in(b2,goal)", "is_in(b3,init)",
                                       "is_in(b4,init)", "hand_empty(r)", "is_in(c,init)"],
    "loaded container at init": ["at_container(b1,c)", "at_container(b2,c)",
                                 "at_container(b3,c)", "is_in(b4,init)", "is_in(b5,init)",
                                 "hand_empty(r)", "is_in(c,init)"],
    "loaded and holding": ["at_container(b1,c)", "at_container(b2,c)", "is_holding(r,b5)",
                           "is_in(b3,init)", "is_in(b4,table)", "is_in(c,init)"],
}


def _counts(state):
    s = sy.normalize(frozenset(state))
    waiting = sum(1 for a in s if a.startswith("is_in(b") and not a.endswith(",goal)"))
    preloaded = sum(1 for a in s if a.startswith("at_container("))
    held = any(a.startswith("is_holding(") for a in s)
    return waiting, held, preloaded, "is_in(c,goal)" in s


@pytest.mark.parametrize("name", sorted(MID_EPISODE))
@pytest.mark.parametrize("shape", ["optimistic", "linear", "steep"])
def test_mid_episode_states_give_valid_optimal_plans(name, shape):
    state = MID_EPISODE[name]
    n = len(sy.blocks(state))
    T = transition(n, push=PUSH_SHAPES.get(shape, lambda k: 1.0),
                   stack=lambda j: 1 - 0.05 * j)
    result = tp.plan(state, T)
    assert_valid_and_consistent(state, result, T)
    waiting, held, preloaded, at_goal = _counts(state)
    assert result.expected_utility == pytest.approx(
        best_split(T, waiting, held, preloaded, at_goal)[0], rel=1e-6)
    assert result.optimal


def test_table_blocks_are_picked_up_where_they_lie():
    result = tp.plan(MID_EPISODE["block on the table"], transition(4))
    assert "pickup(r,b2,table)" in result.actions
    assert result.actions[0] == "pickup(r,b2,table)"      # table blocks first, then init


def test_container_at_goal_goes_back_first():
    result = tp.plan(MID_EPISODE["container at goal with blocks"], transition(5))
    assert result.actions[0] == "push(r,c,goal,init)"
    assert result.loads == (3,)           # b1 and b2 were unloaded on arrival


def test_random_mid_episode_states_match_brute_force():
    rng = np.random.default_rng(7)
    for _ in range(40):
        n = int(rng.integers(1, 8))
        places = rng.choice(["init", "table", "goal", "container"], size=n, p=[.5, .2, .15, .15])
        at_goal = bool(rng.random() < 0.25)
        holder = None if at_goal or rng.random() < 0.6 else int(rng.integers(n))
        atoms = {"is_in(c,goal)" if at_goal else "is_in(c,init)"}
        for i, place in enumerate(places, start=1):
            if i - 1 == holder:
                atoms.add(f"is_holding(r,b{i})")
            elif place == "container":
                atoms.add(f"at_container(b{i},c)")
            else:
                atoms.add(f"is_in(b{i},{place})")
        if holder is None:
            atoms.add("hand_empty(r)")
        # (the defaults bind one draw per model, on purpose)
        T = transition(n, push=lambda k, a=rng.uniform(0, .25): max(0.0, 1 - a * k),  # noqa: B008
                       stack=lambda j, b=rng.uniform(0, .1): 1 - b * j,  # noqa: B008
                       pickup=float(rng.uniform(.5, 1)))
        result = tp.plan(atoms, T)
        sy.validate_plan(atoms, result.actions)
        waiting, held, preloaded, goal = _counts(atoms)
        expected = best_split(T, waiting, held, preloaded, goal)[0] if waiting + held + preloaded else 0.0
        assert result.expected_utility == pytest.approx(expected, rel=1e-6, abs=1e-6), sorted(atoms)
        assert result.optimal


def test_goal_state_gives_the_empty_plan():
    state = ["is_in(b1,goal)", "at_container(b2,c)", "hand_empty(r)", "is_in(c,goal)"]
    result = tp.plan(state, transition(2))
    assert result.actions == () and result.loads == () and result.optimal
    assert result.expected_utility == 0.0


# --------------------------------------------------------------------------- errors

def test_unreachable_goal_is_an_error_not_a_hang():
    state = ["is_holding(r,b1)", "is_in(b2,init)", "is_in(c,goal)"]
    started = time.perf_counter()
    with pytest.raises(tp.PlanningError, match="goal unreachable.*holds b1"):
        tp.plan(state, transition(2))
    with pytest.raises(tp.PlanningError, match="max_steps=5"):
        tp.plan(sy.initial_state(8), transition(8), max_steps=5)
    assert time.perf_counter() - started < 2.0


@pytest.mark.parametrize("atoms, named", [
    (["is_in(b1,init)", "is_in(b1,goal)", "hand_empty(r)", "is_in(c,init)"], "b1"),
    (["is_in(b1,init)", "hand_empty(r)", "is_in(c,init)", "is_on(b1,b2)"], "is_on(b1,b2)"),
    (["is_in(b1,init)", "hand_empty(r)", "is_in(c,table)"], "is_in(c,table)"),
    (["is_in(b1,init)", "is_in(c,init)"], "hand"),
])
def test_malformed_states_name_the_atom(atoms, named):
    with pytest.raises(tp.PlanningError, match=named.replace("(", r"\(").replace(")", r"\)")):
        tp.plan(atoms, transition(1))
    assert issubclass(tp.PlanningError, ValueError)


@pytest.mark.parametrize("change, message", [
    ({"push": [1.0] * 7}, r"push: expected 8 probabilities \(loads 1..8\), got 7"),
    ({"stack": [1.0] * 9}, r"stack: expected 8 probabilities \(pile heights 0..7\), got 9"),
    ({"push": [1.0] * 7 + [1.5]}, r"push\[7\]: probability 1.5 is not in \[0, 1\]"),
    ({"stack": [float("nan")] * 8}, r"stack\[0\]"),
    ({"pickup": -0.1}, "pickup"),
    ({"pickup": "high"}, "pickup"),
    ({"push": "1,1,1"}, "push"),
    ({"pickup": {"block": 1.0, "huge": 0.5}}, "unknown block class 'huge'"),
    ({"pick": 1.0}, "unknown field 'pick'"),
])
def test_bad_transition_models_name_the_field(change, message):
    T = dict(transition(8), **change)
    with pytest.raises(tp.PlanningError, match=message):
        tp.plan(sy.initial_state(8), T)


def test_missing_fields_and_bad_costs_are_named():
    with pytest.raises(tp.PlanningError, match="missing field 'push'"):
        tp.plan(sy.initial_state(2), {"pickup": 1.0, "stack": [1.0, 1.0]})
    with pytest.raises(tp.PlanningError, match="no probability for block class 'large'"):
        tp.plan(sy.initial_state(2), dict(transition(2), pickup={"block": 1.0}),
                block_classes={"b2": "large"})
    with pytest.raises(tp.PlanningError, match="unknown block 'b9'"):
        tp.plan(sy.initial_state(2), transition(2), block_classes={"b9": "large"})
    with pytest.raises(tp.PlanningError, match="'push' must be a finite number >= 0"):
        tp.plan(sy.initial_state(2), transition(2), {"push": -1})
    with pytest.raises(tp.PlanningError, match="unknown field 'bribe'"):
        tp.plan(sy.initial_state(2), transition(2), {"bribe": 1})


def test_expected_utility_by_hand_and_bad_plans():
    T = transition(2, push=lambda k: 0.5)
    actions = ["pickup(r,b1,init)", "stack(r,b1,c)", "push(r,c,init,goal)",
               "push(r,c,goal,init)", "pickup(r,b2,init)", "stack(r,b2,c)",
               "push(r,c,init,goal)"]
    # p 0.5: two pushes, one failing (50) and rebuilding its trip of one block (the return
    # push 30, a pickup 15, a stack 10), then the delivery (40)
    trip = -15 - 10 + (-2 * 30 - (50 + 30 + 15 + 10) + 40)
    assert tp.expected_utility(sy.initial_state(2), actions, T) == pytest.approx(2 * trip - 30)
    with pytest.raises(tp.PlanningError, match="step 2"):
        tp.expected_utility(sy.initial_state(2), ["pickup(r,b1,init)", "push(r,c,init,goal)"], T)


def test_plan_to_dict_is_json():
    result = tp.plan(sy.initial_state(3), transition(3))
    data = json.loads(json.dumps(result.to_dict()))
    assert set(data) == {"plan", "loads", "expected_utility", "optimal", "solve_ms"}
    assert data["plan"] == list(result.actions) and data["loads"] == [3]


def test_optimistic_transition():
    assert tp.optimistic_transition(3) == {"pickup": 1.0, "stack": [1.0] * 3, "push": [1.0] * 3}
    with pytest.raises(tp.PlanningError):
        tp.optimistic_transition(0)


# --------------------------------------------------------------------------- GP baseline

def test_satisficing_plans_are_valid_and_seeded():
    state = sy.initial_state(8)
    plans = [tp.satisficing(state, rng=np.random.default_rng(seed)) for seed in range(6)]
    for result in plans:
        assert_valid_and_consistent(state, result, tp.optimistic_transition(8))
        assert not result.optimal and sum(result.loads) == 8
    again = tp.satisficing(state, rng=np.random.default_rng(3))
    assert again.actions == plans[3].actions
    assert len({p.actions for p in plans}) == len(plans)


@pytest.mark.parametrize("name", sorted(MID_EPISODE))
def test_satisficing_from_mid_episode_states(name):
    state = MID_EPISODE[name]
    rng = np.random.default_rng(11)
    T = transition(len(sy.blocks(state)), push=PUSH_SHAPES["linear"])
    for _ in range(10):
        result = tp.satisficing(state, rng=rng, transition=T)
        assert_valid_and_consistent(state, result, T)


def test_satisficing_is_uniform_over_load_splits():
    rng = np.random.default_rng(0)
    counts: dict[tuple, int] = {}
    for _ in range(800):
        loads = tp.satisficing(sy.initial_state(3), rng=rng).loads
        counts[loads] = counts.get(loads, 0) + 1
    assert set(counts) == {(3,), (1, 2), (2, 1), (1, 1, 1)}
    assert all(150 <= c <= 250 for c in counts.values()), counts


def test_satisficing_never_beats_the_optimum():
    T = transition(8, push=PUSH_SHAPES["linear"])
    best = tp.plan(sy.initial_state(8), T).expected_utility
    rng = np.random.default_rng(5)
    for _ in range(20):
        assert tp.satisficing(sy.initial_state(8), rng=rng, transition=T).expected_utility \
            <= best + 1e-9
