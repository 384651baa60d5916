"""Counterfactual simulated experience (issue 40): the particle worlds asked about contexts
the robot has not tried.

The paper's point of grounding objects in a physics engine is that the grounded worlds
yield simulated experience for policy learning. The loop's own simulated experience is
only the action being executed (``Session._reweight``), so T stays optimistic for every
context until the robot fails in it. Before an episode's first plan, this module draws M
rows of L from the belief, and in the world of each row runs one trial of every context the
domain declares (``PhysicsDomain.counterfactual_jobs``: by default T*'s probes) with Y at
the belief's mean, on the shards. The successes become T's rates in the planner's form
(``counterfactual_rates``), and each context gets them as M trials of evidence
(``context_counts``). A trial whose context the probe could not reach (a tower that Y, at
the belief, could not build in that row's world) is left out of its job: a job's success
rate is over the trials that reached it, and its context is credited only that share of
the M trials (the shares taken through the same ``counterfactual_rates``, so a context
derived from several jobs gets their derived share). T weighs them by a power prior per context family
(``coordinator.transition.transition_model.family_discount``): a family whose real outcomes
the simulations keep mispredicting (a reality gap the worlds cannot represent) loses its
counterfactual evidence in untried contexts too.

Within an episode the snapshot is kept until the belief has moved enough to matter: at a
replan (after a failure), the snapshot's rows, as an importance sample of the belief as it
is now, would be worth fewer than half their number (``ess_fraction``, the filter's own
resampling threshold); then a new one is drawn. The rows are a sample of the belief at the
snapshot, so that is when they no longer stand for the belief.

Rows are drawn with replacement in proportion to the weights (systematic resampling), so a
row's trials count alike; trial m of every job replays the same seeded world (common random
numbers, as the domains' T* estimates assume). Every draw comes from the episode's own seed
sequence (the run's seed, stream ``COUNTERFACTUAL_STREAM``, the episode), so the snapshot
depends on the seed and the belief only, not on shards, and turning it on shifts no other
draw of the run.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..particle_filter.belief import systematic_resample

__all__ = ["REFRESH_ESS_FRACTION", "Counterfactual", "SnapshotStopped", "context_counts", "draw_rows",
           "ess_fraction", "row_properties", "simulate"]

# A snapshot is redrawn when its rows would be worth fewer than this share of their number
# as an importance sample of the belief now: the threshold the filter resamples at
# (``Reweighting``: ESS < N / 2), for the same reason (docs/LOOP.md).
REFRESH_ESS_FRACTION = 0.5


class SnapshotStopped(Exception):
    """A snapshot told to stop (a cancel or a shutdown) between two of its contexts."""


@dataclass
class Counterfactual:
    """One snapshot: per T context (action name, context) the simulated (successes,
    trials), and what it cost."""

    episode: int
    rows: int
    counts: dict = field(default_factory=dict)
    trials: int = 0                # world trials run (rows x jobs)
    wall_s: float = 0.0
    refresh: int = 0               # 0: the episode's first snapshot; k: its k-th redraw
    mean: np.ndarray | None = None  # the belief's mean and std per column of L it was drawn from
    std: np.ndarray | None = None


def ess_fraction(mean0: np.ndarray, std0: np.ndarray, mean1: np.ndarray, std1: np.ndarray) -> float:
    """The share of their number that draws from belief 0 are worth as an importance sample
    of belief 1, each fitted by independent normals per column: 1 / (1 + chi^2(1 || 0)), the
    large-sample Kish ESS over M (Kong 1992), in closed form, so it means the same for any M.
    A column that moved or narrowed is costed exactly; one that widened to sqrt(2) x its std
    or more, or moved off a point, gives 0 (the draws cannot cover it).

    Per column, E_0[(p1 / p0)^2] = s0^2 / (s1 sqrt(2 s0^2 - s1^2)) exp(d^2 / (2 s0^2 - s1^2)).

    >>> ess_fraction(np.array([0.045]), np.array([0.002]), np.array([0.045]), np.array([0.002]))
    1.0
    >>> round(ess_fraction(np.array([0.045]), np.array([0.002]), np.array([0.046]), np.array([0.002])), 3)
    0.779
    >>> ess_fraction(np.array([0.045]), np.array([0.002]), np.array([0.045]), np.array([0.0005])) < 0.5
    True
    """
    m0, s0, m1, s1 = (np.asarray(a, dtype=np.float64).ravel() for a in (mean0, std0, mean1, std1))
    log_r = 0.0
    for a, b, u, v in zip(m0, s0, m1, s1):
        scale = max(abs(a), abs(u), b, v)
        if abs(u - a) <= 1e-9 * scale and abs(v - b) <= 1e-9 * scale:
            continue        # did not move (a known property too), up to a weighted sum's rounding
        room = 2.0 * b * b - v * v
        if b <= 0.0 or v <= 0.0 or room <= 0.0:
            return 0.0
        log_r += 2.0 * np.log(b) - np.log(v) - 0.5 * np.log(room) + (u - a) ** 2 / room
    return float(np.exp(-log_r))


def draw_rows(weights: np.ndarray, m: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of `m` rows drawn in proportion to `weights`: the belief's own systematic
    resampling (one uniform draw, the lowest variance of the unbiased schemes).

    >>> draw_rows(np.array([0.5, 0.25, 0.25]), 4, np.random.default_rng(0)).tolist()
    [0, 0, 1, 2]
    """
    return systematic_resample(weights, rng, m)


