"""Motion planner: the transit strategy (straight, candidates, OMPL RRT*), RRT* itself,
checked approaches, the box checker."""
from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from planner.motion import (
    Bounds,
    MotionPlanningError,
    box_checker,
    interpolate_config,
    path_length,
    plan_approach,
    plan_rrtstar,
    plan_transit,
    unwrap_yaw,
)

BOUNDS = Bounds(np.array([-0.6, -0.6, 0.0, -math.pi]), np.array([0.6, 0.6, 0.8, math.pi]))
GRIPPER = (0.02, 0.06, 0.03)
# A wall across the straight line from START to GOAL: the planner must go over or round it.
WALL = ((0.0, 0.0, 0.25), (0.05, 0.4, 0.25))
START = np.array([-0.3, 0.0, 0.1, 0.0])
GOAL = np.array([0.3, 0.1, 0.1, 3.0])
FAST = dict(iterations=300)  # enough for this scene; keeps the file fast


def wall_checker():
    return box_checker([WALL], GRIPPER)


def yaw_diff(a: float, b: float) -> float:
    """Short signed angle from a to b, computed independently of the module."""
    return math.atan2(math.sin(b - a), math.cos(b - a))


def assert_path_valid(path: np.ndarray, is_valid, *, sub: int = 25) -> None:
    """Every waypoint and `sub` states inside every segment (yaw the short way) are valid."""
    for i, q in enumerate(path):
        assert is_valid(q), f"waypoint {i} {q} in collision"
    for i, (a, b) in enumerate(zip(path[:-1], path[1:])):
        dyaw = yaw_diff(a[3], b[3])
        for t in np.linspace(0.0, 1.0, sub + 2)[1:-1]:
            q = a + t * (b - a)
            q[3] = a[3] + t * dyaw
            assert is_valid(q), f"segment {i} at t={t:.3f} ({q}) in collision"


def assert_resolution(path: np.ndarray, resolution: float, yaw_weight: float = 0.1) -> None:
    dpos = np.linalg.norm(np.diff(path[:, :3], axis=0), axis=1)
    dyaw = np.array([abs(yaw_diff(a, b)) for a, b in zip(path[:-1, 3], path[1:, 3])])
    assert dpos.max() <= resolution + 1e-12
    assert dyaw.max() <= resolution / yaw_weight + 1e-12


@pytest.fixture(scope="module")
def wall_plan() -> np.ndarray:
    return plan_rrtstar(START, GOAL, wall_checker(), BOUNDS, seed=7, **FAST)


# ----------------------------------------------------------------------------- RRT*


def test_rrtstar_detours_round_wall_and_is_collision_free(wall_plan):
    path = wall_plan
    chk = wall_checker()
    assert not chk(interpolate_config(START, GOAL, 0.5))  # the straight line is blocked
    assert path.dtype == np.float64 and path.ndim == 2 and path.shape[1] == 4
    # exact endpoints, bit for bit
    assert path[0].tobytes() == START.tobytes()
    assert path[-1].tobytes() == GOAL.tobytes()
    assert_path_valid(path, chk)
    assert_resolution(path, 0.01)
    # a real detour: longer than the blocked straight line
    assert path_length(path) > np.linalg.norm(GOAL[:3] - START[:3]) + 0.05


def test_same_seed_same_path_different_seed_different_path(wall_plan):
    path = wall_plan
    chk = wall_checker()
    other = plan_rrtstar(START, GOAL, chk, BOUNDS, seed=8, **FAST)
    again = plan_rrtstar(START, GOAL, chk, BOUNDS, seed=7, **FAST)  # after another seed ran
    assert again.shape == path.shape and again.tobytes() == path.tobytes()
    assert other.shape != path.shape or not np.array_equal(other, path)


def test_goal_in_obstacle_raises_naming_goal():
    with pytest.raises(MotionPlanningError, match=r"^goal \(x=0\.0000.*\) is in collision"):
        plan_rrtstar(START, [0.0, 0.0, 0.2, 0.0], wall_checker(), BOUNDS, seed=1)
    with pytest.raises(MotionPlanningError, match=r"^start .* is in collision"):
        plan_rrtstar([0.0, 0.3, 0.3, 0.0], GOAL, wall_checker(), BOUNDS, seed=1)


