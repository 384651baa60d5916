"""The particle worlds meet what the robot perceived off by the perception error, as the
real gripper does (issue 37): each world replays the trajectory Y would have given for
its own draw of the objects' planar positions, N(perceived, sigma^2), so a grasp whose
clearance is smaller than the perception error is predicted to fail at the true L about
as often as it fails in reality, and a real failure of that kind is not charged to L.
Real pybullet (the container's physics)."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.perception import perceived_trajectories, pose_offsets, world_starts
from coordinator.run_config import RunConfig
from coordinator.session import Session
from sim_workers.configuration import Configuration
from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld
from sim_workers.shard import Shard


def _start(n_objects: int = 4) -> np.ndarray:
    rng = np.random.default_rng(0)
    return Configuration(rng.normal(size=5), rng.normal(size=(n_objects, 7))).to_array()


def test_no_perception_noise_is_the_perceived_start_and_draws_nothing():
    rng = np.random.default_rng(1)
    state = rng.bit_generator.state
    start = _start()
    assert np.array_equal(world_starts(start, 16, (1, 2), 0.0, rng), start)
    assert np.array_equal(world_starts(start, 16, (), 0.002, rng), start)
    assert rng.bit_generator.state == state


def test_each_world_draws_the_listed_objects_planar_positions_at_the_sigma():
    start, sigma, n = _start(), 0.002, 4000
    out = world_starts(start, n, (1, 3), sigma, np.random.default_rng(2))
    assert out.shape == (n, start.size)
    base = Configuration.from_array(start)
    configs = [Configuration.from_array(row) for row in out]
    assert all(np.array_equal(c.robot, base.robot) for c in configs)                 # proprioception is exact
    d = np.array([c.objects - base.objects for c in configs])                         # (n, M, 7)
    assert np.all(d[:, [0, 2]] == 0) and np.all(d[:, :, 2:] == 0)                      # others, heights, poses kept
    moved = d[:, [1, 3], :2].reshape(-1)
    assert abs(moved.std() / sigma - 1) < 0.03 and abs(moved.mean()) < 4 * sigma / np.sqrt(moved.size)
    again = world_starts(start, n, (1, 3), sigma, np.random.default_rng(2))
    assert np.array_equal(out, again)                                                  # the seed alone


def _planned(domain, truth: float, action: str, believed: float | None = None):
    """The episode's start in a world of blocks of side `truth`, and `action`'s trajectory
    and transit end from Y under `believed` (default: the truth)."""
    props = domain.props_from_row([truth])
    with GroundedWorld(domain) as world:
        start = world.reset(domain.initial_configuration(props), props)
    key = domain.action_pose(domain.props_from_row([believed or truth]), start, action)
    return start, domain.action_trajectory(start, action, key), domain.transit_end_time(start, action, key)


def test_a_shard_runs_each_world_from_its_own_start_and_refuses_a_count_mismatch():
    domain, action = load("container", n_blocks=2), "pickup(r,b1,init)"
    start, traj, t_pre = _planned(domain, 0.045, action)
    rows = np.array([[0.045], [0.040]])
    starts = world_starts(start.to_array(), 2, domain.jittered_objects, 0.01, np.random.default_rng(3))
    shard = Shard("container", {"n_blocks": 2})
    try:
        both = shard.simulate(starts, rows, action, traj, t_pre)
        one = [shard.simulate(starts[i], rows[i:i + 1], action, traj, t_pre) for i in range(2)]
        for i in range(2):
            assert np.array_equal(both["configurations"][i], one[i]["configurations"][0])
            assert np.array_equal(both["measurements"][i], one[i]["measurements"][0])
        with pytest.raises(ValueError, match="start: 2 configurations for 1 particles"):
            shard.simulate(starts, rows[:1], action, traj, t_pre)
    finally:
        shard.close()


def test_only_the_objects_the_pose_depends_on_move_the_trajectory():
    """A pickup's pose follows its block: every world's trajectory is the real one shifted
    in the plane by about sigma; a stack into the tray (a fixture, perceived exactly) and a
    push of it move nothing, so towers and loads stay as the robot saw them."""
    domain = load("container", n_blocks=4)
    props = domain.props_from_row([0.045])
    with GroundedWorld(domain) as world:
        start = world.reset(domain.initial_configuration(props), props)
    rng, sigma = np.random.default_rng(4), 0.002
    pick = pose_offsets(domain, props, start, "pickup(r,b2,init)", 2000, domain.jittered_objects, sigma, rng)
    assert abs(pick.std() / sigma - 1) < 0.05 and np.abs(pick.mean(axis=0)).max() < 0.0002
    for action in ("stack(r,b2,c)", "push(r,c,init,goal)"):
        moved = pose_offsets(domain, props, start, action, 50, domain.jittered_objects, sigma, rng)
        assert np.abs(moved).max() < 1e-12, action
    key = domain.action_pose(props, start, "pickup(r,b2,init)")
    traj = domain.action_trajectory(start, "pickup(r,b2,init)", key)
    out = perceived_trajectories(domain, props, start.to_array(), "pickup(r,b2,init)", traj, 8, sigma,
                                 np.random.default_rng(5))
    assert out.shape == (8, *traj.shape)
    shift = out - traj
    assert np.all(shift[:, :, [0, 3, 4, 5]] == 0)                       # time, height, yaw, opening
    assert np.allclose(shift[:, :, 1:3], shift[:, :1, 1:3])             # one planar shift per world
    assert perceived_trajectories(domain, props, start.to_array(), "pickup(r,b2,init)", traj, 8, 0.0,
                                  np.random.default_rng(5)) is traj


def _grasp_success(sigma: float, seed: int) -> np.ndarray:
    """Rows of L near a 57.9 mm truth, a pickup planned for a believed 50.4 mm (its opening,
    1.15 x 50.4 = 58.0 mm, clears a 57.9 mm block by 0.1 mm): which rows' worlds hold b1,
    each started by the session's own draw at perception `sigma`."""
    s = Session(RunConfig(particles=12, seed=seed, perception_sigma=sigma, particle_budget="fixed"))
    action = "pickup(r,b1,init)"
    start, traj, t_pre = _planned(s.domain, 0.0579, action, believed=0.0504)
    s.shard_pool = Shard("container", {"n_blocks": 8})
    try:
        rows = np.linspace(0.0565, 0.0595, 12)[:, None]
        res = s._simulate_rows(start.to_array(), rows, action, traj, t_pre)
    finally:
        s.shard_pool.close()
    return np.array(["is_holding(r,b1)" in st for st in res["states"]])


def test_perception_makes_a_zero_clearance_grasp_uncertain_at_the_true_size():
    """From the perceived start itself the worlds near the truth hold the block (the plan
    aimed exactly at it: 11 of 12 measured, one at 59 mm slips); from draws at the declared
    2 mm, about half miss it (measured 9 of 24), as the real gripper does when its target
    is off by the perception error."""
    assert _grasp_success(0.0, 0).mean() >= 11 / 12
    held = np.concatenate([_grasp_success(0.002, seed) for seed in (0, 1)])
    assert held.mean() < 0.7, held
