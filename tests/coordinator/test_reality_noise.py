"""A simulated reality that reads like a robot (issue 37 item 1): each weighed measurement
channel is noisy at its declared sigma (bias and heavy tails as options), the movable
objects' perceived positions are noisy, the world goes on from the truth, every draw is the
run's seed's, and the noise off is the exact reality of before, bit for bit. Real pybullet
(and MuJoCo where it is installed)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sim_workers.engines import ENGINES
from pydantic import ValidationError

from coordinator.loop.reality import SimulatedReality
from coordinator.run_config import PRE_SENSOR_NOISE, RunConfig, stored_run_config
from coordinator.loop.runner import reality_stream, sensor_noise
from sim_workers.domains import load
from sim_workers.engines import installed
from sim_workers.reality_gap import SensorNoise, noisy_readings, perceived_planar

SIGMA = 0.002                       # the container's finger opening
PICKUP = "pickup(r,b1,init)"


def kurtosis(x: np.ndarray) -> float:
    """Pearson's kurtosis (3 for a Gaussian)."""
    d = x - x.mean()
    return float(np.mean(d ** 4) / np.mean(d ** 2) ** 2)


def iqr(x: np.ndarray) -> float:
    q1, q3 = np.percentile(x, [25, 75])
    return float(q3 - q1)


def reality(domain: str = "container", n_blocks: int = 3, noise: SensorNoise = SensorNoise(),  # noqa: B008
            **options) -> SimulatedReality:
    truth = load(domain, n_blocks=n_blocks, **options).true_properties()
    return SimulatedReality(domain, {"n_blocks": n_blocks, **options}, truth, noise=noise)


def pickup(world: SimulatedReality, config, action: str = PICKUP):
    """Y's trajectory for `action` at the truth in `config` (the transit unchecked), executed."""
    d = world._domain
    pose = d.action_pose(world.truth, config, action)
    return world.execute(d.action_trajectory(config, action, pose), action)


def episode(noise: SensorNoise, seed: int, domain: str = "container", **options):
    """(start, after the pickup, the true configuration after it) of one episode; the
    pickup is planned on the true start, so that realities of other noise act alike."""
    world = reality(domain, noise=noise, **options)
    try:
        start = world.start_episode(np.random.default_rng(seed))
        after = pickup(world, world._start)
        return start, after, world.world.observe()
    finally:
        world.close()


def assert_same(a, b) -> None:
    np.testing.assert_array_equal(a.configuration.robot, b.configuration.robot)
    np.testing.assert_array_equal(a.configuration.objects, b.configuration.objects)
    np.testing.assert_array_equal(a.measurements, b.measurements)        # NaN == NaN here
    assert a.state == b.state


# -- (a) the noise itself ------------------------------------------------------------------
def test_the_container_s_finger_opening_after_a_pickup_is_noisy():
    _, noisy, _ = episode(SensorNoise(), seed=3)
    _, exact, _ = episode(SensorNoise.NONE, seed=3)
    assert "is_holding(r,b1)" in exact.state and noisy.state == exact.state
    diff = noisy.measurements[0] - exact.measurements[0]
    assert diff != 0 and abs(diff) < 5 * SIGMA
    assert exact.measurements[0] > 0.03              # the exact reading: the block's width


def test_gaussian_noise_has_the_declared_std_and_bias_shifts_its_mean():
    n = 4000
    x = noisy_readings(np.random.default_rng(0), np.zeros(n), SIGMA, SensorNoise())
    assert x.std() == pytest.approx(SIGMA, rel=0.05)
    assert abs(x.mean()) < 4 * SIGMA / np.sqrt(n)
    assert iqr(x) == pytest.approx(1.349 * SIGMA, rel=0.05)
    wide = noisy_readings(np.random.default_rng(1), np.zeros(n), SIGMA, SensorNoise(scale=2.5))
    assert wide.std() == pytest.approx(2.5 * SIGMA, rel=0.05)
    biased = noisy_readings(np.random.default_rng(2), np.zeros(n), SIGMA, SensorNoise(bias=1.5))
    assert biased.mean() == pytest.approx(1.5 * SIGMA, abs=4 * SIGMA / np.sqrt(n))
    assert biased.std() == pytest.approx(SIGMA, rel=0.05)
    # a bias alone (scale 0) is a constant offset
    only = noisy_readings(np.random.default_rng(3), np.zeros(5), SIGMA, SensorNoise(scale=0, bias=-2))
    np.testing.assert_allclose(only, -2 * SIGMA)
    # each channel its own sigma
    two = noisy_readings(np.random.default_rng(4), np.zeros(2 * n), np.repeat([SIGMA, 0.1], n),
                         SensorNoise())
    assert two[n:].std() == pytest.approx(0.1, rel=0.05)