def test_out_of_bounds_names_the_coordinate():
    with pytest.raises(MotionPlanningError, match=r"^goal .* out of bounds on z \(z=0\.9"):
        plan_rrtstar(START, [0.3, 0.1, 0.9, 0.0], wall_checker(), BOUNDS, seed=1)
    with pytest.raises(MotionPlanningError, match=r"^start .* out of bounds on x .*, y "):
        plan_rrtstar([-0.7, 0.7, 0.1, 0.0], GOAL, wall_checker(), BOUNDS, seed=1)
    # yaw wraps with full-turn bounds: any angle is in bounds
    path = plan_rrtstar([0.3, 0.3, 0.6, 4.0], [0.3, -0.3, 0.6, -4.0], wall_checker(), BOUNDS, seed=1)
    assert path[0, 3] == 4.0 and path[-1, 3] == -4.0


@pytest.mark.parametrize("bad, match", [
    ([0.0, 0.0, 0.1], r"start must be a finite array of shape \(4,\), got shape \(3,\)"),
    ([0.0, np.nan, 0.1, 0.0], "start must be finite"),
    ("abc", "start must be a finite array"),
])
def test_malformed_configuration(bad, match):
    with pytest.raises(MotionPlanningError, match=match):
        plan_rrtstar(bad, GOAL, wall_checker(), BOUNDS, seed=1)


def test_no_path_within_budget_is_an_error():
    # the goal sits in a closed cage (free inside, so only the search can fail)
    cage = [((0.3, 0.0, 0.2), (0.12, 0.12, 0.01)), ((0.3, 0.0, 0.0), (0.12, 0.12, 0.01)),
            ((0.42, 0.0, 0.1), (0.01, 0.12, 0.11)), ((0.18, 0.0, 0.1), (0.01, 0.12, 0.11)),
            ((0.3, 0.12, 0.1), (0.12, 0.01, 0.11)), ((0.3, -0.12, 0.1), (0.12, 0.01, 0.11))]
    chk = box_checker(cage, gripper_radius=0.02)
    with pytest.raises(MotionPlanningError, match=r"no collision-free path .* within 200 RRT\* iterations"):
        plan_rrtstar(START, [0.3, 0.0, 0.1, 0.0], chk, BOUNDS, seed=1, iterations=50, max_iterations=200)


def test_bounded_yaw_does_not_wrap_and_rrtstar_works():
    bounds = Bounds(np.array([-0.6, -0.6, 0.0, -1.5]), np.array([0.6, 0.6, 0.8, 1.5]))
    start, goal = np.array([-0.3, 0.0, 0.1, -1.2]), np.array([0.3, 0.1, 0.1, 1.2])
    path = plan_rrtstar(start, goal, wall_checker(), bounds, seed=3, **FAST)
    assert path[0].tobytes() == start.tobytes() and path[-1].tobytes() == goal.tobytes()
    assert np.all(path[:, 3] >= -1.5) and np.all(path[:, 3] <= 1.5)
    # without wrapping, yaw moves linearly between waypoints
    for i, (a, b) in enumerate(zip(path[:-1], path[1:])):
        for t in np.linspace(0, 1, 12)[1:-1]:
            assert wall_checker()(a + t * (b - a)), f"segment {i}"
    with pytest.raises(MotionPlanningError, match="out of bounds on yaw"):
        plan_rrtstar(start, [0.3, 0.1, 0.1, 2.0], wall_checker(), bounds, seed=3)


def test_validity_callable_errors_propagate():
    chk = wall_checker()
    calls = [0]

    def flaky(q: np.ndarray) -> bool:
        calls[0] += 1
        if calls[0] > 500:
            raise RuntimeError("collision query died")
        return chk(q)

    with pytest.raises(RuntimeError, match="collision query died"):
        plan_rrtstar(START, GOAL, flaky, BOUNDS, seed=1, **FAST)


def test_validity_callable_gets_4_arrays():
    seen: list[np.ndarray] = []
    chk = wall_checker()

    def spy(q):
        seen.append(q)
        return chk(q)

    plan_rrtstar(START, GOAL, spy, BOUNDS, seed=2, iterations=30)
    assert seen and all(isinstance(q, np.ndarray) and q.shape == (4,) and q.dtype == np.float64
                        for q in seen[:1000])


# ----------------------------------------------------------------------------- transit strategy

# Over the wall (its top is at z = 0.5): up, across at 0.7, down.
OVER = np.array([START, [*START[:2], 0.7, 0.0], [*GOAL[:2], 0.7, 3.0], GOAL])


class Draws:
    """A seed source that counts how often it is drawn from."""

    def __init__(self) -> None:
        self.n = 0

    def __call__(self) -> int:
        self.n += 1
        return 7


