"""Bad properties L are refused loudly, with an error that names the field."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld
from sim_workers.properties import (
    MAX_SIZE_M,
    MIN_SIZE_M,
    PropertyError,
    validate_positive,
    validate_sizes,
)
from sim_workers.shard import Shard

N = 8
GOOD = [0.045] * N


def _with(i: int, value) -> list:
    sizes = list(GOOD)
    sizes[i] = value
    return sizes


BAD_SIZES = [
    pytest.param(_with(3, -0.04), r"block_sizes\[3\]", id="negative"),
    pytest.param(_with(0, 0.0), r"block_sizes\[0\]", id="zero"),
    pytest.param(_with(5, math.nan), r"block_sizes\[5\]: not a finite number", id="nan"),
    pytest.param(_with(7, math.inf), r"block_sizes\[7\]: not a finite number", id="inf"),
    pytest.param(_with(2, -math.inf), r"block_sizes\[2\]", id="minus_inf"),
    pytest.param(_with(6, 5.0), r"block_sizes\[6\]: 5.0 m is outside", id="absurd_5m"),
    pytest.param(_with(1, 0.005), r"block_sizes\[1\]", id="too_small"),
    pytest.param(_with(4, 0.2), r"block_sizes\[4\]", id="too_large"),
    pytest.param(GOOD[:7], r"block_sizes: expected 8 sizes", id="too_few"),
    pytest.param(GOOD + [0.045], r"block_sizes: expected 8 sizes", id="too_many"),
    pytest.param([GOOD, GOOD], r"block_sizes: expected 8 sizes", id="two_dimensional"),
    pytest.param([], r"block_sizes: expected 8 sizes", id="empty"),
    pytest.param(_with(2, "big"), r"block_sizes: not a list of numbers", id="non_numeric"),
    pytest.param("0.045 m", r"block_sizes: not a list of numbers", id="string"),
    pytest.param(None, r"block_sizes", id="none"),
    pytest.param({"b1": 0.045}, r"block_sizes", id="mapping"),
]


@pytest.mark.parametrize("sizes, named", BAD_SIZES)
def test_bad_block_sizes_name_the_field(sizes, named):
    domain = load("container")
    with pytest.raises(PropertyError, match=named):
        domain.properties({"block_sizes": sizes})


def test_property_error_is_a_value_error():
    assert issubclass(PropertyError, ValueError)


def test_first_bad_entry_is_named():
    sizes = _with(2, math.nan)
    sizes[6] = -1.0
    with pytest.raises(PropertyError, match=r"block_sizes\[2\]"):
        validate_sizes(sizes, N)
    with pytest.raises(PropertyError, match=r"particle_sizes\[6\]"):
        validate_sizes(_with(6, 1.0), N, field="particle_sizes")


def test_missing_key_and_not_a_mapping():
    domain = load("container")
    with pytest.raises(PropertyError, match="block_sizes: missing"):
        domain.properties({"sizes": GOOD})
    with pytest.raises(PropertyError, match="properties"):
        domain.properties(GOOD)


@pytest.mark.parametrize("density", [-700.0, 0.0, math.nan, math.inf, 1e9, "wood", None])
def test_bad_density_names_the_field(density):
    with pytest.raises(PropertyError, match="density"):
        load("container").properties({"block_sizes": GOOD, "density": density})


def test_good_properties_pass_and_give_masses():
    domain = load("container")
    p = domain.properties({"block_sizes": np.linspace(0.03, 0.06, N), "density": 500.0})
    assert p["block_sizes"].dtype == np.float64 and p["block_sizes"].shape == (N,)
    np.testing.assert_allclose(p["block_masses"], 500.0 * np.linspace(0.03, 0.06, N) ** 3)
    # The edges of the range are allowed; a scalar means every block.
    validate_sizes([MIN_SIZE_M] * 4 + [MAX_SIZE_M] * 4, N)
    np.testing.assert_array_equal(validate_sizes(0.045, N), np.full(N, 0.045))
    assert validate_positive("2.5", "density") == 2.5


def test_the_world_refuses_bad_properties_at_reset_and_stays_usable():
    domain = load("container")
    truth = domain.true_properties()
    config = domain.initial_configuration(truth)
    with GroundedWorld(domain) as world:
        world.reset(config, truth)
        before = world.observe()
        for bad, named in [(_with(3, -0.045), r"block_sizes\[3\]"), (_with(0, math.nan), r"block_sizes\[0\]"),
                           (_with(5, 5.0), r"block_sizes\[5\]"), (GOOD[:3], "block_sizes")]:
            with pytest.raises(PropertyError, match=named):
                world.reset(config, {"block_sizes": bad})
            # Refused before anything was touched: the scene is still the last good one.
            assert world.observe() == before
            assert world.props is not None and np.array_equal(world.props["block_sizes"], truth["block_sizes"])
        with pytest.raises(PropertyError, match="block_sizes: missing"):
            world.reset(config, {})
        world.reset(config, {"block_sizes": _with(3, 0.05)})       # and it still works
        assert world.observe().objects[4, 2] == pytest.approx(0.025)


def test_a_shard_refuses_a_bad_particle_by_field():
    domain = load("container")
    truth = domain.true_properties()
    config = domain.initial_configuration(truth)
    action = "pickup(r,b1,init)"
    key = domain.action_pose(truth, config, action)
    traj = domain.action_trajectory(config, action, key)
    sizes = np.full((3, N), 0.045)
    sizes[1, 4] = np.nan
    shard = Shard("container")
    try:
        with pytest.raises(PropertyError, match=r"block_sizes\[4\]"):
            shard.simulate(config.to_array(), sizes, action, traj, float(traj[3, 0]))
    finally:
        shard.close()


def test_y_refuses_bad_believed_sizes():
    domain = load("container")
    config = domain.initial_configuration(domain.true_properties())
    with pytest.raises(PropertyError, match=r"block_sizes\[0\]"):
        domain.action_pose({"block_sizes": _with(0, -0.03)}, config, "pickup(r,b1,init)")


@pytest.mark.parametrize("density", [7800.0, 300.0])
def test_a_density_other_than_the_default_reaches_the_bodies(density):
    """Issue 11: `reset` validated the properties and `build` validated them again, and the
    second pass dropped `density` (7800 kg/m^3 built 700 kg/m^3 blocks)."""
    import pybullet as pb

    domain = load("container")
    assert density != domain.spec.density
    sizes = np.linspace(0.03, 0.06, N)
    props = {"block_sizes": sizes, "density": density}
    config = domain.initial_configuration(props)
    with GroundedWorld(domain) as world:
        world.reset(config, props)
        masses = [pb.getDynamicsInfo(b, -1, physicsClientId=world.client)[0]
                  for b in world.handles.blocks]
        assert world.props["density"] == density
    np.testing.assert_allclose(masses, density * sizes ** 3, rtol=1e-12)
    # Validation is idempotent: a validated dict validates to itself, density included.
    once = domain.properties(props)
    twice = domain.properties(once)
    assert twice["density"] == density
    np.testing.assert_array_equal(twice["block_masses"], once["block_masses"])


@pytest.mark.parametrize("props,named", [
    ({"block_sizes": GOOD, "weight": 1.0}, "weight"),
    ({"block_sizes": GOOD, "densty": 7800.0}, "densty"),
    ({"block_sizes": GOOD, "density": 7800.0, "block_masses": np.full(N, 0.0638)}, "block_masses"),
])
def test_a_property_that_would_not_reach_the_physics_is_refused_by_name(props, named):
    with pytest.raises(PropertyError, match=named):
        load("container").properties(props)


@pytest.mark.parametrize("name", ["container", "stack_and_push"])
def test_properties_are_validated_once_per_particle_action(name, monkeypatch):
    """The hot path checks a particle's properties once (issue 26): place, build and Y are
    handed the validated mapping, which passes through the check as it is."""
    import sim_workers.properties as properties

    shard = Shard(name)
    d = shard.domain
    truth = d.true_properties()
    config = d.initial_configuration(truth)
    action = "pickup(r,b1,init)"
    key = d.action_pose(truth, config, action)
    traj, t0 = d.action_trajectory(config, action, key), d.transit_end_time(config, action, key)
    checks = []
    real = properties.validate_sizes
    monkeypatch.setattr(properties, "validate_sizes", lambda *a, **k: checks.append(1) or real(*a, **k))
    rows = np.full((3, 1), 0.045)
    shard.simulate(config.to_array(), rows, action, traj, t0)
    assert len(checks) == len(rows)


def test_one_number_per_object_is_checked_and_refusals_name_the_field():
    from sim_workers.properties import PropertyError, per_object_property

    assert per_object_property({"friction": 0.3}, "friction", 3, 0.02, 2.0).tolist() == [0.3] * 3
    assert per_object_property({"friction": [0.1, 0.2]}, "friction", 2, 0.02, 2.0).tolist() == [0.1, 0.2]
    for props, named in (({}, "friction: missing"), ({"friction": 0.3, "mass": 1}, "mass: unknown"),
                         ({"friction": [0.1, 0.2, 0.3]}, "friction: expected one number or 2"),
                         ({"friction": [0.1, float("nan")]}, r"friction\[1\]"),
                         ({"friction": [0.1, 3.0]}, r"friction\[1\]: 3.0 is outside")):
        with pytest.raises(PropertyError, match=named):
            per_object_property(props, "friction", 2, 0.02, 2.0)