def test_student_t_noise_has_the_declared_std_and_heavier_tails():
    t = SensorNoise(tails="student_t")
    x = noisy_readings(np.random.default_rng(0), np.zeros(4000), SIGMA, t)
    # t3's quartiles are +-0.765, over sqrt(3) for unit std: IQR 0.883 std (a Gaussian's 1.349)
    assert iqr(x) == pytest.approx(0.8833 * SIGMA, rel=0.06)
    assert kurtosis(x) > 4
    # t3's fourth moment is infinite: its sample std converges slowly, so many draws
    many = noisy_readings(np.random.default_rng(1), np.zeros(400_000), SIGMA, t)
    assert many.std() == pytest.approx(SIGMA, rel=0.05)
    g = noisy_readings(np.random.default_rng(0), np.zeros(4000), SIGMA, SensorNoise())
    assert kurtosis(g) < 3.3
    with pytest.raises(ValueError, match="tails"):
        SensorNoise(tails="cauchy")
    with pytest.raises(ValueError, match="scale"):
        SensorNoise(scale=-1)


def test_nan_stays_nan_and_the_draws_do_not_depend_on_it():
    a = noisy_readings(np.random.default_rng(5), [np.nan, 0.04, np.nan], SIGMA, SensorNoise())
    b = noisy_readings(np.random.default_rng(5), [0.0, 0.04, 0.0], SIGMA, SensorNoise())
    assert np.isnan(a[0]) and np.isnan(a[2]) and a[1] == b[1] != 0.04


def test_no_noise_draws_nothing():
    rng = np.random.default_rng(6)
    before = rng.bit_generator.state
    v = np.array([0.04, np.nan])
    np.testing.assert_array_equal(noisy_readings(rng, v, SIGMA, SensorNoise.NONE), v)
    objects = np.arange(21.0).reshape(3, 7)
    np.testing.assert_array_equal(perceived_planar(rng, objects, [1, 2], 0.0), objects)
    assert rng.bit_generator.state == before
    assert SensorNoise.NONE.exact and not SensorNoise().exact
    assert SensorNoise(scale=0, perception_m=0).exact


def test_perception_moves_the_rows_planar_positions_only():
    objects = np.tile(np.array([0.1, 0.2, 0.3, 0.0, 0.0, 0.0, 1.0]), (3, 1))
    out = np.array([perceived_planar(np.random.default_rng(s), objects, [1, 2], 0.002) for s in range(500)])
    np.testing.assert_array_equal(out[:, 0], np.broadcast_to(objects[0], (500, 7)))   # row 0 kept
    np.testing.assert_array_equal(out[:, 1:, 2:], np.broadcast_to(objects[1:, 2:], (500, 2, 5)))
    d = (out[:, 1:, :2] - objects[1:, :2]).ravel()
    assert d.std() == pytest.approx(0.002, rel=0.06) and abs(d.mean()) < 4 * 0.002 / np.sqrt(d.size)


# -- (b) every draw is the seed's -----------------------------------------------------------
def test_the_same_seed_gives_the_same_observations_another_seed_others():
    one, two, other = (episode(SensorNoise(), seed=s) for s in (11, 11, 12))
    for a, b in zip(one[:2], two[:2]):
        assert_same(a, b)
    assert one[1].measurements[0] != other[1].measurements[0]
    assert not np.array_equal(one[0].configuration.objects, other[0].configuration.objects)


def test_a_resumed_reality_stream_spawns_the_children_an_uninterrupted_one_would():
    """The noise is a spawned child stream, numbered by how many the generator spawned
    before: a checkpoint carries the count, so a resumed run draws what it would have."""
    world = reality()
    try:
        rng = reality_stream(7)
        world.start_episode(rng)
        checkpoint = {"reality_rng": rng.bit_generator.state,
                      "reality_rng_spawned": rng.bit_generator.seed_seq.n_children_spawned}
        assert checkpoint["reality_rng_spawned"] == 1          # the container: no exec jitter
        second = world.start_episode(rng)
        resumed = world.start_episode(reality_stream(7, json.loads(json.dumps(checkpoint))))
        assert_same(resumed, second)
    finally:
        world.close()


# -- (c) off: the exact reality of before ---------------------------------------------------
def test_noise_off_is_the_exact_reality_bit_for_bit():
    off = sensor_noise(RunConfig(sensor_noise=0, perception_sigma=0))
    assert off.exact
    rng_off, rng_exact = np.random.default_rng(9), np.random.default_rng(9)
    a, b = reality(noise=off), reality(noise=SensorNoise.NONE)
    try:
        assert_same(a.start_episode(rng_off), b.start_episode(rng_exact))
        # no child spawned: the generator (and a checkpoint of it) as before the noise
        assert rng_off.bit_generator.seed_seq.n_children_spawned == 0
        assert rng_off.bit_generator.state == rng_exact.bit_generator.state
    finally:
        a.close(), b.close()
    for x, y in zip(episode(off, seed=9)[:2], episode(SensorNoise.NONE, seed=9)[:2]):
        assert_same(x, y)