def test_transit_takes_the_straight_segment_when_free_without_drawing_a_seed():
    start, goal = np.array([-0.3, 0.3, 0.6, 3.0]), np.array([0.3, 0.3, 0.6, -3.0])
    seed = Draws()
    plan = plan_transit(start, goal, wall_checker(), BOUNDS, seed=seed, candidates=[("over", OVER)])
    assert (plan.strategy, plan.fallback, seed.n) == ("straight", None, 0)
    assert plan.path.tobytes() == np.array([start, goal]).tobytes()


def test_transit_tries_candidates_in_order_then_rrtstar():
    blocked = np.array([START, [0.0, 0.0, 0.2, 0.0], GOAL])          # through the wall
    seed = Draws()
    plan = plan_transit(START, GOAL, wall_checker(), BOUNDS, seed=seed,
                        candidates=[("through", blocked), ("over", OVER)])
    assert (plan.strategy, plan.fallback, seed.n) == ("over", None, 0)
    assert plan.path.tobytes() == OVER.tobytes()
    # No candidate is free: RRT*, seeded from one draw, the same path as plan_rrtstar's.
    plan = plan_transit(START, GOAL, wall_checker(), BOUNDS, seed=seed, candidates=[("through", blocked)],
                        **FAST)
    assert (plan.strategy, plan.fallback, seed.n) == ("rrtstar", None, 1)
    assert plan.path.tobytes() == plan_rrtstar(START, GOAL, wall_checker(), BOUNDS, seed=7, **FAST).tobytes()
    # straight=False skips the straight segment even where it is free.
    free_start, free_goal = np.array([-0.3, 0.3, 0.6, 0.0]), np.array([0.3, 0.3, 0.6, 0.0])
    plan = plan_transit(free_start, free_goal, wall_checker(), BOUNDS, seed=1, straight=False, iterations=50)
    assert plan.strategy == "rrtstar"


def test_transit_that_finds_nothing_says_why():
    inside = np.array([0.0, 0.0, 0.2, 0.0])                             # in the wall
    plan = plan_transit(START, inside, wall_checker(), BOUNDS, seed=1,
                        candidates=[("over", np.array([START, [*START[:2], 0.7, 0.0], inside]))])
    assert plan.path is None and plan.strategy == "none"
    assert plan.fallback.startswith("goal (x=0.0000") and "in collision" in plan.fallback
    assert plan.fallback.endswith("(tried straight, over, rrtstar)")


# ----------------------------------------------------------------------------- approach


def test_plan_approach_segment():
    chk = wall_checker()
    pre, pose = np.array([0.3, 0.2, 0.3, 0.5]), np.array([0.31, 0.19, 0.12, 0.4])
    seg = plan_approach(pre, pose, chk)
    assert seg[0].tobytes() == pre.tobytes() and seg[-1].tobytes() == pose.tobytes()
    assert_resolution(seg, 0.01)
    assert_path_valid(seg, chk)
    block = box_checker([((0.3, 0.2, 0.2), (0.03, 0.03, 0.01))], GRIPPER)
    with pytest.raises(MotionPlanningError, match=r"approach .* is blocked at \(x=0\.30"):
        plan_approach(pre, pose, block)



def test_approach_turns_yaw_the_short_way():
    start, goal = np.array([-0.3, 0.3, 0.6, 3.0]), np.array([0.3, 0.3, 0.6, -3.0])
    path = plan_approach(start, goal, wall_checker())
    assert path[0].tobytes() == start.tobytes() and path[-1].tobytes() == goal.tobytes()
    assert_path_valid(path, wall_checker())
    assert_resolution(path, 0.01)
    # 3.0 -> -3.0 turns +0.28 rad through pi, not -6 rad
    cont = unwrap_yaw(path)
    assert cont[-1, 3] == pytest.approx(2 * math.pi - 3.0)
    assert np.all(np.diff(cont[:, 3]) >= 0)


# ----------------------------------------------------------------------------- checker + bounds


