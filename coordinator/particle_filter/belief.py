"""Belief over the objects' unknown continuous properties L: a weighted particle filter.

(Over ~400 lines because it is one concept, the filter with the likelihoods and the mode
read-out that act on its particles, and a third of it is docstrings and runnable examples.)

Each row of ``particles`` is one hypothesis L_i (for the container domain: block side
lengths in metres). Weights live in log space so that long runs of small likelihoods never
underflow. Pure numpy + stdlib; every random draw comes from the generator passed in.

Choices this module makes (and the rest of the loop can rely on):

* **Degenerate updates.** If a likelihood update gives every particle probability zero
  (all ``-inf`` in log space), the weights are left as they were, ``degenerate_updates``
  is incremented and ``last_update_degenerate`` is set. Nothing becomes NaN; the caller
  can log the flag (it means the observation model's error rate is too small, or the
  real world did something no particle can explain).
* **Resampling** is systematic (one uniform draw), triggered when ESS < threshold * N.
  Rows of surviving particles stay in place, bit-identical; the extra copies of a
  particle go to the rows of particles that died. So a shard holding one world per row
  only rebuilds the worlds of rows that changed.
* **Jitter** is applied to the extra copies only (the first copy of each survivor is kept
  exactly, so no information is thrown away and duplicates still become distinct). Its
  per-dimension std is ``max(jitter * posterior_std_d, jitter_floor * (high_d - low_d))``,
  posterior std being the weighted std before resampling. The default ``jitter = 0.1``
  inflates the posterior variance by about 1 %, negligible; the floor keeps copies distinct
  when the posterior has collapsed onto one particle. Jittered values are reflected at the
  prior bounds (a triangle wave, so any magnitude lands inside) and then clipped against
  rounding, so a particle never leaves [low, high]. (The session's filter resamples with the
  Musso kernel on every particle instead, by default: ``coordinator.particle_filter.rejuvenation``.)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

__all__ = [
    "Belief",
    "symbolic_log_likelihood",
    "gaussian_log_likelihood",
    "systematic_resample",
    "reflect_into",
    "logsumexp",
]

_LOG_2PI = math.log(2.0 * math.pi)


def logsumexp(a: np.ndarray) -> float:
    """log(sum(exp(a))) without overflow; -inf when every entry is -inf.

    >>> round(logsumexp(np.log([1.0, 3.0])), 6)       # log 4
    1.386294
    >>> logsumexp(np.array([-np.inf, -np.inf]))
    -inf
    """
    a = np.asarray(a, dtype=np.float64)
    m = float(np.max(a)) if a.size else -math.inf
    if m == -math.inf:
        return -math.inf
    return m + math.log(float(np.sum(np.exp(a - m))))


def _normalised(log_w: np.ndarray) -> np.ndarray:
    """Shift log weights so that logsumexp == 0 (caller guarantees one finite entry)."""
    return log_w - logsumexp(log_w)


def systematic_resample(weights: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Ancestor indices (n,), sorted, by systematic resampling with one uniform draw
    (n defaults to the number of weights).

    Particle i is drawn floor(n w_i) or ceil(n w_i) times: the n points u0 + k/n hit an
    interval of length w_i of the cumulative sum that many times.

    >>> systematic_resample(np.array([0.1, 0.6, 0.3]), np.random.default_rng(0)).tolist()
    [1, 1, 2]
    """
    w = np.asarray(weights, dtype=np.float64)
    n = w.shape[0] if n is None else int(n)
    cum = np.cumsum(w / w.sum())
    cum[-1] = 1.0  # rounding in cumsum must not leave the last point without a bin
    positions = (rng.random() + np.arange(n)) / n
    return np.searchsorted(cum, positions, side="right").astype(np.int64)