def test_perception_or_sensors_alone():
    """Each part switches on its own, and either leaves the other's draws as they are."""
    both, sensors, seen, exact = (episode(n, seed=4)[1] for n in (
        SensorNoise(), SensorNoise(perception_m=0), SensorNoise(scale=0), SensorNoise.NONE))
    np.testing.assert_array_equal(sensors.configuration.objects, exact.configuration.objects)
    np.testing.assert_array_equal(seen.measurements[:1], exact.measurements[:1])
    assert sensors.measurements[0] == both.measurements[0] != exact.measurements[0]
    np.testing.assert_array_equal(seen.configuration.objects, both.configuration.objects)


# -- (d) perceived, not true ----------------------------------------------------------------
def test_perceived_positions_differ_by_about_the_sigma_and_the_world_keeps_the_truth():
    d = load("container", n_blocks=3)
    moved, noisy, exact = [], reality(noise=SensorNoise()), reality(noise=SensorNoise.NONE)
    try:
        for seed in range(40):
            obs = noisy.start_episode(np.random.default_rng(seed))
            true = exact.start_episode(np.random.default_rng(seed))
            # the true world: as the exact reality's, bit for bit
            np.testing.assert_array_equal(noisy.world.observe().objects, exact.world.observe().objects)
            np.testing.assert_array_equal(noisy._start.objects, true.configuration.objects)
            diff = obs.configuration.objects - true.configuration.objects
            np.testing.assert_array_equal(diff[0], 0.0)                     # the tray: a fixture
            np.testing.assert_array_equal(diff[:, 2:], 0.0)                 # heights, orientations
            moved.append(diff[list(d.jittered_objects), :2].ravel())
            # the block-position channels read the perceived configuration
            np.testing.assert_array_equal(obs.measurements[1:], obs.configuration.objects[1:, :2].ravel())
        moved = np.concatenate(moved)
        assert moved.std() == pytest.approx(0.002, rel=0.12)
        assert np.all(moved != 0)
        # after an action too: the world goes on from the truth
        start_n = noisy.start_episode(np.random.default_rng(1))
        start_e = exact.start_episode(np.random.default_rng(1))
        after_n, after_e = pickup(noisy, start_e.configuration), pickup(exact, start_e.configuration)
        np.testing.assert_array_equal(noisy.world.observe().objects, exact.world.observe().objects)
        assert not np.array_equal(after_n.configuration.objects, after_e.configuration.objects)
        assert not np.array_equal(start_n.configuration.objects, start_e.configuration.objects)
        np.testing.assert_array_equal(after_n.measurements[1:], after_n.configuration.objects[1:, :2].ravel())
    finally:
        noisy.close(), exact.close()


def test_stack_and_push_s_positions_are_perceived_and_its_weight_weighed_with_noise():
    options = {"unknown_density": True}            # the held weight weighed (0.1 N)
    n = 3
    _, noisy, _ = episode(SensorNoise(), seed=2, domain="stack_and_push", **options)
    _, exact, _ = episode(SensorNoise.NONE, seed=2, domain="stack_and_push", **options)
    weight, width = 1 + 2 * n, 2 + 2 * n
    assert np.isfinite(exact.measurements[weight]) and np.isfinite(noisy.measurements[weight])
    assert noisy.measurements[weight] != exact.measurements[weight]
    assert abs(noisy.measurements[weight] - exact.measurements[weight]) < 5 * 0.1
    assert noisy.measurements[width] != exact.measurements[width]
    # every block (b1 at the start site too) is a movable object: its channels read the perception
    np.testing.assert_array_equal(noisy.measurements[1:1 + 2 * n], noisy.configuration.objects[:, :2].ravel())
    assert np.all(noisy.configuration.objects[:, :2] != exact.configuration.objects[:, :2])


# -- (e) Y^-1 tolerates the perception ------------------------------------------------------
@pytest.mark.parametrize("domain", ["container", "stack_and_push"])
def test_y_inverse_of_the_perceived_start_is_the_exact_start_state(domain):
    noisy = reality(domain, n_blocks=8, noise=SensorNoise())
    exact = reality(domain, n_blocks=8, noise=SensorNoise.NONE)
    try:
        for seed in range(20):
            obs = noisy.start_episode(np.random.default_rng(seed))
            true = exact.start_episode(np.random.default_rng(seed))
            assert not np.array_equal(obs.configuration.objects, true.configuration.objects)
            assert obs.state == true.state == noisy._domain.symbolic_state(obs.configuration), seed
    finally:
        noisy.close(), exact.close()


