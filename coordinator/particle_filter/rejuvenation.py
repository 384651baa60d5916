"""Keeping the particle set alive: the kernel that spreads resampled particles, and fresh
draws from the prior when no particle explains what happened (issue 24).

**Regularised resampling.** After systematic resampling every particle is moved by a
Gaussian kernel of std h x the posterior's std per property (at least the jitter floor),
h the optimal bandwidth of Musso, Oudjane and Le Gland (2001) for N particles in d
dimensions, ``h = (4 / (N (d + 2)))^(1 / (d + 4))`` (0.63 at N 16 and d 2): the resampled
set is a draw from the kernel density estimate of the posterior, not from its N points.
The fixed 0.1 of before, on the extra copies only, let a small set collapse along any
property the channels barely inform: resampling after each sharp opening keeps the
densities of two or three particles, jittered by a tenth of their spread, and the density
posterior ended at the jitter floor (54 kg/m^3; measured 57 wide with a 3.5 N sensor that
cannot tell 300 kg/m^3 apart). Every row may change, which costs nothing: a particle world
is rebuilt for every particle-action anyway.

**Lock-in.** When every particle mispredicts an outcome alike (a grasp that fails in the
real world and in no particle world), no weight changes and nothing is resampled, so a
belief stuck away from the truth stays there. Augmented MCL (Thrun, Burgard and Fox,
Probabilistic Robotics, 8.3.5) injects draws from the prior at the rate
``max(0, 1 - w_fast / w_slow)``, w_fast and w_slow short- and long-term averages of how well
the particles explain the observations. Here the averaged quantity is whether the best
particle explained the observation (its likelihood at least ``EXPLAINED`` of an exact
prediction's), w_fast is kept per block (the block an action names first) when L has one
entry per block, so only that block's properties are redrawn, and draws happen only at an
unexplained observation once the ratio is below ``REDRAW_BELOW`` (repeated surprises, not
an isolated one): an explained observation never changes the set. Every draw comes from
the generator passed in.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from .belief import Belief, reflect_into

__all__ = ["EXPLAINED", "REDRAW_BELOW", "LockInMonitor", "rpf_bandwidth", "regularise", "inject_prior", "action_blocks"]

# A best particle below this share of an exact prediction's likelihood did not explain the
# observation: a symbolic mismatch of every particle (0.05 / 0.95 = 0.053 at the default
# error rate), or a channel more than 2.15 sigma off the best particle's prediction.
EXPLAINED = 0.1

# Redraw only once w_fast / w_slow is below this: from the third unexplained observation in
# a row of one key at the default rates (then 60 % of the rows). An isolated surprise, such
# as a stack that toppled in reality and in no particle world (four in one stack-and-push
# episode, measured), is the particle worlds' gap, not a lost belief: redrawing a quarter of
# the particles at each widened the size posterior from 0.5 to 6 mm for nothing.
REDRAW_BELOW = 0.5


def rpf_bandwidth(n: int, d: int) -> float:
    """Musso-Oudjane-Le Gland kernel bandwidth for `n` particles in `d` dimensions (in units
    of the posterior std): optimal for a Gaussian posterior.

    >>> round(rpf_bandwidth(16, 1), 3), round(rpf_bandwidth(16, 2), 3), round(rpf_bandwidth(1000, 1), 3)
    (0.608, 0.63, 0.266)
    """
    if n < 1 or d < 1:
        raise ValueError("rpf_bandwidth: need n >= 1 and d >= 1")
    return float((4.0 / (n * (d + 2.0))) ** (1.0 / (d + 4.0)))


@dataclass
class LockInMonitor:
    """w_slow (all observations) and w_fast (per key) averages of "the best particle
    explained it" (1 or 0); ``observe`` gives the share of particles to redraw."""

    slow: float = 0.05                  # alpha_slow: a memory of ~20 observations
    fast: float = 0.3                   # alpha_fast: the third unexplained in a row redraws 60 %
    w_slow: float | None = None
    w_fast: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 0.0 < self.slow < self.fast <= 1.0:
            raise ValueError(f"lock-in: need 0 < slow < fast <= 1, got {self.slow}, {self.fast}")

    def observe(self, key: str, explained: bool, evidence: float | None = None) -> float:
        """Fold in one observation of `key`; the share of particles to redraw now: 0 when
        it was explained or w_fast / w_slow is still above REDRAW_BELOW, else 1 - that ratio.

        With `evidence` (issue 37) the averaged quantity is augmented MCL's own: how well
        the belief as a whole predicted the observation (``likelihood.normalised_evidence``,
        in [0, 1]), and the ratio alone decides, explained or not: a belief whose every
        particle sits 4 sigma from a run of readings scores ~0.003 each time, and fires.

        >>> m = LockInMonitor()
        >>> [round(m.observe("b1", ok), 2) for ok in (True, False, False, False, False, True, False)]
        [0.0, 0.0, 0.0, 0.6, 0.71, 0.0, 0.58]
        """
        x = (1.0 if explained else 0.0) if evidence is None else min(max(float(evidence), 0.0), 1.0)
        previous = 1.0 if self.w_slow is None else self.w_slow
        self.w_slow = previous + self.slow * (x - previous)
        fast = self.w_fast.get(key, previous)
        fast += self.fast * (x - fast)
        self.w_fast[key] = fast
        gate = explained if evidence is None else False
        if gate or self.w_slow <= 0.0 or fast >= REDRAW_BELOW * self.w_slow:
            return 0.0
        return 1.0 - fast / self.w_slow

    def to_dict(self) -> dict:
        return {"slow": self.slow, "fast": self.fast, "w_slow": self.w_slow,
                "w_fast": dict(sorted(self.w_fast.items()))}

    @classmethod
    def from_dict(cls, data: dict | None, **defaults) -> "LockInMonitor":
        """A monitor from `to_dict` (None, e.g. an old checkpoint: a fresh one)."""
        if data is None:
            return cls(**defaults)
        return cls(float(data["slow"]), float(data["fast"]),
                   None if data["w_slow"] is None else float(data["w_slow"]),
                   {str(k): float(v) for k, v in data["w_fast"].items()})


