"""Belief over L: prior, Bayes update, systematic resampling with jitter, summaries, checkpoints."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from coordinator.particle_filter.belief import (
    Belief,
    gaussian_log_likelihood,
    symbolic_log_likelihood,
    systematic_resample,
)

LOW, HIGH = 0.030, 0.060


def prior(n: int = 200, seed: int = 0, d: int = 1) -> Belief:
    return Belief.from_prior(n, [LOW] * d, [HIGH] * d, np.random.default_rng(seed))


def test_from_prior_uniform_in_bounds_and_seeded():
    b = prior(20000, seed=1)
    assert b.particles.shape == (20000, 1)
    assert np.all(b.particles >= LOW) and np.all(b.particles < HIGH)
    assert np.allclose(b.weights, 1 / 20000) and b.ess() == pytest.approx(20000)
    # Uniform: each of 10 equal bins holds about a tenth (binomial sd ~ 42 of 2000).
    counts, _ = np.histogram(b.particles[:, 0], bins=10, range=(LOW, HIGH))
    assert np.all(np.abs(counts - 2000) < 250)
    assert np.array_equal(prior(50, seed=7).particles, prior(50, seed=7).particles)
    assert not np.array_equal(prior(50, seed=7).particles, prior(50, seed=8).particles)


def test_from_prior_multi_dimensional_and_bad_bounds():
    b = Belief.from_prior(10, [0.0, 1.0], [1.0, 3.0], np.random.default_rng(0))
    assert b.particles.shape == (10, 2)
    assert np.all(b.particles[:, 1] >= 1.0) and np.all(b.particles[:, 1] < 3.0)
    with pytest.raises(ValueError, match="low"):
        Belief.from_prior(10, [1.0], [0.5], np.random.default_rng(0))
    with pytest.raises(ValueError, match="n"):
        Belief.from_prior(0, [0.0], [1.0], np.random.default_rng(0))


def test_update_moves_mean_toward_x0_and_shrinks_spread():
    b = prior(500)
    mean0, std0 = b.mean()[0], b.std()[0]
    x0 = 0.045 + 0.008  # away from the prior mean 0.045
    b.update(gaussian_log_likelihood(np.array([x0]), b.particles, sigma=0.003))
    assert abs(b.mean()[0] - x0) < abs(mean0 - x0) / 4
    assert b.std()[0] < std0 / 2
    assert logsumexp_is_zero(b)
    assert b.weights.sum() == pytest.approx(1.0)


def logsumexp_is_zero(b: Belief) -> bool:
    m = b.log_weights.max()
    return abs(m + math.log(np.exp(b.log_weights - m).sum())) < 1e-12


def test_degenerate_likelihood_keeps_weights_and_flags():
    b = prior(50)
    b.update(np.where(np.arange(50) < 25, 0.0, -np.inf))  # half die: fine
    before = b.log_weights.copy()
    b.update(np.full(50, -np.inf))
    assert b.last_update_degenerate
    assert b.degenerate_updates == 1
    assert np.array_equal(b.log_weights, before)
    assert not np.any(np.isnan(b.weights)) and not math.isnan(b.ess())
    assert b.ess() == pytest.approx(25)
    # Enormous but finite log likelihoods do not underflow either (log space).
    b.update(np.linspace(-1e6, -1e6 + 1.0, 50))
    assert not b.last_update_degenerate
    assert np.all(np.isfinite(b.weights)) and b.weights.sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="NaN"):
        b.update(np.full(50, np.nan))
    with pytest.raises(ValueError, match="shape"):
        b.update(np.zeros(3))


def test_systematic_counts_are_floor_or_ceil():
    rng = np.random.default_rng(3)
    for n in (7, 50, 200):
        for _ in range(20):
            w = rng.dirichlet(np.full(n, 0.3))
            counts = np.bincount(systematic_resample(w, rng), minlength=n)
            assert counts.sum() == n
            assert np.all(counts >= np.floor(n * w) - 1e-9)
            assert np.all(counts <= np.ceil(n * w) + 1e-9)


def test_resample_counts_rows_and_uniform_weights():
    b = prior(100, seed=2)
    original = b.particles.copy()
    rng = np.random.default_rng(4)
    b.update(np.log(rng.dirichlet(np.full(100, 0.2))))
    w = b.weights
    assert b.maybe_resample(rng, jitter=0.0, jitter_floor=0.0)
    # Without jitter each original particle appears floor/ceil(N w_i) times ...
    counts = np.array([np.sum(b.particles[:, 0] == x) for x in original[:, 0]])
    assert counts.sum() == 100
    assert np.all(counts >= np.floor(100 * w)) and np.all(counts <= np.ceil(100 * w))
    # ... survivors keep their row (so shards rebuild only replaced rows) ...
    survivors = counts > 0
    assert np.array_equal(b.particles[survivors], original[survivors])
    # ... and weights become uniform.
    assert np.allclose(b.weights, 0.01) and b.ess() == pytest.approx(100)


def test_ess_threshold_triggers_only_below_half():
    n = 100
    # Weight a on m particles, the rest share the remainder: tune ESS around N/2.
    def belief_with_ess(target: float) -> Belief:
        b = prior(n)
        m = 10
        # ESS = 1 / (m a^2 + (1 - m a)^2 / (n - m)); solve for a by bisection.
        lo, hi = 1 / n, 1 / m
        for _ in range(200):
            a = (lo + hi) / 2
            ess = 1 / (m * a * a + (1 - m * a) ** 2 / (n - m))
            lo, hi = (a, hi) if ess > target else (lo, a)
        w = np.full(n, (1 - m * a) / (n - m))
        w[:m] = a
        b.update(np.log(w))
        return b

    above = belief_with_ess(50.5)
    assert above.ess() == pytest.approx(50.5, abs=1e-6)
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    assert above.maybe_resample(rng) is False
    assert rng.bit_generator.state == state  # no draws when not resampling
    below = belief_with_ess(49.5)
    assert below.maybe_resample(rng) is True


def test_jitter_stays_in_bounds_and_makes_copies_distinct():
    b = prior(200, seed=5, d=2)
    # All mass on the particle closest to the upper bound of dimension 0.
    i = int(np.argmax(b.particles[:, 0]))
    ll = np.full(200, -np.inf)
    ll[i] = 0.0
    b.update(ll)
    rng = np.random.default_rng(6)
    assert b.maybe_resample(rng, jitter=0.1, jitter_floor=0.05)
    assert np.all(b.particles >= LOW) and np.all(b.particles <= HIGH)
    assert len(np.unique(b.particles[:, 0])) == 200
    assert len(np.unique(b.particles[:, 1])) == 200
    # A huge jitter still lands inside (reflection folds any distance).
    b.update(ll)
    b.maybe_resample(rng, jitter=0.0, jitter_floor=10.0)
    assert np.all(b.particles >= LOW) and np.all(b.particles <= HIGH)


def test_weighted_mean_of_angles_near_pi():
    b = prior(4)
    b.update(np.log(np.array([0.375, 0.375, 0.125, 0.125])))
    yaw = np.array([math.pi - 0.1, math.pi - 0.1, -math.pi + 0.1, -math.pi + 0.1])
    poses = np.column_stack([np.arange(4.0), np.zeros(4), np.ones(4), yaw])
    mean = b.weighted_mean(poses)
    expected = math.atan2(0.75 * math.sin(math.pi - 0.1) + 0.25 * math.sin(-math.pi + 0.1),
                          0.75 * math.cos(math.pi - 0.1) + 0.25 * math.cos(-math.pi + 0.1))
    assert mean[3] == pytest.approx(expected)
    assert abs(abs(mean[3]) - math.pi) < 0.1  # near +-pi, not near 0 like the linear mean
    assert mean[0] == pytest.approx(0.375 * 1 + 0.125 * 2 + 0.125 * 3)
    linear = b.weighted_mean(poses, angular=())
    assert linear[3] == pytest.approx(0.75 * (math.pi - 0.1) + 0.25 * (-math.pi + 0.1))
    # Equal weights across the seam: exactly +-pi.
    b2 = prior(2)
    m2 = b2.weighted_mean(np.array([[math.pi - 0.2], [-math.pi + 0.2]]), angular=(0,))
    assert abs(m2[0]) == pytest.approx(math.pi)
    assert b2.weighted_mean(np.array([1.0, 3.0])) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="angular"):
        b2.weighted_mean(np.zeros((2, 2)), angular=(5,))


def test_summary_is_json_able():
    b = prior(100)
    b.update(gaussian_log_likelihood(np.array([0.04]), b.particles, 0.005))
    s = json.loads(json.dumps(b.summary(bins=10)))
    assert s["n"] == 100 and len(s["mean"]) == 1 and len(s["std"]) == 1
    assert s["ess"] == pytest.approx(b.ess())
    h = s["histogram"][0]
    assert len(h["edges"]) == 11 and len(h["weights"]) == 10
    assert h["edges"][0] == LOW and h["edges"][-1] == HIGH
    assert sum(h["weights"]) == pytest.approx(1.0)


def test_to_dict_round_trip_is_exact():
    b = prior(64, d=3)
    ll = np.random.default_rng(1).normal(size=64) * 3
    ll[:5] = -np.inf  # zero weights survive the trip (as None, strict JSON)
    b.update(ll)
    b.update(np.full(64, -np.inf))  # and the degenerate flag
    text = json.dumps(b.to_dict(), allow_nan=False)
    c = Belief.from_dict(json.loads(text))
    assert np.array_equal(c.particles, b.particles)
    assert np.array_equal(c.log_weights, b.log_weights)
    assert np.array_equal(c.low, b.low) and np.array_equal(c.high, b.high)
    assert c.degenerate_updates == 1 and c.last_update_degenerate
    assert c.to_dict() == b.to_dict()


def test_identical_seeds_identical_runs():
    def run(seed: int) -> Belief:
        rng = np.random.default_rng(seed)
        b = Belief.from_prior(100, [LOW], [HIGH], rng)
        for x in (0.044, 0.046, 0.045):
            b.update(gaussian_log_likelihood(np.array([x]), b.particles, 0.002))
            b.maybe_resample(rng)
        return b

    a, b = run(11), run(11)
    assert np.array_equal(a.particles, b.particles)
    assert np.array_equal(a.log_weights, b.log_weights)
    assert abs(a.mean()[0] - 0.045) < 0.002


def test_symbolic_log_likelihood_values():
    s1 = frozenset({"is_in(b1,init)", "hand_empty(r)"})
    s2 = frozenset({"is_holding(r,b1)"})
    ll = symbolic_log_likelihood(s1, [s1, s2, frozenset(s1)], error_rate=0.1)
    assert ll == pytest.approx([math.log(0.9), math.log(0.1), math.log(0.9)])
    assert symbolic_log_likelihood(s1, [s2], error_rate=0.0)[0] == -math.inf
    assert symbolic_log_likelihood(s1, [], 0.05).shape == (0,)
    with pytest.raises(ValueError, match="error_rate"):
        symbolic_log_likelihood(s1, [s1], error_rate=1.0)


def test_gaussian_log_likelihood_values_and_nan():
    obs = np.array([1.0, np.nan, 0.0])
    pred = np.array([[1.0, 5.0, 0.0], [2.0, -3.0, 0.5]])
    ll = gaussian_log_likelihood(obs, pred, sigma=0.5)
    norm = -2 * math.log(0.5 * math.sqrt(2 * math.pi))
    assert ll[0] == pytest.approx(norm)
    assert ll[1] == pytest.approx(norm - 0.5 * (4.0 + 1.0))
    # Per-component sigma.
    ll2 = gaussian_log_likelihood(np.array([0.0, 0.0]), np.array([[1.0, 1.0]]), np.array([1.0, 2.0]))
    assert ll2[0] == pytest.approx(-0.5 * (1 + 0.25) - math.log(2.0) - math.log(2 * math.pi))
    assert np.array_equal(gaussian_log_likelihood(np.array([np.nan]), np.zeros((3, 1)), 1.0),
                          np.zeros(3))
    with pytest.raises(ValueError, match="sigma"):
        gaussian_log_likelihood(obs, pred, sigma=0.0)


def test_mode_mask_shortcut_agrees_with_the_full_density():
    """The O(1) shortcut for a narrow belief keeps exactly what the N^2 density keeps."""
    from coordinator.particle_filter.belief import mode_mask
    rng = np.random.default_rng(3)
    bw = 0.003
    for width in (0.0005, 0.002, 0.0042, 0.02):
        p = 0.045 + rng.uniform(-width / 2, width / 2, size=(200, 2))
        w = rng.dirichlet(np.ones(200))
        got = mode_mask(p, w, bw)
        d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
        best = int(np.argmax((np.exp(-0.5 * d2 / bw ** 2) * w[None, :]).sum(1)))
        np.testing.assert_array_equal(got, d2[best] <= (2 * bw) ** 2)
    # bimodal: only the heavier mode is kept
    p = np.r_[np.full((30, 1), 0.030), np.full((70, 1), 0.060)]
    keep = mode_mask(p, np.full(100, 0.01), bw)
    assert keep.sum() == 70 and np.all(keep[30:])


def test_heaviest_class_keeps_one_class_of_the_mode():
    """Particles of the mode on both sides of a switch in Y: only the heavier side is
    averaged; a mode of one class comes back as it was (the same array)."""
    from coordinator.particle_filter.belief import heaviest_class
    classes = np.array([1, 1, 0, 0, 0])
    keep = np.array([True, True, True, True, False])
    w = np.array([0.3, 0.3, 0.1, 0.1, 0.2])          # the dropped particle's weight does not count
    assert heaviest_class(classes, w, keep).tolist() == [True, True, False, False, False]
    assert heaviest_class(classes, w[::-1], keep).tolist() == [False, False, True, True, False]
    one = np.array([True, True, False, False, False])
    assert heaviest_class(classes, w, one) is one
    # a tie goes to the smallest label, whatever the order
    tie = heaviest_class(np.array([2, 0]), np.array([0.5, 0.5]), np.array([True, True]))
    assert tie.tolist() == [False, True]


@pytest.mark.parametrize("dim", [1, 2, 16])
def test_mode_above_the_exact_limit_keeps_the_exact_mode(dim):
    """Above MODE_EXACT_MAX particles the density is evaluated at candidates drawn by
    weight: on beliefs with a heavier mode (three modes of different weight and width), the
    densest candidate's density is within 3 % of the exact maximum and the kept set is the
    exact one's to >= 95 %, in one, two and sixteen dimensions (per-block L)."""
    from coordinator.particle_filter.belief import MODE_EXACT_MAX, mode_candidates, mode_mask
    rng = np.random.default_rng(5)
    bw = 0.003
    n = MODE_EXACT_MAX + 488
    for trial in range(4):
        centres = rng.uniform(0.03, 0.06, size=(3, dim))
        which = rng.choice(3, size=n, p=[0.6, 0.25, 0.15])
        spread = np.array([0.002, 0.004, 0.003]) / np.sqrt(dim)
        p = centres[which] + spread[which, None] * rng.standard_normal((n, dim))
        w = rng.dirichlet(np.ones(n))
        d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
        exact = (np.exp(-0.5 * d2 / bw ** 2) * w[None, :]).sum(1)
        keep = mode_mask(p, w, bw)
        assert exact[mode_candidates(w, MODE_EXACT_MAX)].max() >= 0.97 * exact.max(), trial
        want = d2[int(np.argmax(exact))] <= (2 * bw) ** 2
        assert (keep & want).sum() >= 0.95 * want.sum(), trial
    # at or below the limit every particle is a candidate: the exact path, unchanged
    assert len(mode_candidates(np.full(MODE_EXACT_MAX, 1.0), MODE_EXACT_MAX)) == MODE_EXACT_MAX


