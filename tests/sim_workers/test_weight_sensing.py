"""Issue 14, the physics half: the wrist force read during an action, density in L.

Real pybullet: a pickup in a grounded world, the wrist sensor log it produces and the
held-weight channel read off it; rows of L with a density; the sensor reading leaves the
physics untouched.
"""
from __future__ import annotations

import numpy as np
import pytest

from sim_workers.engines import ENGINES

from sim_workers.container.scene import GRIPPER_MASS
from sim_workers.grounded_world import GroundedWorld
from sim_workers.properties import PropertyError
from sim_workers.stack_and_push import StackAndPushDomain

G = 9.81
WEIGHT = -2          # the held-weight channel (the grasp width is last)


def _pickup(domain, size: float, density: float, engine: str | None = None):
    props = {"block_sizes": np.full(domain.spec.n_blocks, size), "density": density}
    with GroundedWorld(domain, engine=engine) as world:
        config = world.reset(domain.initial_configuration(props), props)
        action = "pickup(r,b1,init)"
        key = domain.action_pose(props, config, action)
        out = world.execute(domain.action_trajectory(config, action, key), action,
                            start_time=domain.transit_end_time(config, action, key))
        return out, config


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("size,density", [(0.040, 300.0), (0.040, 2400.0), (0.055, 3000.0)])
def test_held_weight_reads_the_blocks_weight_within_20_mN(size, density, engine):
    """In both engines (pybullet reads ~10 mN high, MuJoCo's drives read it exactly)."""
    domain = StackAndPushDomain(unknown_density=True)
    out, _ = _pickup(domain, size, density, engine)
    assert "is_holding(r,b1)" in out.state
    weight = out.measurements[WEIGHT]
    assert weight == pytest.approx(density * size ** 3 * G, abs=0.02)


def test_held_weight_is_nan_after_any_other_action_and_at_rest():
    domain = StackAndPushDomain(unknown_density=True)
    out, config = _pickup(domain, 0.045, 700.0)
    assert np.isnan(domain.measurements(config)[WEIGHT])      # no sensor log: not measured
    props = {"block_sizes": np.full(8, 0.045), "density": 700.0}
    with GroundedWorld(domain) as world:
        held = world.reset(out.configuration, props, place=False)
        action = "stack(r,b1,tower)"
        key = domain.action_pose(props, held, action)
        after = world.execute(domain.action_trajectory(held, action, key), action,
                              start_time=domain.transit_end_time(held, action, key))
    # Released (where it lands is the stack's business: about 1 rebuilt-world stack in 15
    # tips a light block in the hand at either grip depth).
    assert "hand_empty(r)" in after.state
    assert np.isnan(after.measurements[WEIGHT]) and np.isnan(after.measurements[-1])


def test_sensing_does_not_touch_the_physics():
    """Reading the constraint force every step is read-only: the outcome is bit-identical
    to the same action with the log switched off."""
    # (Mass in Y off: it changes the grip, which is physics; the log alone must not.)
    logged, _ = _pickup(StackAndPushDomain(unknown_density=True, force_from_mass=False), 0.045, 1500.0)
    quiet_domain = StackAndPushDomain()          # density known: no sensor log
    assert not quiet_domain.logs_sensors and StackAndPushDomain(unknown_density=True).logs_sensors
    quiet, _ = _pickup(quiet_domain, 0.045, 1500.0)
    assert np.array_equal(logged.configuration.to_array(), quiet.configuration.to_array())
    assert logged.steps == quiet.steps
    assert np.isnan(quiet.measurements[WEIGHT]) and not np.isnan(logged.measurements[WEIGHT])


def test_gripper_tare_is_the_empty_hands_weight():
    """The held weight subtracts the gripper's own weight: a pickup that grasps nothing
    (the block is far too big for the believed opening) reads about zero."""
    domain = StackAndPushDomain(unknown_density=True)
    props = {"block_sizes": np.full(8, 0.058), "density": 2000.0}
    believed = {"block_sizes": np.full(8, 0.032), "density": 2000.0}
    with GroundedWorld(domain) as world:
        config = world.reset(domain.initial_configuration(props), props)
        action = "pickup(r,b1,init)"
        key = domain.action_pose(believed, config, action)
        out = world.execute(domain.action_trajectory(config, action, key), action,
                            start_time=domain.transit_end_time(config, action, key))
    assert "is_holding(r,b1)" not in out.state
    assert abs(out.measurements[WEIGHT]) < 0.05
    assert GRIPPER_MASS == pytest.approx(0.6)


def test_L_with_density_rows_and_refusals():
    domain = StackAndPushDomain(unknown_density=True)
    L = domain.L
    assert L.names == ("size", "density") and L.units == ("m", "kg/m^3")
    assert (L.low[1], L.high[1]) == (300.0, 3000.0)
    shared = domain.properties(domain.props_from_row([0.04, 2400.0]))
    assert shared["density"] == 2400.0
    assert np.allclose(shared["block_masses"], 2400.0 * 0.04 ** 3)
    per_block = np.concatenate([np.full(8, 0.04), np.linspace(500, 2500, 8)])
    p = domain.properties(domain.props_from_row(per_block))
    assert np.allclose(p["block_masses"], np.linspace(500, 2500, 8) * 0.04 ** 3)
    with pytest.raises(PropertyError, match="L: a row of 3 values"):
        domain.props_from_row([0.04, 2400.0, 1.0])
    with pytest.raises(PropertyError, match=r"density: 0.0 is outside"):
        domain.properties(domain.props_from_row([0.04, 0.0]))
    with pytest.raises(PropertyError, match=r"density\[2\]"):
        domain.properties({"block_sizes": np.full(8, 0.04), "density": [100, 100, -1, 100, 100, 100, 100, 100]})
    # Known density (the default): L is the size alone, as before.
    assert StackAndPushDomain().L.names == ("size",)


def test_channels_and_what_is_weighed():
    known = StackAndPushDomain()
    assert known.force_sigma is None
    idx, sigma = known.measurement_model()
    assert list(idx) == [0] and list(sigma) == [0.002]        # as before issue 14
    unknown = StackAndPushDomain(unknown_density=True)
    idx, sigma = unknown.measurement_model()
    assert list(idx) == [0, 17, 18] and list(sigma) == [0.002, 0.1, 0.002]
    assert StackAndPushDomain(unknown_density=True, force_sigma=3.5).measurement_model()[1][1] == 3.5
    chans = unknown.measurement_channels()
    assert [c["name"] for c in chans][-2:] == ["held_weight", "grasp_width"] and chans[-2]["unit"] == "N"
    assert len(chans) == len(unknown.measurements(unknown.initial_configuration(unknown.true_properties())))
    with pytest.raises(ValueError, match="force_sigma"):
        StackAndPushDomain(force_sigma=0.0)