def test_box_checker_geometry():
    slot = [((0.0, 0.1, 0.0), (0.2, 0.05, 0.1)), ((0.0, -0.1, 0.0), (0.2, 0.05, 0.1))]
    chk = box_checker(slot, (0.02, 0.06, 0.03))  # long along its own y
    assert not chk(np.array([0.0, 0.0, 0.0, 0.0]))           # spans the 0.1 m gap: hits both
    assert chk(np.array([0.0, 0.0, 0.0, math.pi / 2]))       # turned, it fits the gap
    assert not chk(np.array([0.0, 0.0, 0.0, math.pi / 4]))   # diagonal: corner hits
    assert chk(np.array([0.0, 0.0, 0.2, 0.0]))               # above the slot
    assert not chk(np.array([0.0, 0.0, np.nan, 0.0]))
    sphere = box_checker(slot, gripper_radius=0.04)
    assert chk is not sphere and sphere(np.array([0.0, 0.0, 0.0, 0.0]))
    assert not sphere(np.array([0.0, 0.0, 0.0, 0.0]) + [0, 0.02, 0, 0])
    assert not box_checker(slot, gripper_radius=0.04, margin=0.02)(np.zeros(4))


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_turned_boxes_are_checked_as_they_lie():
    """A turned obstacle (centre, half extents, rotation): the identity is the axis-aligned
    box; a turn about z is the whole scene turned the other way (the exact yaw-only test);
    a cube turned by 45 degrees leaves free the corners of its bounds."""
    rng = np.random.default_rng(0)
    half = np.array([0.03, 0.02, 0.025])
    for _ in range(300):
        q = np.array([*rng.uniform(-0.12, 0.12, 3), rng.uniform(-math.pi, math.pi)])
        centre = rng.uniform(-0.03, 0.03, 3)
        assert box_checker([(centre, half, np.eye(3))], GRIPPER)(q) == box_checker([(centre, half)], GRIPPER)(q)
        a = rng.uniform(-math.pi, math.pi)
        turned = box_checker([(centre, half, _rot_z(a))], GRIPPER)(q)
        back = _rot_z(-a)
        scene = box_checker([(back @ centre, half)], GRIPPER)(np.array([*(back @ q[:3]), q[3] - a]))
        assert turned == scene
    cube = [((0.0, 0.0, 0.0), (0.03, 0.03, 0.03), _rot_z(math.pi / 4))]
    tip = np.array([0.035, 0.035, 0.0, 0.0])            # inside the bounds, beside a face
    assert box_checker(cube, gripper_radius=0.005)(tip)
    assert not box_checker([((0.0, 0.0, 0.0), (0.0425, 0.0425, 0.03))], gripper_radius=0.005)(tip)
    assert not box_checker(cube, gripper_radius=0.005)(np.array([0.03, 0.0, 0.0, 0.0]))


def _edges(centre: np.ndarray, rot: np.ndarray, half: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """The 12 edges of a box, as (end, end) pairs."""
    corner = {sg: centre + rot @ (np.array(sg) * half) for sg in itertools.product((-1, 1), repeat=3)}
    return [(corner[sg], corner[sg[:k] + (1,) + sg[k + 1:]]) for sg in corner for k in range(3) if sg[k] == -1]


def _segment_meets_box(p0: np.ndarray, p1: np.ndarray, centre, rot, half) -> bool:
    """Whether a segment meets a box: clipped to the box's three slabs, in its frame."""
    a, b = rot.T @ (p0 - centre), rot.T @ (p1 - centre)
    lo, hi = 0.0, 1.0
    for k in range(3):
        d = b[k] - a[k]
        if d == 0.0:
            if abs(a[k]) > half[k]:
                return False
            continue
        u, v = sorted(((-half[k] - a[k]) / d, (half[k] - a[k]) / d))
        lo, hi = max(lo, u), min(hi, v)
        if lo > hi:
            return False
    return True


def test_tipped_boxes_agree_with_an_edge_by_edge_test():
    """The separating-axis test against boxes tipped any way agrees with an independent
    exact test: two boxes meet iff an edge of one meets the other (every vertex of their
    intersection is a vertex of one inside the other or an edge of one through a face)."""
    rng = np.random.default_rng(1)
    gripper, hits = np.array(GRIPPER), 0
    for _ in range(1000):
        half, rot = rng.uniform(0.01, 0.04, 3), _random_rotation(rng)
        q = np.array([*rng.uniform(-0.1, 0.1, 3), rng.uniform(-math.pi, math.pi)])
        turn, origin = _rot_z(q[3]), np.zeros(3)
        meet = (any(_segment_meets_box(a, b, origin, rot, half) for a, b in _edges(q[:3], turn, gripper))
                or any(_segment_meets_box(a, b, q[:3], turn, gripper) for a, b in _edges(origin, rot, half)))
        assert box_checker([(origin, half, rot)], GRIPPER)(q) == (not meet), (q, half, rot)
        hits += meet
    assert 150 < hits < 850            # both outcomes are well represented


def test_bounds_validation():
    with pytest.raises(MotionPlanningError, match="bounds on z are empty"):
        Bounds(np.array([0, 0, 1, -3]), np.array([1, 1, 1, 3]))
    with pytest.raises(MotionPlanningError, match="shape"):
        Bounds(np.zeros(3), np.ones(3))
    b = Bounds([0, 0, 0, -math.pi], [1, 1, 1, math.pi])
    assert b.yaw_wraps and not b.low.flags.writeable