@pytest.mark.parametrize("dim", [1, 2])
def test_binned_density_finds_the_exact_densest_particle(dim):
    """Above MODE_EXACT_MAX, in one and two dimensions, the density comes from a grid
    (binned KDE, linear in N, issue 42): the particle it picks has an exact density within
    1 % of the exact maximum and lies within half a bandwidth of the exact argmax, on beliefs
    with three modes of different weight and width, and on the prior (uniform)."""
    from coordinator.particle_filter.belief import MODE_EXACT_MAX, _densest_binned
    rng = np.random.default_rng(11)
    bw = 0.003
    n = MODE_EXACT_MAX + 988
    for trial in range(5):
        if trial == 4:
            p = rng.uniform(0.03, 0.06, size=(n, dim))
        else:
            centres = rng.uniform(0.03, 0.06, size=(3, dim))
            which = rng.choice(3, size=n, p=[0.5, 0.3, 0.2])
            spread = np.array([0.002, 0.004, 0.003])
            p = centres[which] + spread[which, None] * rng.standard_normal((n, dim))
        w = rng.dirichlet(np.ones(n))
        d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
        exact = (np.exp(-0.5 * d2 / bw ** 2) * w[None, :]).sum(1)
        best = _densest_binned(p, w, bw)
        assert best is not None
        assert exact[best] >= 0.99 * exact.max(), trial
        assert np.sqrt(d2[best, int(np.argmax(exact))]) <= 0.5 * bw, trial


def test_binned_density_declines_a_grid_past_its_budget():
    from coordinator.particle_filter.belief import _densest_binned
    p = np.random.default_rng(0).uniform(0.03, 0.06, size=(1000, 4))   # (40 cells)^4 >> 4 N
    assert _densest_binned(p, np.full(1000, 1e-3), 0.003) is None
