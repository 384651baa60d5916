"""Leaving unreachable bodies out of a particle world (sim_workers/reach.py) keeps outcomes.

Particle worlds (``Shard``) leave out of the action kinds a domain names
(``leave_out_actions``) the bodies the action cannot reach; a guard sends the
particle-action back to the full world when a kept body comes near a left-out one.
stack_and_push leaves bodies out of pickups and stacks: its outcomes are the full world's
(the same symbolic states, the channels the belief weighs within 1e-8, a millionth of
their sigma; left-out blocks report their placed pose, ~1e-5 m from where the full world
lets them settle). The container opts out (its solver's early stop couples the rows: see
``ContainerDomain.leave_out_actions``); the mechanism is still tested on it, opted in per
instance: bodies really are left out, reduced worlds are bit-identical between fresh
worlds, and a guard that trips gives exactly the full world's bits.
"""
from __future__ import annotations

import numpy as np
import pytest

from sim_workers import reach
from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld
from sim_workers.shard import Shard

ACTION = "pickup(r,b3,init)"


def _case(name: str):
    domain = load(name)
    domain.leave_out_actions = ("pickup",)     # the container opts out; opt this instance in
    truth = domain.true_properties()
    config = domain.initial_configuration(truth)
    key = domain.action_pose(truth, config, ACTION)
    traj = domain.action_trajectory(config, ACTION, key)
    return domain, config, traj, domain.transit_end_time(config, ACTION, key)


def _rows(domain, n: int = 10) -> np.ndarray:
    # Sizes across the prior: right, too small and too large beliefs (failed grasps too).
    s = np.linspace(domain.spec.prior_low, domain.spec.prior_high, n)
    return np.repeat(s[:, None], domain.spec.n_blocks, axis=1)


def _likelihood_channels(domain, measurements: np.ndarray) -> np.ndarray:
    idx, _ = domain.measurement_model()
    return measurements[:, np.asarray(idx)]


def test_leaving_out_of_a_pickup_keeps_every_outcome():
    name = "stack_and_push"
    domain = load(name)
    assert "pickup" in domain.leave_out_actions
    _, config, traj, t0 = _case(name)
    rows = _rows(domain)
    full = Shard(name, leave_out=False).simulate(config.to_array(), rows, ACTION, traj, t0)
    shard = Shard(name, leave_out=True)
    reduced = shard.simulate(config.to_array(), rows, ACTION, traj, t0)
    assert list(reduced["states"]) == list(full["states"])
    assert len(set(full["states"])) > 1              # the batch holds grasps and misses
    np.testing.assert_array_equal(reduced["steps"], full["steps"])
    # The weighed channels within 1e-8 (their sigma is 2 mm: a millionth of it).
    np.testing.assert_allclose(_likelihood_channels(domain, reduced["measurements"]),
                               _likelihood_channels(domain, full["measurements"]), rtol=0, atol=1e-8)
    d = np.abs(reduced["measurements"] - full["measurements"])
    assert np.nanmax(d) < 1e-4
    # Positions (not quaternions: q and -q are one orientation) within 0.1 mm.
    pos = lambda c: c[:, 5:].reshape(len(c), -1, 7)[..., :3]     # noqa: E731
    assert np.max(np.abs(pos(reduced["configurations"]) - pos(full["configurations"]))) < 1e-4
    assert shard.worlds[0].reruns == 0


def test_the_container_leaves_nothing_out():
    assert load("container").leave_out_actions == ()


@pytest.mark.parametrize("name", ["container", "stack_and_push"])
def test_a_pickup_leaves_most_of_the_scene_out_and_is_deterministic(name):
    domain, config, traj, t0 = _case(name)
    bits = []
    for _ in range(2):
        with GroundedWorld(domain, leave_out=True) as world:
            world.reset(config, domain.true_properties())
            out = world.execute(traj, ACTION, start_time=t0)
            left_out = sorted(world._absent)
            bits.append(out.configuration.to_array().tobytes() + out.measurements.tobytes())
            # The picked block is kept; more than half of the objects are left out.
            assert 3 - (name == "stack_and_push") not in left_out
            assert len(left_out) > len(domain.object_names) / 2, left_out
            with pytest.raises(RuntimeError, match="reset"):
                world.execute(traj, ACTION, start_time=t0)
    assert bits[0] == bits[1]