def row_properties(names, row: np.ndarray, per_object: int) -> dict[str, float]:
    """A row of L (property-major, `per_object` values each) as one number per property by
    L's names: the objects' mean where L has a value per object (the probes set every
    object alike)."""
    row = np.asarray(row, dtype=np.float64)
    return {name: float(np.mean(row[j * per_object:(j + 1) * per_object])) for j, name in enumerate(names)}


def context_counts(rates: dict, contexts, trials: int,
                   shares: dict | None = None) -> dict[tuple[str, int], tuple[float, float]]:
    """T's contexts with the simulated evidence of `rates` (the planner's form: ``{name: p}``
    for an action whose only context is 0, else ``{name: [p per context, in order]}``) as
    (successes, trials) with `trials` trials each, or `trials` x the context's share in
    `shares` (the same form; a share of 0: no evidence); contexts without a rate get none.

    >>> ctx = [("pickup", 0), ("push", 1), ("push", 2)]
    >>> context_counts({"pickup": 1.0, "push": [1.0, 0.25]}, ctx, 4)
    {('pickup', 0): (4.0, 4.0), ('push', 1): (4.0, 4.0), ('push', 2): (1.0, 4.0)}
    >>> context_counts({"pickup": 1.0, "push": [1.0, 0.25]}, ctx, 4, {"pickup": 1.0, "push": [0.5, 0.0]})
    {('pickup', 0): (4.0, 4.0), ('push', 1): (2.0, 2.0)}
    """
    by_name: dict[str, list[int]] = {}
    for name, k in contexts:
        by_name.setdefault(str(name), []).append(int(k))
    out = {}
    for name, ks in by_name.items():
        if name not in rates:
            continue
        value = rates[name]
        ps = [value] if np.isscalar(value) else list(value)
        share = (shares or {}).get(name, 1.0)
        qs = [share] * len(ps) if np.isscalar(share) else list(share)
        for k, p, q in zip(sorted(set(ks)), ps, qs):
            n = float(trials) * float(min(1.0, max(0.0, q)))
            if n > 0:
                out[(name, k)] = (float(min(1.0, max(0.0, p))) * n, n)
    return out


def simulate(pool, physics, names, per_object: int, rows: np.ndarray, weights: np.ndarray,
             believed: dict[str, float], m: int, n_objects: int, contexts,
             seed: np.random.SeedSequence, episode: int, refresh: int = 0,
             marginals: tuple[np.ndarray, np.ndarray] | None = None,
             should_stop: Callable[[], bool] | None = None, arm=None) -> Counterfactual:
    """The snapshot of M = `m` rows drawn from the belief (`rows`, `weights`) with Y at
    `believed`, on `pool`'s shards (``ShardPool.probe_rows``); `marginals`: the belief's mean
    and std per column of L, kept for the redraw test. With `should_stop` the contexts go to
    the shards one at a time and it is polled before each (``SnapshotStopped``): a snapshot
    is tens of seconds of physics, and a cancel must not wait for all of it. The counts are
    the same either way (each trial's world is seeded by its row alone). `arm`: a factory of
    the run's arm (``coordinator.loop.arm_trials.ArmForTrials``), which then does every
    trial's actions as the session's steps do them: a context the arm cannot do (no branch
    reaches it, no path clears the scene) fails in the snapshot, so T knows it before the
    robot is asked to try (issue 41); None: the floating gripper."""
    t0 = time.perf_counter()
    mean, std = (None, None) if marginals is None else (np.array(marginals[0]), np.array(marginals[1]))
    jobs = physics.counterfactual_jobs(n_objects)
    if not jobs or m < 1:
        return Counterfactual(episode, 0, refresh=refresh, mean=mean, std=std)
    rng = np.random.default_rng(seed)
    picked = draw_rows(weights, m, rng)
    truths = [row_properties(names, rows[i], per_object) for i in picked]
    trial_seeds = rng.integers(0, 2**63 - 1, size=m, dtype=np.int64)
    outcome = _probe(pool, jobs, truths, believed, trial_seeds, should_stop, arm)
    reached = (outcome >= 0).sum(axis=0)
    wins = (outcome == 1).sum(axis=0)
    keys = [(a, int(k)) for a, k in jobs]
    # Each job's rate over the trials that reached it, as successes out of m (a job none
    # reached: m, which its share of 0 then drops).
    conditional = {j: (float(w) * m / r if r else float(m)) for j, w, r in zip(keys, wins, reached)}
    rates = physics.counterfactual_rates(conditional, m, n_objects)
    shares = physics.counterfactual_rates({j: float(r) for j, r in zip(keys, reached)}, m, n_objects)
    return Counterfactual(episode, m, context_counts(rates, contexts, m, shares), m * len(jobs),
                          time.perf_counter() - t0, refresh, mean, std)


def _probe(pool, jobs: list, truths: list[dict], believed: dict, seeds: np.ndarray,
           should_stop: Callable[[], bool] | None, arm=None) -> np.ndarray:
    """(M, J) outcomes of every job for every row: one call, or one per job polling
    `should_stop` before each."""
    extra = {} if arm is None else {"arm": arm}
    if should_stop is None:
        return np.asarray(pool.probe_rows(jobs, truths, believed, seeds, **extra)["successes"])
    columns = []
    for job in jobs:
        if should_stop():
            raise SnapshotStopped(f"counterfactual snapshot stopped after {len(columns)} of {len(jobs)} contexts")
        columns.append(np.asarray(pool.probe_rows([job], truths, believed, seeds, **extra)["successes"]))
    return np.concatenate(columns, axis=1)
