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
monitor fires.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .belief import reflect_into

__all__ = ["MOVE_WINDOW", "PRIOR_SHARE", "RealStep", "propose", "mh_move"]

# Real steps re-simulated per move. The monitor fires after two or three badly predicted
# observations (REDRAW_BELOW at the default rates), so a window of 8 holds those and about
# as many again that the belief did predict, which keep a move from trading the old
# evidence for the new. The cost is linear in it (docs/LOOP.md, "Constants").
MOVE_WINDOW = 8

# The share of proposals drawn from the prior: half global (to reach a region no particle
# holds), half local (to refine where the rows are). Any share in (0, 1) leaves the target
# invariant; 1/2 is the mixture that neither starves.
PRIOR_SHARE = 0.5


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


def window_log_likelihood(steps: Sequence[RealStep], rows: np.ndarray,
                          simulate: Callable[..., dict],
                          step_log_likelihood: Callable[[RealStep, dict], np.ndarray]) -> np.ndarray:
    """Sum over `steps` of each row's log-likelihood, every step re-simulated for every row."""
    total = np.zeros(len(rows))
    for st in steps:
        res = simulate(st.start, rows, st.action, st.trajectory, st.start_time)
        total += step_log_likelihood(st, res)
    return total


def mh_move(rows: np.ndarray, dims: np.ndarray, low: np.ndarray, high: np.ndarray, scale: np.ndarray,
            steps: Sequence[RealStep], simulate: Callable[..., dict],
            step_log_likelihood: Callable[[RealStep, dict], np.ndarray],
            rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """One Metropolis-Hastings sweep over every row (equal weights assumed): the new rows
    and how many proposals were accepted. Current and proposed rows are simulated in one
    call per step, so the shards see one batch of 2N."""
    rows = np.asarray(rows, dtype=np.float64)
    if not steps or np.asarray(dims).size == 0:
        return rows.copy(), 0
    n = rows.shape[0]
    proposed = propose(rows, dims, low, high, scale, rng)
    ll = window_log_likelihood(steps, np.vstack([rows, proposed]), simulate, step_log_likelihood)
    accept = np.log(rng.random(n)) < ll[n:] - ll[:n]
    out = rows.copy()
    out[accept] = proposed[accept]
    return out, int(accept.sum())
