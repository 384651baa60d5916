"""Resample-move: the filter's recovery when the particles have stopped explaining what
the robot observes (issue 37).

The lock-in monitor (``coordinator.particle_filter.rejuvenation.LockInMonitor``, fed with augmented MCL's
average likelihood) says when the particle set is impoverished: a run of observations the
belief as a whole predicted badly. Redrawing rows from the prior at uniform weight (issue
24's answer) throws away what the rows had learned and hands new hypotheses a weight no
data gave them. Here every row instead takes one Metropolis-Hastings step (Gilks and
Berzuini 2001, "Following a moving target"): a proposal L' is drawn from a mixture of the
prior (an independence proposal: it can jump to a region no particle holds) and a
Gaussian random walk around the row (reflected at the prior's bounds, so symmetric), and
accepted with probability

    min(1, p(y_window | L') / p(y_window | L))

where y_window are the last ``MOVE_WINDOW`` real steps of the episode, re-simulated in
the particle worlds for both L and L' (one world per row and step, as the update itself).
The prior is uniform and the mixture proposal's density is symmetric (the uniform part is
constant, the reflected walk symmetric), so the ratio is the likelihood's alone. The
step leaves the posterior of those steps invariant: a belief stuck between two failing
grasp poses, or confidently 8 mm away from a run of finger readings, is moved to where
the recent evidence is, and a belief that is right barely moves (its proposals are
rejected or stay local). Older evidence is carried by where the rows were (the random
walk's share starts from them), not re-simulated: the window bounds the cost at
2 x N x ``MOVE_WINDOW`` particle-actions per move, and a move happens only when the
monitor fires. While the window still holds every real step since the prior (the run's
first ``MOVE_WINDOW``) the target is the exact posterior, and the chain takes the run's
``first_window_sweeps`` (default ``MAX_SWEEPS``) sweeps towards it (N x ``MOVE_WINDOW``
more particle-actions each): one
sweep moves only the rows whose one proposal lands where the evidence is, and a run of
failed first grasps that no row explains otherwise goes on (docs/LOOP.md). A proposal
is replayed step by step only while it can still be accepted (early rejection against
the likelihood's bound: the same runs, fewer particle-actions; docs/LOOP.md, "Early
rejection in the move").

``resample_move`` is Gilks and Berzuini's scheme as written, under ``move_after_resample``
(off by default): after every resample (and every step no row explained) the rows
take ``MAX_SWEEPS`` sweeps against the belief before the step, as the kernel density the
regularised filter resamples from (``KernelDensity``), times that one step's likelihood. A
reading that pins L to a hundredth of the prior leaves the weight on the one or two rows
nearest it (or, beyond the outlier floor, on none); the sweeps put rows where the reading
is instead of where the resampling happened to copy them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .belief import reflect_into
from .block_weights import unbiased_std_factor
from .rejuvenation import rpf_bandwidth

__all__ = ["MOVE_WINDOW", "PRIOR_SHARE", "MAX_SWEEPS", "RealStep", "KernelDensity", "LinearisedProposal",
           "propose", "mh_move", "resample_move"]

# Real steps re-simulated per move. The monitor fires after two or three badly predicted
# observations (REDRAW_BELOW at the default rates), so a window of 8 holds those and about
# as many again that the belief did predict, which keep a move from trading the old
# evidence for the new. The cost is linear in it (docs/LOOP.md, "Constants").
MOVE_WINDOW = 8

# The share of proposals drawn from the prior: half global (to reach a region no particle
# holds), half local (to refine where the rows are). Any share in (0, 1) leaves the target
# invariant; 1/2 is the mixture that neither starves.
PRIOR_SHARE = 0.5

# Metropolis-Hastings sweeps per resample-move (``resample_move``): a fixed number, not
# "until every row has moved" (where every row lies beyond the outlier floor the likelihood
# is flat for all of them, every proposal there is accepted, and that rule stopped after one
# sweep with nothing found). Swept on a synthetic channel 10x sharper than the particles'
# spacing: 4 sweeps bring every run within 2x the exact posterior's std, 8 to a median of
# 0.99x (docs/LOOP.md, "Resample-move after a sharp step"). A move costs (1 + MAX_SWEEPS) x
# N particle-actions where a step costs N. The first window's move (``mh_move`` while
# the window reaches back to the prior) takes as many: on three failed grasps that strand
# every row, 1 / 2 / 4 / 8 sweeps put 40 / 60 / 80 / 93 % of the rows where the exact
# posterior holds 97 % (docs/LOOP.md, "The first window's move").
MAX_SWEEPS = 8


@dataclass(frozen=True)
class RealStep:
    """One real step as the particle worlds replay it, with what the robot observed."""

    start: np.ndarray             # the observed configuration before, as an array
    action: str
    trajectory: np.ndarray
    start_time: float             # where particle worlds start (the checked transit's end)
    expected: frozenset[str]
    observed: frozenset[str]
    measurements: np.ndarray
    arm: object = None            # an arm's joints the worlds move its links along (ArmMotion), or None
    # The perceptions the update replayed the step at (perception_samples; 1: the perceived
    # start alone), so that a re-scored step is weighed as the update weighed it.
    samples: int = 1

    def replay(self, simulate, rows: np.ndarray) -> dict:
        """`simulate` (the particle worlds) run for this step with `rows` of L."""
        extra = {} if self.arm is None else {"arm": self.arm}
        if self.samples > 1:
            extra["samples"] = self.samples
        return simulate(self.start, rows, self.action, self.trajectory, self.start_time, **extra)


def propose(rows: np.ndarray, dims: np.ndarray, low: np.ndarray, high: np.ndarray,
            scale: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each row with its `dims` redrawn: from the uniform prior with probability
    PRIOR_SHARE, else a reflected Gaussian step of std `scale` (per dim)."""
    rows = np.asarray(rows, dtype=np.float64)
    dims = np.asarray(dims, dtype=np.int64)
    n, k = rows.shape[0], dims.size
    from_prior = rng.random(n) < PRIOR_SHARE
    lo, hi = low[dims], high[dims]
    walk = reflect_into(rows[:, dims] + np.asarray(scale, dtype=np.float64) * rng.standard_normal((n, k)), lo, hi)
    prior = lo + (hi - lo) * rng.random((n, k))
    out = rows.copy()
    out[:, dims] = np.where(from_prior[:, None], prior, walk)
    return out


