"""The measurement likelihood of a particle's prediction, robust to what no particle explains.

A weighed channel c (finger opening, held weight, ...) of an observation y is scored per
particle i as a mixture, as laser beam models score a range reading (Thrun, Burgard and Fox,
Probabilistic Robotics, 6.3):

    p(y_c | L_i) = (1 - eps) N(y_c; f_c(L_i), sigma_c) + eps / W_c

The Gaussian is the sensor (and the model error, ``coordinator.particle_filter.model_error``) around the
particle's prediction; the flat floor eps / W_c, over a width W_c of ``OUTLIER_WIDTH_SIGMAS``
sensor sigmas, is what the particle worlds do not model (a cube that fell off the pile, a
tilted block). A particle that predicts y_c within ~3.4 sigma keeps the Gaussian's full
information; beyond that every particle scores the floor alike, so an observation that
every hypothesis explains equally badly leaves the weights (almost) where they were,
instead of dragging the belief toward whichever hypothesis is least wrong. eps = 0 is the
plain Gaussian (what the loop weighed before issue 24).

With ``ess_keep`` > 0 (issue 24; off by default since issue 37) an update may at most
cut the effective sample size to that share of what it was (``ess_temper``): a sharper one
has its log-likelihood scaled by the largest alpha <= 1 that keeps it. That is a *power
likelihood*, not SMC tempering: adaptive tempering (Jasra, Stephens, Doucet and Tsagaris
2011) takes the rest of the likelihood in later steps with moves between, and this throws
it away for good. It kept a failure at one grasp mode from ever resampling (the seed-91
grasp loop of issue 37), so the default is now the whole likelihood, with the kernel and
the resample-move (``coordinator.particle_filter.resample_move``) keeping the particle set alive.

Each update's information is its Kullback-Leibler divergence from the weights before
(``update_information``); the session counts updates above ``INFORMATIVE_NATS`` as
informative. ``normalised_evidence`` is how well the belief as a whole predicted an
observation (1: every particle exactly), what the lock-in monitor
(``coordinator.particle_filter.rejuvenation``) averages with ``recovery="mh_move"`` (issue 37).

**Readings of a world whose outcome was wrong** (``readings_given_outcome``). An
observation is an outcome and the readings that follow from it, y = (o, m), and a world
predicts both: o_i = f(L_i), m_i = g(L_i). The symbolic match says reality departs from a
right world's outcome with probability eps (``error_rate``). A world whose outcome matched
scores the readings against its own prediction, p(m | L_i) as above. A world whose outcome
did not match predicted readings of the other regime (fingers closed on nothing, opening
0, where the real grasp held and read 60 mm); scored against them ("own") the departure
was charged a second time, eps x floor / peak, about x7000 for the container's opening
where the declared error rate says x19 (docs/LOOP.md, "Readings of a world whose outcome
was wrong"). Under a departure the world says nothing about the readings, so they are
scored by the density the mixture above already gives what the worlds do not model, flat
over each channel's width W_c (``departure_log_likelihood``), not discounted by eps a
second time: p(y | L_i) = eps prod_c 1 / W_c. It is a proper density, a function of the
observation alone (no other row, no weight), so a Metropolis-Hastings move's target stays
a fixed function of L; and a matched world within 3.4 sigma, where the floor meets the
Gaussian, still outscores every departed one. "profile" (an exact prediction's score, the
most a readings' term can give) charged the departure eps alone, but rated a departed
world above every matched one 2.4 sigma off: on a sharp channel (the slide's puck) that is
most of the matched worlds, and the belief ran to the wrong ones.
"""
from __future__ import annotations

import math

import numpy as np

from .belief import observed_and_predicted

__all__ = ["INFORMATIVE_NATS", "OUTLIER_WIDTH_SIGMAS", "robust_log_likelihood",
           "perfect_log_likelihood", "departure_log_likelihood", "matched", "readings_given_outcome",
           "update_information", "normalised_evidence", "ess_temper"]

_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)

# The outlier floor's width in sensor sigmas: 50 x 2 mm = 100 mm, a finger opening's whole
# range (0 to 90 mm). With eps = 0.05 the floor equals the Gaussian at 3.44 sigma, whatever
# the channel (both scale with sigma), so "explains it" means the same on every channel.
OUTLIER_WIDTH_SIGMAS = 50.0

