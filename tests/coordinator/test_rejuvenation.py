"""Regularised resampling and the lock-in monitor (issue 24): the Musso bandwidth, prior
draws only when no particle explained an observation, only for the block it concerns."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.particle_filter.belief import Belief
from coordinator.particle_filter.rejuvenation import LockInMonitor, action_blocks, inject_prior, regularise, rpf_bandwidth


def test_the_bandwidth_is_musso_oudjane_le_gland():
    for n, d in ((16, 1), (16, 2), (8, 16), (1000, 3)):
        assert rpf_bandwidth(n, d) == pytest.approx((4 / (n * (d + 2))) ** (1 / (d + 4)))
    assert rpf_bandwidth(1000, 1) < rpf_bandwidth(16, 1) < 1.0        # more particles, less smoothing
    with pytest.raises(ValueError):
        rpf_bandwidth(0, 1)


def test_the_monitor_redraws_only_at_repeated_unexplained_observations():
    m = LockInMonitor(slow=0.05, fast=0.3)
    assert [m.observe("b1", True) for _ in range(20)] == [0.0] * 20
    shares = [m.observe("b1", False) for _ in range(4)]
    assert shares[:2] == [0.0, 0.0]                                   # an isolated surprise: nothing
    assert 0.5 < shares[2] < shares[3] < 0.8                          # the third in a row: 60 %
    assert m.observe("b1", True) == 0.0                               # explained: never
    # Another block's history is its own: its first unexplained observation starts afresh.
    assert m.observe("b2", False) == 0.0
    with pytest.raises(ValueError, match="slow < fast"):
        LockInMonitor(slow=0.5, fast=0.3)


def test_the_monitor_round_trips():
    m = LockInMonitor()
    for key, ok in (("b1", True), ("b2", False), ("b1", False)):
        m.observe(key, ok)
    back = LockInMonitor.from_dict(m.to_dict())
    assert back == m
    assert back.observe("b1", False) == m.observe("b1", False)
    assert LockInMonitor.from_dict(None, slow=0.1, fast=0.4) == LockInMonitor(0.1, 0.4)


def test_action_blocks_reads_the_blocks_an_action_names():
    names = [f"b{i}" for i in range(1, 9)]
    assert action_blocks("pickup(r,b3,init)", names) == [2]
    assert action_blocks("stack(r, b8, tower)", names) == [7]
    assert action_blocks("push(r,tower,start,goal)", names) == []


def _locked(n: int = 16) -> Belief:
    """Every particle's block-2 size stuck at the prior's 30 mm floor; other blocks spread."""
    rng = np.random.default_rng(0)
    b = Belief.from_prior(n, [0.030] * 3, [0.060] * 3, rng)
    b.particles[:, 1] = 0.030 + 0.0005 * rng.random(n)
    return b


def test_inject_redraws_the_given_dimensions_of_a_share_of_rows_from_the_prior():
    b = _locked()
    before = b.particles.copy()
    count = inject_prior(b, 0.5, np.array([1]), np.random.default_rng(1))
    assert count in (8, 9)                                            # floor(0.5 * 16 + u)
    changed = np.flatnonzero(b.particles[:, 1] != before[:, 1])
    assert len(changed) == count
    assert np.all((b.particles[:, 1] >= 0.030) & (b.particles[:, 1] <= 0.060))
    assert b.particles[changed, 1].std() > 0.003                      # spread over the prior
    # Other blocks keep what they learned.
    assert np.array_equal(b.particles[:, [0, 2]], before[:, [0, 2]])
    assert np.allclose(b.weights, 1 / 16)


def test_inject_is_deterministic_with_a_seeded_generator_and_draws_nothing_for_zero():
    a, b = _locked(), _locked()
    inject_prior(a, 0.3, np.array([1]), np.random.default_rng(7))
    inject_prior(b, 0.3, np.array([1]), np.random.default_rng(7))
    assert np.array_equal(a.particles, b.particles)
    c, rng = _locked(), np.random.default_rng(7)
    state = rng.bit_generator.state
    assert inject_prior(c, 0.0, np.array([1]), rng) == 0
    assert np.array_equal(c.particles, _locked().particles) and rng.bit_generator.state == state


def test_regularising_keeps_the_posterior_spread_where_fixed_jitter_loses_it():
    """A property the observations do not concern (here dimension 1): twenty sharp updates
    of dimension 0, each followed by resampling when the ESS falls below N/2, 16 particles,
    eight seeds. The fixed jitter of a tenth of the std on extra copies leaves a sliver of
    dimension 1's prior (median std 0.024 against the prior's 0.29); the Musso kernel on every
    particle keeps most of it (0.25)."""
    def run(kernel: str, seed: int) -> float:
        rng = np.random.default_rng(seed)
        b = Belief.from_prior(16, [0.0, 0.0], [1.0, 1.0], rng)
        for _ in range(20):
            b.update(-0.5 * ((b.particles[:, 0] - 0.4) / 0.05) ** 2)
            if b.ess() < 8:
                if kernel == "rpf":
                    std = b.std()
                    b.resample_to(16, rng, jitter=0.0, jitter_floor=0.0)
                    regularise(b, std, rpf_bandwidth(16, 2), 0.0, rng)
                else:
                    b.resample(rng, jitter=0.1, jitter_floor=0.0)
        return float(b.std()[1])

    prior_std = 1 / np.sqrt(12)
    assert np.median([run("jitter", s) for s in range(8)]) < 0.15 * prior_std
    assert np.median([run("rpf", s) for s in range(8)]) > 0.6 * prior_std


def test_regularise_moves_every_particle_within_the_bounds():
    b = Belief.from_prior(50, [0.03], [0.06], np.random.default_rng(0))
    before = b.particles.copy()
    regularise(b, b.std(), 0.6, 0.02, np.random.default_rng(1))
    assert np.all(b.particles != before)
    assert np.all((b.particles >= 0.03) & (b.particles <= 0.06))
