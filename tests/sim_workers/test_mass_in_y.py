"""Issue 14, item 3: mass in Y. With the density unknown, Y sizes the grip force and the
push's force limit from the believed mass, so a wrong belief costs something: too light a
grip drops the block on the lift, too light a push limit stalls the tower, too heavy a one
throws a tall tower over. Real pybullet throughout (the probes of `tmoc probe`).
"""
from __future__ import annotations

import numpy as np
import pytest

from sim_workers import trajectory as tr
from sim_workers.grounded_world import GroundedWorld
from sim_workers.probe import probe
from sim_workers.stack_and_push import StackAndPushDomain, efforts
from sim_workers.stack_and_push.probes import tower_configuration

HEAVY = {"density": 2400.0}
TRIALS = 6


def _rate(action: str, load: int, believed: float, truth: dict = HEAVY) -> float:
    return probe(action, 0.045, load_k=load, trials=TRIALS, seed=0, n_blocks=8, domain="stack_and_push",
                 options=truth, believed_density=believed).success_rate


@pytest.mark.slow
def test_the_grip_comes_from_the_believed_mass():
    """Too light a belief (42 % of the true mass) and the block slips out on every lift;
    the truth, or heavier, holds it every time. (Probe, 16 trials: 1000 -> 0/16, 1300 ->
    15/16, 2400 -> 16/16.)"""
    assert _rate("pickup", 1, 1000.0) == 0.0
    assert _rate("pickup", 1, 2400.0) == 1.0
    assert _rate("pickup", 1, 3000.0) == 1.0


@pytest.mark.slow
def test_the_push_limit_comes_from_the_believed_tower_mass():
    """A tower of 4 heavy blocks: a limit from half its mass does not beat its friction
    (it stalls at the start); from its true mass it reaches the goal every time."""
    assert _rate("push", 4, 1200.0) == 0.0
    assert _rate("push", 4, 2400.0) == 1.0


@pytest.mark.slow
def test_too_heavy_a_belief_throws_a_tall_tower_over():
    """A tower of 6 light (700 kg/m^3) blocks pushed with a limit for 3000 kg/m^3: nothing
    holds the stroke back and the tower is thrown at the reference's 8 m/s^2. (16 trials:
    13/16 at the truth, 5/16 at 3000.) The nominal stroke: with the arm's timing jitter
    (push_time_jitter 0.3, issue 24) a slower reference throws less, and the gap shrinks
    to 7 against 6 of 12."""
    light = {"density": 700.0, "push_time_jitter": 0.0}
    right = probe("push", 0.045, load_k=6, trials=12, seed=0, domain="stack_and_push", options=light,
                  believed_density=700.0).successes
    heavy = probe("push", 0.045, load_k=6, trials=12, seed=0, domain="stack_and_push", options=light,
                  believed_density=3000.0).successes
    assert right >= heavy + 4, (right, heavy)


def test_a_stalled_push_leaves_the_tower_and_does_not_snap_the_gripper_through_it():
    """The force-limited stroke is a guarded move: when it ends, the rest of the trajectory
    continues from where the gripper got to. (Before, the full wrist force snapped the
    gripper to its reference and launched the bottom block 6 m.)"""
    d = StackAndPushDomain(unknown_density=True)
    sizes = np.full(8, 0.045)
    truth = {"block_sizes": sizes, "density": 2400.0}
    action = "push(r,tower,start,goal)"
    with GroundedWorld(d) as w:
        config = w.reset(tower_configuration(d, sizes, 4, np.random.default_rng(0)), truth)
        key = d.action_pose({"block_sizes": sizes, "density": 1000.0}, config, action)
        traj = d.action_trajectory(config, action, key)
        out = w.execute(traj, action, start_time=d.transit_end_time(config, action, key))
    moved = out.configuration.objects[:4, 0] - config.objects[:4, 0]
    assert np.all(np.abs(moved) < 0.05), moved                  # stalled near the start
    assert np.all(out.configuration.objects[:4, 2] > 0.0)       # nothing fell off the table
    assert "is_in(b1,goal)" not in out.state


def test_y_carries_the_effort_and_the_trajectory_its_columns():
    d = StackAndPushDomain(unknown_density=True)
    props = d.props_from_row([0.045, 2400.0])
    config = d.initial_configuration(props)
    key = d.action_pose(props, config, "pickup(r,b1,init)")
    mass = 2400.0 * 0.045 ** 3
    assert key.shape == (6,) and key[5] == pytest.approx(efforts.grip_force(d.spec, mass))
    traj = d.action_trajectory(config, "pickup(r,b1,init)", key)
    assert traj.shape[1] == 8 and tr.columns_of(traj)[-2:] == ("grip_force", "force_limit")
    assert np.all(traj[:, 6] == key[5]) and np.all(traj[:, 7] == d.spec.base_max_force)
    # The pre-pose is a pose: the effort is not part of it.
    assert d.pre_pose(config, "pickup(r,b1,init)", key).shape == (5,)
    # Without mass in Y nothing changes: five entries, six columns.
    plain = StackAndPushDomain()
    assert plain.action_pose(props, config, "pickup(r,b1,init)").shape == (5,)
    # Efforts are commands: held from a row on, not interpolated.
    t = np.array([[0.0, 0, 0, 0, 0, 0, 1.0, 40.0], [1.0, 1, 0, 0, 0, 0, 3.0, 5.0]])
    assert list(tr.sample(t, np.array([0.5]))[0]) == [0.5, 0, 0, 0, 0, 1.0, 40.0]


def test_the_grasp_width_tells_a_slip_from_a_miss():
    """A heavy block that slipped on the lift and a small block the fingers missed both end
    with an empty hand and no held weight; the opening at the end of the grip differs (the
    block's width, against nothing). Without it the filter learned "small" from slips."""
    d = StackAndPushDomain(unknown_density=True)
    believed = d.props_from_row([0.045, 1000.0])
    action = "pickup(r,b1,init)"
    readings = {}
    for label, row in (("slip", [0.045, 2400.0]), ("miss", [0.030, 700.0])):
        truth = d.props_from_row(row)
        with GroundedWorld(d) as w:
            start = w.reset(d.initial_configuration(truth), truth)
            key = d.action_pose(believed, start, action)
            out = w.execute(d.action_trajectory(start, action, key), action,
                            start_time=d.transit_end_time(start, action, key))
        assert "is_holding(r,b1)" not in out.state
        readings[label] = out.measurements[-1]
    assert readings["slip"] == pytest.approx(0.045, abs=0.002)
    assert readings["miss"] < 0.005
    names = [c["name"] for c in d.measurement_channels()]
    assert names[-2:] == ["held_weight", "grasp_width"]


def test_mass_in_y_is_deterministic_bit_for_bit():
    d = StackAndPushDomain(unknown_density=True)
    sizes = np.full(8, 0.045)
    truth = {"block_sizes": sizes, "density": 2400.0}
    action = "push(r,tower,start,goal)"
    outs = []
    for _ in range(2):
        with GroundedWorld(d) as w:
            config = w.reset(tower_configuration(d, sizes, 4, np.random.default_rng(3)), truth)
            key = d.action_pose({"block_sizes": sizes, "density": 1800.0}, config, action)
            out = w.execute(d.action_trajectory(config, action, key), action,
                            start_time=d.transit_end_time(config, action, key))
            outs.append(np.concatenate([out.configuration.to_array(), out.measurements]))
    assert np.array_equal(outs[0], outs[1], equal_nan=True)