# An update that moves the weights by less than this (KL divergence, nats) is counted as
# uninformative. A particle at 5 sigma against one at 10 sigma differs by 1.5e-3 nats under
# the mixture; one informative opening on a converged belief by ~0.01-0.1.
INFORMATIVE_NATS = 1e-3


def _measured(observed, predicted, sigma, width) -> tuple[np.ndarray, ...]:
    """The measured columns (observed not NaN) of every argument, checked."""
    obs, pred = observed_and_predicted(observed, predicted)
    sig = np.broadcast_to(np.asarray(sigma, dtype=np.float64), obs.shape)
    wid = np.broadcast_to(np.asarray(width, dtype=np.float64), obs.shape)
    if np.any(~(sig > 0)) or np.any(~(wid > 0)):
        raise ValueError("sigma/width: must be positive")
    used = ~np.isnan(obs)
    p = pred[:, used]
    if np.any(np.isnan(p)):
        raise ValueError("predicted: NaN on a measured component")
    return obs[used], p, sig[used], wid[used]


def _channel_terms(z: np.ndarray, sigma: np.ndarray, width: np.ndarray, eps: float) -> np.ndarray:
    """log((1 - eps) N(z sigma; 0, sigma) + eps / width) per entry, without underflow."""
    gauss = -0.5 * z * z - np.log(sigma) - _LOG_SQRT_2PI
    if eps <= 0.0:
        return gauss
    return np.logaddexp(math.log1p(-eps) + gauss, math.log(eps) - np.log(width))


def _robust_terms(observed, predicted, sigma, eps: float, width) -> tuple[np.ndarray, np.ndarray]:
    """The mixture's log term per particle and measured channel (N, K), and each measured
    channel's outlier width (K,); `width` None: ``OUTLIER_WIDTH_SIGMAS`` x sigma."""
    wid = OUTLIER_WIDTH_SIGMAS * np.asarray(sigma, dtype=np.float64) if width is None else width
    obs, pred, sig, wid = _measured(observed, predicted, sigma, wid)
    return _channel_terms((pred - obs) / sig, sig, wid, eps), wid


def robust_log_likelihood(observed, predicted, sigma, eps: float = 0.05,
                          width=None) -> np.ndarray:
    """Sum over measured channels of log((1 - eps) N(y; f_i, sigma) + eps / W) per particle.

    ``observed`` (M,), NaN where not measured; ``predicted`` (N, M); ``sigma`` a scalar or
    (M,); ``width`` (default ``OUTLIER_WIDTH_SIGMAS * sigma``) the outlier floor's width.
    eps = 0 gives ``belief.gaussian_log_likelihood`` exactly.

    A reading no particle explains (every prediction 10+ sigma off) changes nothing:

    >>> ll = robust_log_likelihood([0.0], [[0.040], [0.050]], sigma=0.002)
    >>> round(float(ll[1] - ll[0]), 12)
    0.0

    one that some particles explain keeps the Gaussian's information (0.5 against 1.5
    sigma: the Gaussian's 1.0 nat), and a particle 4.5 sigma off counts as an outlier
    (5.8 nats below one at 0.5 sigma, where the Gaussian alone would say 10.0):

    >>> ll = robust_log_likelihood([0.041], [[0.040], [0.044], [0.050]], sigma=0.002)
    >>> [round(float(ll[0] - x), 2) for x in ll[1:]]
    [0.99, 5.8]
    """
    if not 0.0 <= eps < 1.0:
        raise ValueError(f"eps: must be in [0, 1), got {eps}")
    terms, _ = _robust_terms(observed, predicted, sigma, eps, width)
    return np.sum(terms, axis=1)


def perfect_log_likelihood(observed, sigma, eps: float = 0.05, width=None) -> float:
    """The log-likelihood of a particle that predicted every measured channel exactly."""
    obs = np.asarray(observed, dtype=np.float64).reshape(-1)
    return float(robust_log_likelihood(obs, np.where(np.isnan(obs), 0.0, obs)[None, :],
                                       sigma, eps, width)[0])