def action_blocks(action: str, block_names: list[str]) -> list[int]:
    """Indices of the blocks an action names, e.g. ``pickup(r,b3,init)`` -> [2].

    >>> action_blocks("stack(r,b3,b1)", ["b1", "b2", "b3"]), action_blocks("push(r,c,init,goal)", ["b1"])
    ([2, 0], [])
    """
    args = re.findall(r"[A-Za-z0-9_]+", action.split("(", 1)[-1])
    return [block_names.index(a) for a in args if a in block_names]


def regularise(belief: Belief, std: np.ndarray, h: float, jitter_floor: float,
               rng: np.random.Generator, mean: np.ndarray | None = None) -> None:
    """Move every particle by the kernel N(0, max(h std, jitter_floor (high - low))) per
    dimension, folded back into the prior's bounds (`std`: the posterior's, before
    resampling).

    With `mean` (the posterior's, before resampling) the kernel is Liu and West's (2001):
    each particle is first shrunk towards the mean, x -> a x + (1 - a) mean with
    a = sqrt(1 - h^2), so that the moved set keeps the posterior's mean and variance
    (a^2 var + h^2 var = var) instead of inflating the variance by (1 + h^2) at every
    resample, which over many resamples widens the posterior for nothing:

    >>> rng = np.random.default_rng(0)
    >>> b = Belief(rng.normal(0.045, 0.002, (4000, 1)), np.full(4000, -np.log(4000)), [0.03], [0.06])
    >>> s0 = float(b.std()[0]); m0 = b.mean()
    >>> regularise(b, b.std(), 0.6, 0.0, rng, mean=m0)
    >>> round(float(b.std()[0]) / s0, 2)
    1.0
    """
    sigma = np.maximum(h * np.asarray(std, dtype=np.float64), jitter_floor * (belief.high - belief.low))
    if not np.any(sigma > 0):
        return
    x = belief.particles
    if mean is not None:
        a = math.sqrt(max(1.0 - h * h, 0.0))
        x = a * x + (1.0 - a) * np.asarray(mean, dtype=np.float64).reshape(1, -1)
    moved = x + sigma * rng.standard_normal(belief.particles.shape)
    if mean is not None:
        moved = _matched(moved, np.asarray(mean, dtype=np.float64), np.asarray(std, dtype=np.float64))
    belief.particles = reflect_into(moved, belief.low, belief.high)


def _matched(x: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """`x` moved and scaled per column so that its sample mean and std are `mean` and `std`
    (a column without spread is left as it is). Resampling N equal-weight copies loses
    about 1/N of the variance each time in expectation, which at 8 particles and a resample
    per reading compounds into a posterior several times too narrow (measured: mean z^2
    79 at N = 8 after 80 openings); the kernel keeps the moments only in expectation, this
    keeps them exactly, as square-root ensemble filters do."""
    m = x.mean(axis=0)
    s = x.std(axis=0)
    scale = np.where(s > 0, std / np.where(s > 0, s, 1.0), 1.0)
    return mean + (x - m) * scale


def inject_prior(belief: Belief, share: float, dims: np.ndarray, rng: np.random.Generator) -> int:
    """Redraw `dims` of about `share` x N rows, chosen at random, from the uniform prior;
    returns how many. The caller resamples first: with weights uniform no row's weight is
    handed to a new hypothesis, and a row's other dimensions (other blocks' properties)
    keep what they learned. The count is systematic, floor(share N + u).
    """
    if share <= 0.0:
        return 0
    count = min(belief.n, int(math.floor(share * belief.n + rng.random())))
    if count == 0:
        return 0
    rows = np.sort(rng.choice(belief.n, size=count, replace=False))
    dims = np.asarray(dims, dtype=np.int64)
    low, high = belief.low[dims], belief.high[dims]
    particles = belief.particles.copy()
    particles[np.ix_(rows, dims)] = low + (high - low) * rng.random((count, dims.size))
    belief.particles = particles
    return count
