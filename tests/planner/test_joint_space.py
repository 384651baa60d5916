"""Issue 41: an arm's joint-space motion: OMPL RRT* over the joint box, and toppra's timing
within the joint limits, never faster than the domain's own timing."""
from __future__ import annotations

import numpy as np
import pytest

from planner.motion import MotionPlanningError
from planner.motion.joint_space import densify_joints, plan_joint_rrtstar, time_joint_path

LOW, HIGH = np.full(2, -np.pi), np.full(2, np.pi)


def _wall(q: np.ndarray) -> bool:
    """A joint-space wall at q0 in [-0.2, 0.2] for q1 < 1.5: the straight path crosses it."""
    return not (abs(q[0]) < 0.2 and q[1] < 1.5)


def test_rrtstar_goes_round_a_wall_in_joint_space_deterministically():
    start, goal = np.array([-1.0, 0.0]), np.array([1.0, 0.0])
    a = plan_joint_rrtstar(start, goal, _wall, LOW, HIGH, seed=3, iterations=200)
    b = plan_joint_rrtstar(start, goal, _wall, LOW, HIGH, seed=3, iterations=200)
    assert np.array_equal(a, b)
    assert np.array_equal(a[0], start) and np.array_equal(a[-1], goal)
    dense = densify_joints(a, 0.005)
    assert all(_wall(q) for q in dense)                       # every state along it is free
    assert np.all(dense >= LOW) and np.all(dense <= HIGH)
    assert dense[:, 1].max() >= 1.5                            # it went round the wall's end


def test_a_free_straight_segment_is_returned_without_search_and_a_blocked_goal_is_named():
    path = plan_joint_rrtstar(np.zeros(2), np.array([0.5, 0.5]), lambda q: True, LOW, HIGH, seed=0,
                              resolution=0.1)
    assert np.allclose(path[:, 0], path[:, 1]) and np.abs(np.diff(path, axis=0)).max() <= 0.1 + 1e-12
    with pytest.raises(MotionPlanningError, match="goal .* in collision"):
        plan_joint_rrtstar(np.array([-1.0, 0.0]), np.zeros(2), _wall, LOW, HIGH, seed=0)
    with pytest.raises(MotionPlanningError, match="outside the joint limits"):
        plan_joint_rrtstar(np.array([-1.0, 0.0]), np.array([4.0, 0.0]), _wall, LOW, HIGH, seed=0)


def _check_limits(path, vmax, amax, slack=1.02):
    assert np.all(np.diff(path.t) >= 0)
    assert np.all(np.abs(path.qd) <= vmax * slack + 1e-9)
    assert np.all(np.abs(path.qdd) <= amax * slack + 1e-9)
    assert np.allclose(path.qd[0], 0) and np.allclose(path.qd[-1], 0)       # rest to rest


def test_timing_keeps_the_joint_limits_and_never_outruns_the_nominal_timing():
    w = densify_joints(np.array([[0.0, 0.0, 0.0], [1.0, 0.4, -0.2], [1.0, 0.4, -0.2], [1.0, 1.4, 0.3]]), 0.05)
    vmax, amax = np.full(3, 1.0), np.full(3, 1.4)
    fast = time_joint_path(w, vmax, amax)
    _check_limits(fast, vmax, amax)
    assert np.array_equal(fast.q, w)
    # the nominal timing of a slow tool: 0.5 s a waypoint gap; the arm never goes faster
    nominal = np.full(len(w) - 1, 0.5)
    slow = time_joint_path(w, vmax, amax, nominal_dt=nominal)
    _check_limits(slow, vmax, amax)
    assert np.all(np.diff(slow.t) >= nominal * 0.98)
    assert slow.t[-1] > fast.t[-1]
    # where the arm stands still the gap keeps its nominal time (the fingers close)
    still = np.flatnonzero(np.abs(np.diff(w, axis=0)).max(axis=1) == 0)
    assert still.size == 1 and np.isclose(np.diff(slow.t)[still[0]], 0.5)
    # a time-optimal profile: some joint at its velocity or acceleration limit somewhere
    assert np.abs(fast.qd).max() > 0.9 * vmax[0] or np.abs(fast.qdd).max() > 0.9 * amax[0]
    goal = fast.goal(["a", "b", "c"])
    assert goal["joint_names"] == ["a", "b", "c"] and len(goal["points"]) == len(w)
    assert set(goal["points"][1]) == {"positions", "velocities", "accelerations", "time_from_start"}


def test_timing_refuses_bad_limits():
    with pytest.raises(MotionPlanningError, match="positive"):
        time_joint_path(np.zeros((2, 2)), np.array([1.0, 0.0]), np.ones(2))