def _propose_from(before: "KernelDensity", rows: np.ndarray, dims: np.ndarray, low: np.ndarray,
                  high: np.ndarray, scale: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """`propose` with the independence share drawn from `before` instead of the prior, and
    each proposal's log density ratio under `before` where it took the walk (0 where it
    was independent: the ratio cancels against the proposal's)."""
    n, k = rows.shape[0], dims.size
    independent = rng.random(n) < PRIOR_SHARE
    lo, hi = low[dims], high[dims]
    walk = reflect_into(rows[:, dims] + np.asarray(scale, dtype=np.float64) * rng.standard_normal((n, k)), lo, hi)
    walk[independent] = before.sample(int(independent.sum()), rng, lo, hi)
    proposed = rows.copy()
    proposed[:, dims] = walk
    log_ratio = np.where(independent, 0.0,
                         before.log_density(proposed[:, dims]) - before.log_density(rows[:, dims]))
    return proposed, log_ratio


def window_log_likelihood(steps: Sequence[RealStep], rows: np.ndarray,
                          simulate: Callable[..., dict],
                          step_log_likelihood: Callable[[RealStep, dict], np.ndarray]) -> np.ndarray:
    """Sum over `steps` of each row's log-likelihood, every step re-simulated for every row."""
    total = np.zeros(len(rows))
    for st in steps:
        res = st.replay(simulate, rows)
        total += step_log_likelihood(st, res)
    return total


def _in_order(per_step: np.ndarray) -> np.ndarray:
    """The rows' window log-likelihood from their (steps, rows) terms, summed in the
    window's order, as ``window_log_likelihood`` sums it (so bit for bit its value)."""
    total = np.zeros(per_step.shape[1])
    for terms in per_step:
        total += terms
    return total


# Early rejection's slack (nats): a proposal is dropped only when even the bound of the
# steps it has not replayed leaves it this far short of acceptance, so that summing its
# terms in another order than the window's (rounding of ~1e-13 nats) cannot flip a decision.
EARLY_REJECTION_SLACK = 1e-6


def _screened(steps: Sequence[RealStep], proposed: np.ndarray, needed: np.ndarray, bounds: np.ndarray,
              order: np.ndarray, simulate: Callable[..., dict],
              step_log_likelihood: Callable[[RealStep, dict], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The proposals' window log-likelihood with early rejection (Solonen et al. 2012): the
    steps replayed in `order`, each for the proposals still alive, and a proposal dropped
    once its terms so far plus the `bounds` (the most any row can score) of the steps left
    fall short of `needed` (what acceptance asks of its whole sum). Returns the sums (NaN
    where dropped: rejected for certain, the same decision the full window makes), the
    (steps, rows) terms replayed, and whether each row was replayed in full."""
    n = len(proposed)
    per_step = np.full((len(steps), n), np.nan)
    partial = np.zeros(n)
    alive = np.ones(n, dtype=bool)
    rest = np.concatenate([np.cumsum(bounds[order][::-1])[::-1][1:], [0.0]])
    for j, left in zip(order, rest):
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        st = steps[j]
        terms = step_log_likelihood(st, st.replay(simulate, proposed[idx]))
        per_step[j, idx] = terms
        partial[idx] += terms
        alive[idx] = ~(partial[idx] + left < needed[idx] - EARLY_REJECTION_SLACK)
    full = alive.copy()
    out = np.full(n, np.nan)
    if full.any():
        out[full] = _in_order(per_step[:, full])
    return out, per_step, full


def _screening_order(per_step: np.ndarray) -> np.ndarray:
    """The steps that tell the current rows apart most, first (their terms' spread over the
    rows): where a proposal that will be rejected shows it soonest. Stable, so ties keep
    the window's order."""
    finite = np.isfinite(per_step)
    count = np.maximum(finite.sum(axis=1), 1)
    vals = np.where(finite, per_step, 0.0)
    mean = vals.sum(axis=1) / count
    spread = np.sqrt(np.where(finite, (vals - mean[:, None]) ** 2, 0.0).sum(axis=1) / count)
    return np.argsort(-spread, kind="stable")


def mh_move(rows: np.ndarray, dims: np.ndarray, low: np.ndarray, high: np.ndarray, scale: np.ndarray,
            steps: Sequence[RealStep], simulate: Callable[..., dict],
            step_log_likelihood: Callable[[RealStep, dict], np.ndarray],
            rng: np.random.Generator, sweeps: int = 1,
            before: "KernelDensity | None" = None,
            step_bound: Callable[[RealStep], float] | None = None) -> tuple[np.ndarray, int]:
    """`sweeps` Metropolis-Hastings sweeps over every row (equal weights assumed) against
    the belief before the window times the window's likelihood: the new rows and how many
    proposals were accepted. `before` None is the uniform prior (the window reaches back
    to it); else the kernel density of the belief before the window's first step, which
    carries the older evidence. Each row takes, with probability PRIOR_SHARE, an
    independence proposal from `before` (or the prior), accepted on the likelihood ratio
    alone (the density cancels), else the reflected random walk, accepted on the target's
    ratio: a mixture of two kernels that each leave the target invariant.

    Without `step_bound` the first sweep simulates current and proposed rows in one call
    per step (the shards see one batch of 2N) and later sweeps only the proposals. With
    `step_bound` (an upper bound on any row's log-likelihood of a step) the proposals are
    screened by early rejection: the acceptance's uniform is drawn before the window is
    replayed (the same draws in the same order: the worlds draw nothing), and a proposal
    is replayed step by step only while it can still be accepted. The rows, the accepted
    count and every later draw are bit for bit those of the full replay; only the
    particle-actions spent differ."""
    rows = np.asarray(rows, dtype=np.float64).copy()
    if not steps or np.asarray(dims).size == 0 or sweeps <= 0:
        return rows, 0
    n = rows.shape[0]
    ll = None
    accepted = 0
    bounds = None if step_bound is None else np.array([float(step_bound(st)) for st in steps])
    cur_steps = None
    for _ in range(sweeps):
        if before is None:
            proposed, log_ratio = propose(rows, dims, low, high, scale, rng), np.zeros(n)
        else:
            proposed, log_ratio = _propose_from(before, rows, dims, low, high, scale, rng)
        if bounds is not None:
            log_u = np.log(rng.random(n))
            if cur_steps is None:
                cur_steps = np.array([step_log_likelihood(st, st.replay(simulate, rows)) for st in steps])
                ll = _in_order(cur_steps)
            # accepted iff log_u < ll_p - ll + log_ratio, i.e. ll_p > log_u + ll - log_ratio
            ll_p, terms, full = _screened(steps, proposed, log_u + ll - log_ratio, bounds,
                                          _screening_order(cur_steps), simulate, step_log_likelihood)
            with np.errstate(invalid="ignore"):
                accept = full & (log_u < ll_p - ll + log_ratio)
            cur_steps[:, accept] = terms[:, accept]
        else:
            if ll is None:
                both = window_log_likelihood(steps, np.vstack([rows, proposed]), simulate, step_log_likelihood)
                ll, ll_p = both[:n], both[n:]
            else:
                ll_p = window_log_likelihood(steps, proposed, simulate, step_log_likelihood)
            accept = np.log(rng.random(n)) < ll_p - ll + log_ratio
        rows[accept], ll[accept] = proposed[accept], ll_p[accept]
        accepted += int(accept.sum())
    return rows, accepted


@dataclass(frozen=True)
class KernelDensity:
    """The belief before a step as a density: the Gaussian kernel density estimate the
    regularised filter resamples from (Liu and West: centres shrunk towards the weighted
    mean by a = sqrt(1 - h^2), kernel std h x the weighted std), truncated to the prior's
    box. The resample-move's target is this density times the step's likelihood."""

    centres: np.ndarray     # (N, k)
    log_w: np.ndarray       # (N,), normalised
    bandwidth: np.ndarray   # (k,) kernel std per column

    @classmethod
    def of(cls, cols: np.ndarray, log_w: np.ndarray, h: float, floor: np.ndarray) -> "KernelDensity":
        """The density of weighted rows `cols` (N, k) with bandwidth factor `h`; `floor` the
        least kernel std per column (the jitter floor)."""
        cols = np.asarray(cols, dtype=np.float64)
        log_w = np.asarray(log_w, dtype=np.float64)
        log_w = log_w - _logsumexp(log_w)
        w = np.exp(log_w)
        mean = w @ cols
        # The weighted variance of a sample of effective size ESS is short by (ESS - 1) / ESS
        # (the reliability-weights correction the resampler applies too): uncorrected, every
        # move shrank the belief by it and 80 openings ended at mean z^2 13 with 8 particles.
        c = unbiased_std_factor(1.0 / float(np.dot(w, w)))
        std = c * np.sqrt(np.maximum(w @ (cols - mean) ** 2, 0.0))
        a = np.sqrt(max(1.0 - h * h, 0.0))
        return cls(mean + a * c * (cols - mean), log_w, np.maximum(h * std, floor))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """The density's mean and covariance (the centres' weighted ones plus the kernel's)."""
        w = np.exp(self.log_w)
        mean = w @ self.centres
        dev = self.centres - mean
        return mean, (dev * w[:, None]).T @ dev + np.diag(self.bandwidth ** 2)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """Log density at each row of `x` (M, k) (of the untruncated mixture)."""
        z = (np.asarray(x, dtype=np.float64)[:, None, :] - self.centres[None]) / self.bandwidth
        norm = np.sum(np.log(self.bandwidth)) + 0.5 * self.bandwidth.size * math.log(2 * math.pi)
        return _logsumexp(self.log_w[None] - 0.5 * np.sum(z * z, axis=-1), axis=1) - norm

    def draw(self, m: int, rng: np.random.Generator) -> np.ndarray:
        """`m` draws of the untruncated mixture."""
        idx = rng.choice(len(self.log_w), size=m, p=np.exp(self.log_w))
        return self.centres[idx] + self.bandwidth * rng.standard_normal((m, self.centres.shape[1]))

    def sample(self, m: int, rng: np.random.Generator, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """`m` draws inside [low, high] (out-of-box draws drawn again: the truncated density,
        whose normalising constant cancels in the acceptance ratio)."""
        out = np.empty((m, self.centres.shape[1]))
        todo = np.arange(m)
        for _ in range(64):
            if todo.size == 0:
                return out
            idx = rng.choice(len(self.log_w), size=todo.size, p=np.exp(self.log_w))
            draw = self.centres[idx] + self.bandwidth * rng.standard_normal((todo.size, out.shape[1]))
            out[todo] = draw
            todo = todo[np.any((draw < low) | (draw > high), axis=1)]
        out[todo] = np.clip(out[todo], low, high)   # a box the kernel barely reaches
        return out


def _logsumexp(a: np.ndarray, axis: int | None = None) -> np.ndarray:
    m = np.max(a, axis=axis, keepdims=True)
    out = m + np.log(np.sum(np.exp(a - m), axis=axis, keepdims=True))
    return np.squeeze(out, axis=axis) if axis is not None else float(out.squeeze())


@dataclass(frozen=True)
class LinearisedProposal:
    """An independence proposal where the step's reading says L is: the belief before
    (as a Gaussian of the kernel density's moments) updated by the reading through the
    particle worlds' measurements regressed linearly on L over the current rows (a Kalman
    step with an ensemble-estimated observation matrix, as the unscented and extended
    particle filters' proposals; van der Merwe et al. 2000). The regression's residual
    scatter is added to the sensor's variance, so a poor linear fit widens the proposal
    instead of pointing it confidently wrong. None where the fit is undetermined."""

    mean: np.ndarray
    cov: np.ndarray
    chol: np.ndarray

    @classmethod
    def fit(cls, cols: np.ndarray, predicted: np.ndarray, observed: np.ndarray, sigma: np.ndarray,
            before: KernelDensity) -> "LinearisedProposal | None":
        """`cols` (n, k) the rows' columns moved; `predicted` (n, c) their simulated weighed
        channels, `observed` (c,) the readings, `sigma` (c,) the likelihood's sigma."""
        predicted = np.asarray(predicted, dtype=np.float64)
        observed = np.asarray(observed, dtype=np.float64)
        keep = np.isfinite(observed) & np.all(np.isfinite(predicted), axis=0)
        n, k = cols.shape
        if not keep.any() or n < k + 3:
            return None
        x_mean = cols.mean(axis=0)
        design = np.column_stack([np.ones(n), cols - x_mean])
        coef, *_ = np.linalg.lstsq(design, predicted[:, keep], rcond=None)
        resid = predicted[:, keep] - design @ coef
        resid_var = np.sum(resid * resid, axis=0) / (n - k - 1)
        jac = coef[1:].T                                        # (c, k)
        m, p = before.moments()
        s_cov = jac @ p @ jac.T + np.diag(np.asarray(sigma, dtype=np.float64)[keep] ** 2 + resid_var)
        gain = p @ jac.T @ np.linalg.inv(s_cov)
        innovation = observed[keep] - (coef[0] + jac @ (m - x_mean))
        mean = m + gain @ innovation
        cov = p - gain @ jac @ p
        cov = 0.5 * (cov + cov.T) + np.diag(1e-12 + 1e-9 * np.diag(p))
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            return None
        return cls(mean, cov, chol)

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """Log density at each row of `x` (M, k)."""
        z = np.linalg.solve(self.chol, (np.asarray(x, dtype=np.float64) - self.mean).T)
        norm = np.sum(np.log(np.diag(self.chol))) + 0.5 * self.mean.size * math.log(2 * math.pi)
        return -0.5 * np.sum(z * z, axis=0) - norm

    def draw(self, m: int, rng: np.random.Generator) -> np.ndarray:
        """`m` draws of the untruncated Gaussian."""
        return self.mean + rng.standard_normal((m, self.mean.size)) @ self.chol.T


def _simulated(step: RealStep, rows: np.ndarray, simulate: Callable[..., dict],
               step_log_likelihood: Callable[[RealStep, dict], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Each row's log-likelihood of `step`, and its simulated measurements."""
    res = step.replay(simulate, rows)
    return step_log_likelihood(step, res), np.asarray(res["measurements"], dtype=np.float64)


def resample_move(rows: np.ndarray, dims: np.ndarray, low: np.ndarray, high: np.ndarray,
                  before: KernelDensity, step: RealStep, simulate: Callable[..., dict],
                  step_log_likelihood: Callable[[RealStep, dict], np.ndarray],
                  rng: np.random.Generator, max_sweeps: int = MAX_SWEEPS,
                  channels: np.ndarray | None = None, sigma: np.ndarray | None = None
                  ) -> tuple[np.ndarray, int, int]:
    """Gilks and Berzuini's move after a resample: Metropolis-Hastings sweeps over the
    resampled rows (equal weights) targeting ``before(L) x p(y_step | L)``, the belief
    before the step as its kernel density times the step's likelihood, the step re-simulated
    for each proposal. Each row, each sweep, takes one of two proposals, chosen by a coin
    independent of the row (so the mixture keeps the target invariant): a reflected random
    walk of h x the rows' std (accepted with the target's ratio), or an independence draw
    (accepted with pi(L') q(L) / (pi(L) q(L'))) from `before`, or, when `channels` and
    `sigma` name the weighed channels, from the defensive mixture of `before` and the
    ``LinearisedProposal`` (where the reading says L is). The linearised proposal is
    refitted to the population before each sweep, as population-based SMC proposals are.
    `max_sweeps` sweeps. (rows, accepted proposals, sweeps)."""
    rows = np.asarray(rows, dtype=np.float64).copy()
    dims = np.asarray(dims, dtype=np.int64)
    n, k = rows.shape[0], dims.size
    if n < 2 or k == 0 or max_sweeps <= 0:
        return rows, 0, 0
    lo, hi = low[dims], high[dims]
    ll, meas = _simulated(step, rows, simulate, step_log_likelihood)
    lp = before.log_density(rows[:, dims])
    guided = channels is not None and sigma is not None and np.asarray(channels).size > 0
    accepted = sweeps = 0
    while sweeps < max_sweeps:
        cols = rows[:, dims]
        lin = (LinearisedProposal.fit(cols, meas[:, channels], step.measurements[channels], sigma, before)
               if guided else None)
        scale = np.maximum(rpf_bandwidth(n, k) * cols.std(axis=0), before.bandwidth * 1e-3)
        independent = rng.random(n) < PRIOR_SHARE
        walk = reflect_into(cols + scale * rng.standard_normal((n, k)), lo, hi)
        jump = _independence_draw(before, lin, n, rng)
        pick = np.where(independent[:, None], jump, walk)
        inside = np.all((pick >= lo) & (pick <= hi), axis=1)      # outside: target 0, rejected
        proposed = rows.copy()
        proposed[:, dims] = np.clip(pick, lo, hi)
        ll_p, meas_p = _simulated(step, proposed, simulate, step_log_likelihood)
        lp_p = before.log_density(proposed[:, dims])
        log_ratio = (ll_p + lp_p) - (ll + lp)
        # an independence proposal's correction q(L) / q(L'); the walk is symmetric
        log_ratio = np.where(independent, log_ratio + _independence_log_density(before, lin, cols)
                             - _independence_log_density(before, lin, pick), log_ratio)
        accept = inside & (np.log(rng.random(n)) < log_ratio)
        rows[accept], ll[accept], lp[accept], meas[accept] = (proposed[accept], ll_p[accept],
                                                               lp_p[accept], meas_p[accept])
        accepted += int(accept.sum())
        sweeps += 1
    return rows, accepted, sweeps


def _independence_draw(before: KernelDensity, lin: LinearisedProposal | None, m: int,
                       rng: np.random.Generator) -> np.ndarray:
    """`m` draws of the independence proposal: the belief before, or half of it and half the
    linearised proposal (a defensive mixture, Hesterberg 1995: the belief's half keeps the
    proposal's tails as heavy as the target's, so a row the linearisation misses can still
    leave; a light-tailed proposal alone strands every row where it puts no mass)."""
    out = before.draw(m, rng)
    if lin is not None:
        aimed = rng.random(m) < 0.5
        out = np.where(aimed[:, None], lin.draw(m, rng), out)
    return out


def _independence_log_density(before: KernelDensity, lin: LinearisedProposal | None,
                              x: np.ndarray) -> np.ndarray:
    if lin is None:
        return before.log_density(x)
    return np.logaddexp(before.log_density(x), lin.log_density(x)) - math.log(2.0)