# -- (f) the settings ------------------------------------------------------------------------
def test_run_config_bounds_defaults_and_stored_configs():
    with pytest.raises(ValidationError, match="sensor_noise"):
        RunConfig(sensor_noise=-1)
    for field, bad in (("sensor_noise", 11), ("sensor_bias", 6), ("sensor_bias", -6),
                       ("sensor_tails", "cauchy"), ("perception_sigma", -0.001), ("perception_sigma", 0.1)):
        with pytest.raises(ValidationError, match=field):
            RunConfig(**{field: bad})
    d = RunConfig()
    assert sensor_noise(d) == SensorNoise()            # RunConfig's defaults are SensorNoise's
    assert (d.sensor_noise, d.sensor_bias, d.sensor_tails, d.perception_sigma) == (1.0, 0.0, "gaussian", 0.002)
    old = {k: v for k, v in d.model_dump().items() if k not in PRE_SENSOR_NOISE}
    stored = stored_run_config(old)
    assert {k: getattr(stored, k) for k in PRE_SENSOR_NOISE} == PRE_SENSOR_NOISE
    assert sensor_noise(stored) == SensorNoise.NONE
    kept = stored_run_config({**old, "sensor_noise": 2.0, "sensor_tails": "student_t"})
    assert sensor_noise(kept) == SensorNoise(scale=2.0, tails="student_t", perception_m=0.0)


def test_the_run_flags_set_the_fields(capsys):
    from coordinator.cli import main

    assert main(["run", "--sensor-noise", "0.5", "--sensor-bias", "-1", "--sensor-tails", "student_t",
                 "--perception-sigma", "0.004", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert (cfg["sensor_noise"], cfg["sensor_bias"], cfg["sensor_tails"], cfg["perception_sigma"]) == \
        (0.5, -1.0, "student_t", 0.004)
    assert main(["run", "--sensor-noise", "-1", "--print-config"]) == 2
    assert "--sensor-noise" in capsys.readouterr().err
    assert main(["run", "--sensor-tails", "cauchy", "--print-config"]) == 2
    assert "--sensor-tails" in capsys.readouterr().err


def test_a_robot_session_has_no_sensor_fields_a_task_has():
    from api.schemas.requests import session_create_model, task_spec_model
    from pydantic import TypeAdapter

    fields = ("sensor_noise", "sensor_bias", "sensor_tails", "perception_sigma")
    task = TypeAdapter(task_spec_model(100, 10)).json_schema()
    session = TypeAdapter(session_create_model(100, 10)).json_schema()
    task_props = {p for m in task["$defs"].values() for p in m.get("properties", {})}
    session_props = {p for m in session["$defs"].values() for p in m.get("properties", {})}
    assert set(fields) <= task_props and not set(fields) & session_props


def test_the_gym_env_s_reality_is_noisy_by_default():
    pytest.importorskip("gymnasium")
    from coordinator.integrations.gym_env import TmocEnv

    noisy, exact = TmocEnv(n_blocks=2), TmocEnv(n_blocks=2, sensor_noise=0, perception_sigma=0)
    try:
        assert noisy.noise == SensorNoise() and exact.noise.exact
        a, _ = noisy.reset(seed=1)
        b, _ = exact.reset(seed=1)
        assert not np.array_equal(a["configuration"], b["configuration"])
        np.testing.assert_array_equal(a["state"], b["state"])
    finally:
        noisy.close(), exact.close()


# -- (g) both engines ----------------------------------------------------------------------
@pytest.mark.skipif(not installed("mujoco") or not installed("pybullet"), reason="needs both engines")
def test_mujoco_s_reality_has_the_same_channels_and_the_same_noise():
    """The container's reality in MuJoCo (`--reality-engine mujoco`: ``engine`` in the domain
    options): the same channel layout, noisy readings, and the same draws as pybullet's."""
    runs = {}
    for engine in ENGINES:
        runs[engine] = [episode(n, seed=5, engine=engine) for n in (SensorNoise(), SensorNoise.NONE)]
    channels = {e: load("container", n_blocks=3, engine=e).measurement_channels() for e in runs}
    assert channels["mujoco"] == channels["pybullet"]
    offsets = {}
    for engine, ((start, after, _), (start0, after0, _)) in runs.items():
        assert len(after.measurements) == len(channels[engine])
        assert "is_holding(r,b1)" in after0.state and after.state == after0.state
        assert after.measurements[0] != after0.measurements[0]
        offsets[engine] = (after.measurements - after0.measurements,
                           start.configuration.objects - start0.configuration.objects)
    for a, b in zip(offsets["pybullet"], offsets["mujoco"]):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
