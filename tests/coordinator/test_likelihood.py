"""The robust measurement likelihood, the update's information and the online model error
(issue 24): what no particle explains moves nothing, what some explain keeps its weight."""
from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.particle_filter.belief import Belief, gaussian_log_likelihood
from coordinator.particle_filter.likelihood import (INFORMATIVE_NATS, normalised_evidence, perfect_log_likelihood,
                                    robust_log_likelihood, update_information)
from coordinator.particle_filter.model_error import MIN_COUNT, ModelError, model_variance

LOW, HIGH, SIGMA = 0.030, 0.060, 0.002


def sizes_belief(n: int = 64, seed: int = 0) -> Belief:
    return Belief.from_prior(n, [LOW], [HIGH], np.random.default_rng(seed))


def opening_update(b: Belief, reading: float, eps: float) -> float:
    """Update with a finger opening `reading` that each particle predicts at its size; the KL."""
    before = b.log_weights.copy()
    ll = (robust_log_likelihood([reading], b.particles, SIGMA, eps) if eps > 0
          else gaussian_log_likelihood([reading], b.particles, SIGMA))
    b.update(ll)
    return update_information(before, b.log_weights)


def test_an_observation_no_particle_explains_leaves_the_belief_unchanged():
    """Fingers that closed on air (opening ~0) against predictions of 30-60 mm: the
    Gaussian drags the belief to the smallest particles; the mixture leaves it alone."""
    robust, plain = sizes_belief(), sizes_belief()
    mean0 = plain.mean()[0]
    kl = opening_update(robust, 0.0005, eps=0.05)
    assert kl < 1e-12 < INFORMATIVE_NATS
    assert np.allclose(robust.log_weights, sizes_belief().log_weights, atol=1e-12, rtol=0)
    kl_plain = opening_update(plain, 0.0005, eps=0.0)
    assert kl_plain > 2.0 and plain.mean()[0] < mean0 - 0.010       # before: 10+ mm off at once


def test_an_observation_some_particles_explain_still_moves_it():
    b = sizes_belief()
    kl = opening_update(b, 0.041, eps=0.05)
    assert kl > 1.0
    assert abs(b.mean()[0] - 0.041) < 0.002 and b.std()[0] < 0.003


def test_the_robust_likelihood_concentrates_on_the_truth_with_consistent_data():
    """Twenty readings of a 41 mm block with 2 mm noise: about the Gaussian's posterior (the
    means within half its std of each other), around the truth."""
    rng = np.random.default_rng(3)
    readings = 0.041 + SIGMA * rng.standard_normal(20)
    robust, plain = sizes_belief(2000, 1), sizes_belief(2000, 1)
    for y in readings:
        opening_update(robust, y, eps=0.05)
        opening_update(plain, y, eps=0.0)
    assert abs(robust.mean()[0] - 0.041) < 0.001
    assert abs(robust.mean()[0] - plain.mean()[0]) < 0.5 * plain.std()[0]
    assert robust.std()[0] == pytest.approx(plain.std()[0], rel=0.15)


def test_zero_outlier_rate_is_the_plain_gaussian_and_nan_is_not_measured():
    pred = np.array([[0.040, 1.0], [0.045, 2.0], [0.050, 3.0]])
    obs = np.array([0.044, np.nan])
    assert np.allclose(robust_log_likelihood(obs, pred, [SIGMA, 0.1], eps=0.0),
                       gaussian_log_likelihood(obs, pred, [SIGMA, 0.1]), rtol=0, atol=1e-9)
    assert np.all(robust_log_likelihood([np.nan], pred[:, :1], SIGMA) == 0.0)
    with pytest.raises(ValueError, match="eps"):
        robust_log_likelihood(obs, pred, SIGMA, eps=1.0)
    with pytest.raises(ValueError, match="NaN"):
        robust_log_likelihood([0.04], [[np.nan]], SIGMA)


def test_per_channel_a_bad_channel_does_not_hide_a_good_one():
    """The opening fits particle 0, the other channel is wild for both: particle 0 still wins
    by the opening's Gaussian information."""
    obs = np.array([0.041, 50.0])
    pred = np.array([[0.041, 1.0], [0.045, 1.2]])
    ll = robust_log_likelihood(obs, pred, [SIGMA, 0.1])
    assert ll[0] - ll[1] == pytest.approx(0.5 * 4.0, abs=0.02)        # (4 mm / 2 mm)^2 / 2


def test_normalised_evidence_is_one_for_an_exact_prediction():
    obs = np.array([0.041])
    perfect = perfect_log_likelihood(obs, SIGMA)
    ll = robust_log_likelihood(obs, np.array([[0.041], [0.041]]), SIGMA)
    assert normalised_evidence(np.log([0.5, 0.5]), ll, perfect) == pytest.approx(1.0)
    miss = robust_log_likelihood(obs, np.array([[0.060], [0.031]]), SIGMA)
    assert normalised_evidence(np.log([0.5, 0.5]), miss, perfect) < 0.01


# -- model error --------------------------------------------------------------------------
def _innovations(model: ModelError, residuals, spread: float = 0.0) -> None:
    for r in residuals:
        pred = np.array([[0.045 - spread], [0.045 + spread]])
        model.observe(np.array([0.045 + r]), pred, np.array([0.5, 0.5]))


def test_model_error_grows_with_the_scatter_of_residuals_only():
    rng = np.random.default_rng(0)
    consistent, scattered = ModelError([SIGMA]), ModelError([SIGMA])
    _innovations(consistent, SIGMA * rng.standard_normal(200))
    _innovations(scattered, 0.005 * rng.standard_normal(200))
    assert consistent.model_sigma[0] < 0.0008                        # the sensor explains it
    assert scattered.model_sigma[0] == pytest.approx(math.sqrt(0.005 ** 2 - SIGMA ** 2), rel=0.2)
    assert scattered.sigma()[0] == pytest.approx(0.005, rel=0.2)
    # The predictive spread of the particles is not model error: wide predictions explain it.
    wide = ModelError([SIGMA])
    _innovations(wide, 0.005 * rng.standard_normal(200), spread=0.005)
    assert wide.model_sigma[0] < 0.0015


def test_model_error_ignores_a_few_outliers_and_waits_for_enough_data():
    rng = np.random.default_rng(1)
    m = ModelError([SIGMA])
    _innovations(m, [0.05] * (MIN_COUNT - 1))
    assert m.model_sigma[0] == 0.0                                   # too few to say
    m = ModelError([SIGMA])
    _innovations(m, list(SIGMA * rng.standard_normal(90)) + [0.045] * 10)   # 10 % closed on air
    assert m.model_sigma[0] < 0.0015
    assert model_variance(np.zeros(0), np.zeros(0), SIGMA ** 2) == 0.0


def test_model_error_round_trips_and_an_old_checkpoint_starts_fresh():
    rng = np.random.default_rng(2)
    m = ModelError([SIGMA, 0.1])
    for _ in range(30):
        m.observe(np.array([0.045 + 0.004 * rng.standard_normal(), np.nan]),
                  np.array([[0.045, 1.0], [0.046, 1.1]]), np.array([0.3, 0.7]))
    back = ModelError.from_dict(m.to_dict(), [SIGMA, 0.1])
    assert back.history == m.history and np.array_equal(back.model_sigma, m.model_sigma)
    assert back.model_sigma[0] > 0 and back.model_sigma[1] == 0.0    # channel 2 never measured
    fresh = ModelError.from_dict(None, [SIGMA, 0.1])
    assert np.array_equal(fresh.sigma(), [SIGMA, 0.1])