def departure_log_likelihood(observed, predicted, sigma, eps: float = 0.05,
                             width=None) -> np.ndarray:
    """Per row, the readings' log-density under a departure from its world's outcome
    (module docstring): each measured channel scores the better of its own prediction's
    term and the flat 1 / W_c, sum_c max(log p_c(y_c | L_i), -log W_c). Arguments as
    ``robust_log_likelihood``'s; eps = 0: the plain Gaussian's terms.

    A departed world whose opening read 0 where reality read 60 mm scores -log W there
    (not the mixture's eps / W), and keeps the terms of the channels it got right:

    >>> ll = departure_log_likelihood([0.060, 0.10], [[0.0, 0.10]], 0.002)
    >>> round(float(ll[0] - robust_log_likelihood([0.10], [[0.10]], 0.002)[0]), 4)  # -log 0.1 m
    2.3026
    """
    terms, wid = _robust_terms(observed, predicted, sigma, eps, width)
    return np.sum(np.maximum(terms, -np.log(wid)), axis=1)


def matched(symbolic_ll, error_rate: float) -> np.ndarray:
    """Per row, whether its world predicted the observed symbolic outcome (its symbolic
    log-likelihood is log(1 - `error_rate`), not log `error_rate`)."""
    return np.asarray(symbolic_ll, dtype=np.float64) >= math.log1p(-error_rate) - 1e-12


def readings_given_outcome(agreed, readings_ll, departed: float) -> np.ndarray:
    """The readings' log-likelihood per row given its world's outcome (module docstring): a
    row whose world `agreed` with the observed outcome (``matched``) keeps its own
    `readings_ll`; one that did not scores `departed` (``departure_log_likelihood``, or
    an exact prediction's for the "profile" rule).

    >>> readings_given_outcome(np.array([True, False]), np.array([4.0, -0.7]), 5.3).tolist()
    [4.0, 5.3]
    """
    return np.where(np.asarray(agreed, dtype=bool), np.asarray(readings_ll, dtype=np.float64), departed)


def update_information(log_w_before: np.ndarray, log_w_after: np.ndarray) -> float:
    """KL(after || before) of two normalised log-weight vectors, in nats (>= 0).

    >>> before = np.log([0.5, 0.5])
    >>> update_information(before, before), round(update_information(before, np.log([0.9, 0.1])), 3)
    (0.0, 0.368)
    """
    a = np.asarray(log_w_after, dtype=np.float64)
    b = np.asarray(log_w_before, dtype=np.float64)
    live = a > -math.inf
    kl = float(np.sum(np.exp(a[live]) * (a[live] - b[live])))
    return max(kl, 0.0)


def normalised_evidence(log_w_before: np.ndarray, log_lik: np.ndarray, perfect: float) -> float:
    """sum_i w_i p_i / p_perfect, in [0, 1] (up to rounding): how well the belief as a whole
    predicted the observation, where `perfect` is the log-likelihood of an exact prediction.

    >>> round(normalised_evidence(np.log([0.5, 0.5]), np.log([0.95, 0.05]), math.log(0.95)), 6)
    0.526316
    """
    w = np.asarray(log_w_before, dtype=np.float64)
    ll = np.asarray(log_lik, dtype=np.float64)
    terms = w + ll - perfect
    m = float(np.max(terms))
    if m == -math.inf:
        return 0.0
    return min(math.exp(m) * float(np.sum(np.exp(terms - m))), 1.0)


def _ess(log_w: np.ndarray) -> float:
    w = np.exp(log_w - np.max(log_w))
    w = w / w.sum()
    return float(1.0 / np.dot(w, w))


def ess_temper(log_w: np.ndarray, log_lik: np.ndarray, keep: float) -> float:
    """The largest alpha in [0, 1] for which weights ``log_w + alpha log_lik`` keep an ESS of
    at least `keep` x the ESS of `log_w` (1: the whole update keeps it, or keep is 0).

    >>> log_w = np.full(4, -math.log(4))
    >>> ess_temper(log_w, np.array([0.0, 0.0, -1.0, -1.0]), 0.5)
    1.0
    >>> round(ess_temper(log_w, np.array([0.0, -9.0, -9.0, -9.0]), 0.5), 3)   # 4 -> 2 at most
    0.207
    """
    if keep <= 0.0:
        return 1.0
    lw = np.asarray(log_w, dtype=np.float64)
    ll = np.asarray(log_lik, dtype=np.float64)
    live = lw > -math.inf
    if not np.all(np.isfinite(ll[live])):
        return 1.0           # a zero likelihood: tempering cannot soften it, Belief.update handles it
    target = keep * _ess(lw)
    if _ess(lw + ll) >= target:
        return 1.0
    lo, hi = 0.0, 1.0        # ESS falls as alpha grows (the weights sharpen)
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        if _ess(lw + mid * ll) >= target:
            lo = mid
        else:
            hi = mid
    return lo