@pytest.mark.parametrize("name", ["container", "stack_and_push"])
def test_the_guard_sends_a_near_miss_back_to_the_full_world(name, monkeypatch):
    """With a negative sweep margin the picked block itself is left out: the descending
    gripper comes near it, the guard trips, and the re-run in the full world gives exactly
    the full world's bits (the reduced world would have missed the block)."""
    domain, config, traj, t0 = _case(name)
    props = domain.true_properties()
    with GroundedWorld(domain) as world:
        world.reset(config, props)
        full = world.execute(traj, ACTION, start_time=t0)
    monkeypatch.setattr(reach, "SWEEP_MARGIN", -0.2)
    with GroundedWorld(domain, leave_out=True) as world:
        world.reset(config, props)
        out = world.execute(traj, ACTION, start_time=t0)
        assert world.reruns == 1
    assert "is_holding(r,b3)" in full.state and out.state == full.state
    assert out.configuration.to_array().tobytes() == full.configuration.to_array().tobytes()
    assert out.measurements.tobytes() == full.measurements.tobytes()
    assert out.steps > full.steps                    # the tripped attempt's steps count too


def test_the_reach_keeps_what_the_gripper_sweeps_and_what_touches_it():
    # Boxes: 0 under the path, 1 touching 0, 2 far away, 3 within the margin past the
    # path's end (the swept box ends at x = 0.2 + 0.05), 4 just beyond the margin.
    boxes = np.array([[-0.02, -0.02, 0.0, 0.02, 0.02, 0.04],
                      [0.021, -0.02, 0.0, 0.06, 0.02, 0.04],
                      [0.5, 0.5, 0.0, 0.54, 0.54, 0.04],
                      [0.27, -0.02, 0.0, 0.31, 0.02, 0.04],
                      [0.25 + reach.SWEEP_MARGIN + 0.001, 0.3, 0.0, 0.4, 0.34, 0.04]])
    gripper = np.array([-0.01, -0.05, 0.10, 0.01, 0.05, 0.16])
    path = np.array([[0.0, 0.0, 0.10], [0.0, 0.0, 0.05], [0.2, 0.0, 0.2]])
    keep = reach.kept_objects(boxes, gripper, np.array([0.0, 0.0, 0.10]), path)
    assert keep.tolist() == [True, True, False, True, False]


def test_a_stack_onto_a_tower_keeps_every_outcome():
    """stack_and_push also leaves bodies out of a stack: a real grasp of b3 (a pickup in a
    full world) stacked onto a tower of two, across the prior."""
    from sim_workers.stack_and_push.probes import tower_configuration

    name = "stack_and_push"
    domain = load(name)
    assert "stack" in domain.leave_out_actions
    truth = domain.true_properties()
    two = tower_configuration(domain, truth["block_sizes"], 2, np.random.default_rng(0))
    key = domain.action_pose(truth, two, ACTION)
    with GroundedWorld(domain) as world:
        world.reset(two, truth)
        held = world.execute(domain.action_trajectory(two, ACTION, key), ACTION,
                             start_time=domain.transit_end_time(two, ACTION, key))
    assert "is_holding(r,b3)" in held.state
    stack = "stack(r,b3,tower)"
    config = held.configuration
    key = domain.action_pose(truth, config, stack)
    traj, t0 = domain.action_trajectory(config, stack, key), domain.transit_end_time(config, stack, key)
    rows = _rows(domain, 8)
    full = Shard(name, leave_out=False).simulate(config.to_array(), rows, stack, traj, t0)
    shard = Shard(name, leave_out=True)
    reduced = shard.simulate(config.to_array(), rows, stack, traj, t0)
    assert list(reduced["states"]) == list(full["states"])
    np.testing.assert_allclose(_likelihood_channels(domain, reduced["measurements"]),
                               _likelihood_channels(domain, full["measurements"]), rtol=0, atol=1e-8)
    # Readings the likelihood does not weigh agree to half a millimetre (0.28 mm with the
    # grasp clearance's wider opening, under 0.1 mm before it); the weighed ones above to 1e-8.
    assert np.nanmax(np.abs(reduced["measurements"] - full["measurements"])) < 5e-4
    with GroundedWorld(domain, leave_out=True) as world:
        world.reset(config, truth)
        world.execute(traj, stack, start_time=t0)
        assert len(world._absent) >= 3              # the blocks on the table far away