def reflect_into(x: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Fold values into [low, high] by mirror reflection at the bounds (any distance)."""
    width = high - low
    y = np.mod(x - low, 2.0 * width)
    y = np.where(y > width, 2.0 * width - y, y)
    return np.clip(low + y, low, high)


@dataclass(eq=False)  # arrays inside: element-wise == would be ambiguous
class Belief:
    """N weighted particles over D continuous properties with a uniform prior on [low, high].

    A filter step: draw from the prior, weigh by a likelihood, resample when the effective
    sample size falls below half (every draw comes from the generator passed in):

    >>> rng = np.random.default_rng(0)
    >>> b = Belief.from_prior(1000, low=[0.030], high=[0.060], rng=rng)  # a size in metres
    >>> b.n, b.dim, round(b.ess())
    (1000, 1, 1000)
    >>> b.update(gaussian_log_likelihood([0.050], b.particles, sigma=0.002))
    >>> b.mean().round(3).tolist(), b.std().round(3).tolist(), round(b.ess())
    ([0.05], [0.002], 254)
    >>> b.maybe_resample(rng), round(b.ess()), b.mean().round(3).tolist()
    (True, 1000, [0.05])

    A checkpoint round-trips bit for bit:

    >>> c = Belief.from_dict(b.to_dict())
    >>> bool(np.array_equal(c.particles, b.particles) and np.array_equal(c.log_weights, b.log_weights))
    True
    """

    particles: np.ndarray  # (N, D) float64
    log_weights: np.ndarray  # (N,) normalised: logsumexp == 0
    low: np.ndarray  # (D,)
    high: np.ndarray  # (D,)
    degenerate_updates: int = 0  # how many updates were all -inf and got ignored
    last_update_degenerate: bool = False

    def __post_init__(self) -> None:
        self.particles = np.array(self.particles, dtype=np.float64, ndmin=2)
        self.log_weights = np.array(self.log_weights, dtype=np.float64).reshape(-1)
        self.low = np.array(self.low, dtype=np.float64).reshape(-1)
        self.high = np.array(self.high, dtype=np.float64).reshape(-1)
        n, d = self.particles.shape
        if n < 1:
            raise ValueError("particles: need at least one particle")
        if self.log_weights.shape != (n,):
            raise ValueError(f"log_weights: shape {self.log_weights.shape}, expected ({n},)")
        if self.low.shape != (d,) or self.high.shape != (d,):
            raise ValueError(f"low/high: shapes {self.low.shape}/{self.high.shape}, expected ({d},)")
        if not np.all(self.low < self.high):
            raise ValueError("low/high: every low must be below its high")
        if np.any(np.isnan(self.log_weights)) or np.any(self.log_weights == math.inf):
            raise ValueError("log_weights: NaN or +inf")
        if np.all(self.log_weights == -math.inf):
            raise ValueError("log_weights: every weight is zero")

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_prior(
        cls, n: int, low: Any, high: Any, rng: np.random.Generator
    ) -> "Belief":
        """N particles drawn uniformly on [low, high) per dimension, uniform weights."""
        if int(n) < 1:
            raise ValueError(f"n: need at least one particle, got {n}")
        low_a = np.array(low, dtype=np.float64).reshape(-1)
        high_a = np.array(high, dtype=np.float64).reshape(-1)
        if low_a.shape != high_a.shape:
            raise ValueError(f"low/high: shapes differ ({low_a.shape} vs {high_a.shape})")
        if not np.all(low_a < high_a):
            raise ValueError("low/high: every low must be below its high")
        n = int(n)
        particles = low_a + (high_a - low_a) * rng.random((n, low_a.shape[0]))
        return cls(particles, np.full(n, -math.log(n)), low_a, high_a)

    # ----------------------------------------------------------------- read-outs
    @property
    def n(self) -> int:
        return int(self.particles.shape[0])

    @property
    def dim(self) -> int:
        return int(self.particles.shape[1])

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights (N,), summing to 1."""
        w = np.exp(self.log_weights)
        return w / w.sum()

    def ess(self) -> float:
        """Effective sample size 1 / sum w_i^2, in [1, N]."""
        w = self.weights
        return float(1.0 / np.dot(w, w))

    def mean(self) -> np.ndarray:
        """Weighted mean of the particles (D,)."""
        return self.weights @ self.particles

    def std(self) -> np.ndarray:
        """Weighted standard deviation of the particles (D,)."""
        w = self.weights
        dev = self.particles - w @ self.particles
        return np.sqrt(np.maximum(w @ (dev * dev), 0.0))

    def weighted_mean(
        self, values: np.ndarray, angular: Sequence[int] | None = None
    ) -> np.ndarray:
        """Weighted mean over particles of per-particle values (N,) or (N, P).

        Columns in ``angular`` are averaged as angles: atan2 of the weighted sin and cos,
        so yaws near +pi and -pi average to about pi, not 0. ``None`` (default) means
        column 3 (yaw of x, y, z, yaw, ...) when there is one, else none; pass ``()`` for
        a purely linear mean.
        """
        v = np.asarray(values, dtype=np.float64)
        if v.ndim not in (1, 2) or v.shape[0] != self.n:
            raise ValueError(f"values: shape {v.shape}, expected ({self.n},) or ({self.n}, P)")
        squeeze = v.ndim == 1
        v2 = v.reshape(self.n, -1)
        p = v2.shape[1]
        if angular is None:
            cols = [3] if p > 3 else []
        else:
            cols = [int(c) for c in angular]
            bad = [c for c in cols if not -p <= c < p]
            if bad:
                raise ValueError(f"angular: columns {bad} out of range for {p} columns")
        w = self.weights
        out = w @ v2
        for c in cols:
            out[c] = math.atan2(float(w @ np.sin(v2[:, c])), float(w @ np.cos(v2[:, c])))
        return out[0:1].reshape(()) if squeeze else out

    def summary(self, bins: int = 20) -> dict:
        """Plain JSON-able posterior summary: mean, std, ess, n and a weighted histogram
        per dimension over [low, high] (``weights`` per bin sum to 1)."""
        w = self.weights
        hist = []
        for d in range(self.dim):
            h, edges = np.histogram(
                self.particles[:, d], bins=int(bins), range=(self.low[d], self.high[d]), weights=w
            )
            hist.append({"edges": edges.tolist(), "weights": h.tolist()})
        joint = None
        if self.dim == 2:      # two properties (size, density): their joint, not just margins
            h2, xe, ye = np.histogram2d(self.particles[:, 0], self.particles[:, 1], bins=int(bins),
                                        range=[(self.low[0], self.high[0]), (self.low[1], self.high[1])],
                                        weights=w)
            joint = {"x_edges": xe.tolist(), "y_edges": ye.tolist(), "weights": h2.tolist()}
        return {
            "n": self.n,
            "ess": self.ess(),
            "mean": self.mean().tolist(),
            "std": self.std().tolist(),
            "low": self.low.tolist(),
            "high": self.high.tolist(),
            "histogram": hist,
            "joint": joint,
            "degenerate_updates": int(self.degenerate_updates),
        }

    # ----------------------------------------------------------------- filtering
    def update(self, log_likelihood: np.ndarray) -> None:
        """Bayes step w_i *= p_i, in log space, then renormalise.

        If every particle gets probability zero the update is ignored (weights unchanged)
        and flagged in ``last_update_degenerate`` / ``degenerate_updates``.
        """
        ll = np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        if ll.shape != (self.n,):
            raise ValueError(f"log_likelihood: shape {ll.shape}, expected ({self.n},)")
        if np.any(np.isnan(ll)) or np.any(ll == math.inf):
            raise ValueError("log_likelihood: NaN or +inf entries")
        new = self.log_weights + ll
        if np.all(new == -math.inf):
            self.degenerate_updates += 1
            self.last_update_degenerate = True
            return
        self.last_update_degenerate = False
        self.log_weights = _normalised(new)

    def maybe_resample(
        self,
        rng: np.random.Generator,
        *,
        threshold: float = 0.5,
        jitter: float = 0.1,
        jitter_floor: float = 0.005,
    ) -> bool:
        """Resample (systematic, then jitter the copies) when ESS < threshold * N.

        Returns whether it resampled; draws nothing from ``rng`` when it does not.
        """
        if self.ess() >= threshold * self.n:
            return False
        self.resample(rng, jitter=jitter, jitter_floor=jitter_floor)
        return True

    def resample(
        self, rng: np.random.Generator, *, jitter: float = 0.1, jitter_floor: float = 0.005
    ) -> None:
        """Systematic resampling now; weights become uniform. See the module docstring."""
        if jitter < 0 or jitter_floor < 0:
            raise ValueError("jitter/jitter_floor: must be >= 0")
        sigma = np.maximum(jitter * self.std(), jitter_floor * (self.high - self.low))
        ancestors = systematic_resample(self.weights, rng)
        counts = np.bincount(ancestors, minlength=self.n)
        # Survivors keep their row; each extra copy of ancestor i fills a dead row, in order.
        extra = np.repeat(np.arange(self.n), np.maximum(counts - 1, 0))
        dead = np.flatnonzero(counts == 0)
        new = self.particles.copy()
        if dead.size:
            copies = self.particles[extra]
            if np.any(sigma > 0):
                copies = copies + sigma * rng.standard_normal(copies.shape)
                copies = reflect_into(copies, self.low, self.high)
            new[dead] = copies
        self.particles = new
        self.log_weights = np.full(self.n, -math.log(self.n))

    def resample_to(self, n: int, rng: np.random.Generator, *, jitter: float = 0.1,
                    jitter_floor: float = 0.005) -> None:
        """Systematic resampling to `n` particles (the adaptive budget's step); every copy
        after an ancestor's first is jittered as in `resample`; weights become uniform."""
        n = int(n)
        if n < 1:
            raise ValueError(f"n: need at least one particle, got {n}")
        sigma = np.maximum(jitter * self.std(), jitter_floor * (self.high - self.low))
        ancestors = systematic_resample(self.weights, rng, n)
        first = np.ones(n, dtype=bool)
        first[1:] = ancestors[1:] != ancestors[:-1]          # sorted: repeats are copies
        new = self.particles[ancestors].copy()
        copies = ~first
        if copies.any() and np.any(sigma > 0):
            new[copies] = reflect_into(new[copies] + sigma * rng.standard_normal((int(copies.sum()), self.dim)),
                                        self.low, self.high)
        self.particles = new
        self.log_weights = np.full(n, -math.log(n))

    # ----------------------------------------------------------------- checkpoints
    def to_dict(self) -> dict:
        """Exact, JSON-able state. Zero weights (log -inf) are written as None, since
        strict JSON has no infinities; Python floats round-trip bit for bit."""
        return {
            "particles": self.particles.tolist(),
            "log_weights": [None if x == -math.inf else x for x in self.log_weights.tolist()],
            "low": self.low.tolist(),
            "high": self.high.tolist(),
            "degenerate_updates": int(self.degenerate_updates),
            "last_update_degenerate": bool(self.last_update_degenerate),
        }

    @classmethod
    def from_dict(cls, data: dict) -> "Belief":
        log_w = [-math.inf if x is None else float(x) for x in data["log_weights"]]
        particles = np.array(data["particles"], dtype=np.float64)
        if particles.ndim == 1:  # tolerate a flat list for D == 1
            particles = particles.reshape(len(log_w), -1)
        return cls(
            particles=particles,
            log_weights=np.array(log_w, dtype=np.float64),
            low=np.array(data["low"], dtype=np.float64),
            high=np.array(data["high"], dtype=np.float64),
            degenerate_updates=int(data.get("degenerate_updates", 0)),
            last_update_degenerate=bool(data.get("last_update_degenerate", False)),
        )


# --------------------------------------------------------------------- likelihoods
def symbolic_log_likelihood(
    observed: frozenset[str], predicted: Sequence[frozenset[str]], error_rate: float = 0.05
) -> np.ndarray:
    """Match model: log(1 - e) where a particle predicted exactly the observed state,
    log(e) otherwise. A positive e keeps a particle that disagrees once alive (Y^-1 and
    the real world are noisy); e = 0 makes a mismatch fatal (-inf).

    >>> symbolic_log_likelihood({"on(b1,c)"}, [{"on(b1,c)"}, set()], error_rate=0.05).round(3).tolist()
    [-0.051, -2.996]
    """
    if not 0.0 <= error_rate < 1.0:
        raise ValueError(f"error_rate: must be in [0, 1), got {error_rate}")
    observed = frozenset(observed)
    match = np.fromiter((frozenset(s) == observed for s in predicted), dtype=bool,
                        count=len(predicted))
    miss = math.log(error_rate) if error_rate > 0 else -math.inf
    return np.where(match, math.log1p(-error_rate), miss)


def observed_and_predicted(observed, predicted) -> tuple[np.ndarray, np.ndarray]:
    """`observed` as (M,) and `predicted` as (N, M) float arrays; ValueError on a shape
    that does not pair them."""
    obs = np.asarray(observed, dtype=np.float64).reshape(-1)
    pred = np.asarray(predicted, dtype=np.float64)
    if pred.ndim == 1:
        pred = pred.reshape(-1, obs.shape[0]) if obs.shape[0] else pred.reshape(-1, 0)
    if pred.ndim != 2 or pred.shape[1] != obs.shape[0]:
        raise ValueError(f"predicted: shape {pred.shape}, expected (N, {obs.shape[0]})")
    return obs, pred


def gaussian_log_likelihood(
    observed: np.ndarray, predicted: np.ndarray, sigma: float | np.ndarray
) -> np.ndarray:
    """Sum over measured components of the log density N(observed_m; predicted_im, sigma_m).

    ``observed`` (M,), ``predicted`` (N, M), ``sigma`` a scalar or (M,). Components where
    ``observed`` is NaN (not measured) are ignored; a NaN in ``predicted`` on a measured
    component is an error upstream and raises.

    >>> gaussian_log_likelihood([0.0, np.nan], [[0.0, 5.0], [1.0, 0.0]], sigma=1.0).round(3).tolist()
    [-0.919, -1.419]
    """
    obs, pred = observed_and_predicted(observed, predicted)
    sig = np.broadcast_to(np.asarray(sigma, dtype=np.float64), obs.shape)
    if np.any(~(sig > 0)):
        raise ValueError("sigma: must be positive")
    used = ~np.isnan(obs)
    if not np.any(used):
        return np.zeros(pred.shape[0])
    p, o, s = pred[:, used], obs[used], sig[used]
    if np.any(np.isnan(p)):
        raise ValueError("predicted: NaN on a measured component")
    z = (p - o) / s
    return -0.5 * np.sum(z * z, axis=1) - float(np.sum(np.log(s))) - 0.5 * _LOG_2PI * o.shape[0]


def mode_mask(particles: np.ndarray, weights: np.ndarray, bandwidth: float,
              scale: np.ndarray | None = None) -> np.ndarray:
    """Particles in the heaviest mode: within `bandwidth` of the particle of highest
    weighted kernel density (Gaussian kernel of that bandwidth, Euclidean in L).

    The real pose is averaged over these only: the weighted mean of a bimodal belief's
    poses (say a grasp for a small block and one for a large block) is neither grasp.
    For a unimodal belief narrower than the bandwidth it keeps every particle. `scale`
    (D,) divides each dimension first, so that properties in different units compare.

    >>> sizes = np.array([[0.030], [0.031], [0.050], [0.051], [0.052]])    # two modes
    >>> mode_mask(sizes, np.full(5, 0.2), bandwidth=0.002).tolist()
    [False, False, True, True, True]
    """
    p = np.asarray(particles, dtype=np.float64).reshape(len(particles), -1)
    if scale is not None:   # each dimension in its own units (e.g. m and kg/m^3)
        p = p / np.asarray(scale, dtype=np.float64).reshape(1, -1)
    # Exact shortcut: when the particles' bounding box has a diagonal within 2 bandwidths,
    # every particle is within 2 bandwidths of any one, so of the densest: all are kept.
    # A converged belief (0.3 mm wide against a 3 mm bandwidth) never pays the N^2 below.
    if float(((p.max(axis=0) - p.min(axis=0)) ** 2).sum()) <= (2.0 * bandwidth) ** 2:
        return np.ones(len(p), dtype=bool)
    w = np.asarray(weights, dtype=np.float64)
    if len(p) > MODE_EXACT_MAX:
        best = _densest_binned(p, w, bandwidth)
        if best is None:       # a grid too large for the spread: weight-drawn candidates
            best = _densest_candidate(p, w, bandwidth, mode_candidates(w, MODE_EXACT_MAX))
        return ((p - p[best]) ** 2).sum(-1) <= (2.0 * bandwidth) ** 2
    d2 = ((p[:, None, :] - p[None, :, :]) ** 2).sum(-1)
    density = (np.exp(-0.5 * d2 / bandwidth ** 2) * w[None, :]).sum(1)
    best = int(np.argmax(density))
    return d2[best] <= (2.0 * bandwidth) ** 2


def heaviest_class(classes: np.ndarray, weights: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """`keep` narrowed to the class holding most of the kept particles' weight (ties: the
    smallest label); `keep` itself when the kept particles share one class.

    A class is a discrete choice Y made for a particle (the container's tray layout, one
    column or two): particles close in L can still get poses far apart across such a
    switch, and their weighted mean is neither pose.

    >>> heaviest_class(np.array([1, 1, 0, 0]), np.array([0.1, 0.1, 0.3, 0.5]),
    ...                np.array([True, True, True, False])).tolist()
    [False, False, True, False]
    """
    classes = np.asarray(classes)
    labels = np.unique(classes[keep])
    if len(labels) < 2:
        return keep
    w = np.asarray(weights, dtype=np.float64)
    mass = [float(w[keep & (classes == label)].sum()) for label in labels]
    return keep & (classes == labels[int(np.argmax(mass))])


# Up to this many particles the density is evaluated at every particle (N^2 kernel terms:
# 28 us per particle per action at N = 1000, 190 at 5000, measured); above it by binned
# kernel density estimation (``_densest_binned``, linear in N), or, where L's spread would
# need too large a grid, at this many candidates drawn by weight (M x N terms). Every
# committed figure used N <= 200, so none of them changes.
MODE_EXACT_MAX = 512

# Binned KDE (Wand 1994, "Fast computation of multivariate kernel estimators"): the grid
# spacing in bandwidths, and the kernel's reach in bandwidths. With linear binning the
# density's relative error is O((spacing / bandwidth)^2): ~1 % at 1/4, measured against the
# exact sums in tests/coordinator/test_pose_mode.py; the Gaussian beyond 4 bandwidths is
# below 3.4e-4 of its peak.
BIN_SPACING = 0.25
BIN_REACH = 4.0
# The most grid cells the binned path builds: 4 per particle (at least 4096), so that its
# cost (33 kernel taps per cell per dimension) stays linear in N; a wider spread of L in
# bandwidths (many dimensions, a prior-wide belief of a long L) goes to the weight-drawn
# candidates.
BIN_CELLS_PER_PARTICLE = 4
BIN_MIN_CELLS = 4096


def mode_candidates(weights: np.ndarray, m: int) -> np.ndarray:
    """`m` particles spread over the posterior: systematic selection by weight with a fixed
    offset (no random draw), so where the posterior has mass it has candidates."""
    cum = np.cumsum(weights / weights.sum())
    cum[-1] = 1.0
    return np.unique(np.searchsorted(cum, (np.arange(m) + 0.5) / m, side="right"))


def _densest_binned(p: np.ndarray, w: np.ndarray, bandwidth: float) -> int | None:
    """The particle of highest weighted kernel density, the density from a grid: weights
    spread linearly onto a grid of ``BIN_SPACING`` bandwidths, convolved with the Gaussian
    kernel one axis at a time (it is separable), read back at every particle by multilinear
    interpolation. O(N 2^D + cells x kernel) instead of N^2; None when the grid would have
    more than ``BIN_CELLS_PER_PARTICLE`` cells a particle."""
    n, dims = p.shape
    delta = BIN_SPACING * bandwidth
    lo = p.min(axis=0)
    shape = np.floor((p.max(axis=0) - lo) / delta).astype(np.int64) + 2
    if float(np.prod(shape.astype(np.float64))) > max(BIN_MIN_CELLS, BIN_CELLS_PER_PARTICLE * n):
        return None
    u = (p - lo) / delta                               # grid coordinates
    base = np.minimum(np.floor(u).astype(np.int64), shape - 2)
    frac = u - base
    grid = np.zeros(int(np.prod(shape)))
    corners = [np.array(c) for c in np.ndindex(*(2,) * dims)]
    strides = np.array([int(np.prod(shape[k + 1:])) for k in range(dims)], dtype=np.int64)
    for c in corners:                                  # linear binning: 2^D corners
        share = np.prod(np.where(c, frac, 1.0 - frac), axis=1)
        np.add.at(grid, (base + c) @ strides, w * share)
    grid = grid.reshape(shape)
    reach = int(np.ceil(BIN_REACH / BIN_SPACING))
    kernel = np.exp(-0.5 * (np.arange(-reach, reach + 1) * BIN_SPACING) ** 2)
    for axis in range(dims):                           # separable Gaussian, zero outside
        g = np.moveaxis(grid, axis, 0)
        padded = np.concatenate([np.zeros((reach,) + g.shape[1:]), g, np.zeros((reach,) + g.shape[1:])])
        out = np.zeros_like(g)
        for j, k in enumerate(kernel):
            out += k * padded[j:j + len(g)]
        grid = np.moveaxis(out, 0, axis)
    flat = grid.ravel()
    density = np.zeros(n)
    for c in corners:
        density += np.prod(np.where(c, frac, 1.0 - frac), axis=1) * flat[(base + c) @ strides]
    return int(np.argmax(density))


def _densest_candidate(p: np.ndarray, w: np.ndarray, bandwidth: float, candidates: np.ndarray) -> int:
    """The candidate of highest weighted kernel density over all N particles (exact sums)."""
    d2 = np.zeros((len(candidates), len(p)))
    for k in range(p.shape[1]):            # one dimension at a time: M x N memory, not M x N x D
        d2 += (p[candidates, k][:, None] - p[None, :, k]) ** 2
    density = (np.exp(-0.5 * d2 / bandwidth ** 2) * w[None, :]).sum(1)
    return int(candidates[int(np.argmax(density))])
