"""What one observation does to the belief: the likelihood of every particle's prediction,
the Bayes update, resampling with a regularising kernel and, when no particle explained the
observation, fresh draws from the prior (issue 24).

The session simulates the particles and scores the symbolic outcome; this module adds the
measurement channels (``coordinator.particle_filter.likelihood``: a robust mixture, with the likelihood's
sigma widened by the measured model error, ``coordinator.particle_filter.model_error``), tempers an update
that would cut the effective sample size by more than ``ess_keep``, updates the belief and
says whether the update was informative, then resamples with the Musso kernel and watches
for lock-in (``coordinator.particle_filter.rejuvenation``). Under the sizes variation the weights are kept
per block (``coordinator.particle_filter.block_weights``), an action's update going to the block it
names. Its state (model error, lock-in averages, block weights) goes into the session's
checkpoint.

Settings (RunConfig): ``outlier_rate`` (0: the plain Gaussian), ``model_error``
("online" | "none"), ``ess_keep`` (0: untempered), ``resample_kernel`` ("rpf" | "jitter":
the fixed ``jitter`` on extra copies), ``block_weights``, ``lock_in`` with ``lock_in_slow``
/ ``lock_in_fast``. With 0, "none", 0, "jitter", off and off (what a stored config from
before issue 24 gets) every number is what it was before.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .belief import Belief, gaussian_log_likelihood, logsumexp
from .block_weights import GroupWeights
from .likelihood import (INFORMATIVE_NATS, OUTLIER_WIDTH_SIGMAS, departure_log_likelihood, ess_temper, matched,
                         normalised_evidence, perfect_log_likelihood, readings_given_outcome, robust_log_likelihood,
                         update_information)
from .model_error import BIAS_Z, ModelError
from .perception import mixture_log_likelihood
from .rejuvenation import EXPLAINED, LockInMonitor, action_blocks, inject_prior, regularise, rpf_bandwidth
from ..run_config import RunConfig

__all__ = ["Reweighting", "UpdateOutcome"]


def _normalised(log_w: np.ndarray) -> np.ndarray:
    return log_w - logsumexp(log_w)


@dataclass(frozen=True)
class UpdateOutcome:
    """One update: its information (KL, nats), whether it counts as informative, whether
    the best particle explained the observation, and the tempering it took (1: none)."""

    information: float
    informative: bool
    explained: bool
    alpha: float = 1.0


class Reweighting:
    """The filter's settings and its state between observations, for one session."""

    def __init__(self, config: RunConfig, measurement_model: tuple[np.ndarray, np.ndarray],
                 block_names: list[str], n_properties: int, per_block: bool) -> None:
        self.config = config
        idx, sigma = measurement_model
        self.channels = np.asarray(idx, dtype=np.int64)
        self.sensor_sigma = np.asarray(sigma, dtype=np.float64).reshape(-1)
        self.block_names = list(block_names)
        self.n_properties = int(n_properties)
        self.per_block = bool(per_block)
        self.model_error = ModelError(self.sensor_sigma, centered=config.model_error == "centered")
        self.lock_in = LockInMonitor(config.lock_in_slow, config.lock_in_fast)
        self.weights: GroupWeights | None = None     # made from the belief on first use
        self._explained = True
        self._evidence = 1.0
        self._biased = False
        # The columns of L a resample-move is due on (set by `resample` when the lock-in
        # monitor fires with recovery "mh_move"; the session runs the move: it holds the
        # particle worlds and the recent real steps).
        self.pending_move: np.ndarray | None = None
        # Per row, the explained steps whose outcome it mispredicted since the rows were last
        # renewed (``mismatches``); emptied at each episode's start like the move's window.
        self.mismatched: np.ndarray | None = None
        self._rows: np.ndarray | None = None
        self._impoverished = False

    @property
    def regularised(self) -> bool:
        """The filter of issue 24 (group weights, Musso kernel); else the one of before."""
        return self.config.resample_kernel in ("rpf", "liu_west")

    @property
    def shrink(self) -> bool:
        """Liu and West's shrinkage in the kernel (keeps the posterior's mean and variance)."""
        return self.config.resample_kernel == "liu_west"

    # ----------------------------------------------------------------- groups of L
    def _block_groups(self) -> list[np.ndarray]:
        """Each block's columns of L (property-major rows) when weights are kept per block."""
        if not (self.per_block and self.config.block_weights and self.regularised):
            return []
        n = len(self.block_names)
        return [np.array([j * n + k for j in range(self.n_properties)]) for k in range(n)]

    def _groups(self, belief: Belief) -> GroupWeights:
        if self.weights is None or self.weights.log_w.shape[1] != belief.n:
            self.weights = GroupWeights.for_belief(belief, self._block_groups())
        return self.weights

    def _group(self, action: str, groups: GroupWeights) -> int:
        """The group an action's update goes to: the block it names when it names one, else
        ALL. An action naming several blocks (a stack of b3 onto b1) has an outcome that
        depends on all of them jointly, so its likelihood goes to the whole rows (issue 37:
        it went to the first block alone, and the block beneath never learned)."""
        named = sorted(set(action_blocks(action, self.block_names)))
        return named[0] if len(named) == 1 and groups.all > 0 else groups.all

    def action_view(self, belief: Belief, action: str) -> tuple[np.ndarray, np.ndarray]:
        """The log-weights and the columns of L an action concerns: with weights per block,
        the columns of the block it names, weighted by that block's and the whole row's
        weights (the other blocks' weights say nothing about it and only add noise);
        otherwise every column and the belief's weights."""
        every = np.arange(belief.dim)
        if not self.regularised:
            return belief.log_weights, every
        groups = self._groups(belief)
        g = self._group(action, groups)
        if g == groups.all:
            return belief.log_weights, every
        return _normalised(groups.log_w[g] + groups.log_w[groups.all]), groups.groups[g]

    def marginals(self, belief: Belief) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean and std per column of L: each block's columns under its own and the
        whole row's weights when weights are per block; else the belief's."""
        if not self.regularised or not self._block_groups():
            return belief.mean(), belief.std()
        groups = self._groups(belief)
        mean, std = np.zeros(belief.dim), np.zeros(belief.dim)
        for g in range(groups.all):
            w = np.exp(_normalised(groups.log_w[g] + groups.log_w[groups.all]))
            cols = belief.particles[:, groups.groups[g]]
            mean[groups.groups[g]] = w @ cols
            dev = cols - w @ cols
            std[groups.groups[g]] = np.sqrt(np.maximum(w @ (dev * dev), 0.0))
        return mean, std

    # ----------------------------------------------------------------- likelihood
    def sigma(self) -> np.ndarray:
        """The likelihood's sigma per weighed channel (sensor, widened by the model error)."""
        if self.config.model_error in ("online", "centered"):
            return self.model_error.sigma()
        return self.sensor_sigma

    def log_likelihood(self, symbolic_ll: np.ndarray, observed: np.ndarray,
                       predicted: np.ndarray) -> tuple[np.ndarray, float]:
        """Per-particle log-likelihood of an observation (the symbolic outcome's, plus the
        weighed channels' at the current sigma), and an exact prediction's; changes no state.
        The update (`weigh`) and the resample-move's re-simulated history both use it."""
        ll = np.asarray(symbolic_ll, dtype=np.float64)
        perfect = math.log1p(-self.config.error_rate)
        if self.config.use_measurements and self.channels.size:
            meas_ll, meas_perfect = self._measurement_ll(observed[self.channels], predicted[:, self.channels])
            rule = self.config.disagreement_readings
            if rule != "own":
                departed = meas_perfect if rule == "profile" else departure_log_likelihood(
                    observed[self.channels], predicted[:, self.channels], self.sigma(),
                    self.config.outlier_rate, OUTLIER_WIDTH_SIGMAS * self.sensor_sigma)
                meas_ll = readings_given_outcome(matched(ll, self.config.error_rate), meas_ll, departed)
            ll, perfect = ll + meas_ll, perfect + meas_perfect
        return ll, perfect

    def log_likelihood_bound(self, observed: np.ndarray) -> float:
        """The most any row's ``log_likelihood`` (or ``node_log_likelihood``, a mixture of
        them) of `observed` can be, whatever its world predicted: the better symbolic term,
        plus per weighed channel the better of the robust term's peak and the departure's
        flat floor. The move's early rejection drops a proposal only against it."""
        err = self.config.error_rate
        bound = max(math.log1p(-err), math.log(err) if err > 0.0 else -math.inf)
        if self.config.use_measurements and self.channels.size:
            obs = np.asarray(observed, dtype=np.float64)[self.channels]
            exact = np.where(np.isnan(obs), 0.0, obs)[None, :]
            bound += float(departure_log_likelihood(obs, exact, self.sigma(), self.config.outlier_rate,
                                                    OUTLIER_WIDTH_SIGMAS * self.sensor_sigma)[0])
        return bound

    def node_log_likelihood(self, nodes: Sequence[tuple[float, np.ndarray, np.ndarray]],
                            observed: np.ndarray) -> np.ndarray:
        """Per-particle log-likelihood integrated over the perception error: nodes are
        (log weight, symbolic log-likelihood, predicted measurements) per quadrature node
        (``coordinator.particle_filter.perception``)."""
        return mixture_log_likelihood([(lw, self.log_likelihood(sym, observed, pred)[0]) for lw, sym, pred in nodes])

    def weigh(self, belief: Belief, action: str, symbolic_ll: np.ndarray, observed: np.ndarray,
              predicted: np.ndarray,
              nodes: Sequence[tuple[float, np.ndarray, np.ndarray]] | None = None) -> UpdateOutcome:
        """Bayes-update `belief` after `action` with the symbolic log-likelihood and the
        weighed channels of `observed` (M,) against each particle's `predicted` (N, M).
        With `nodes` (the worlds replayed at each perception quadrature node) the
        likelihood is their mixture; `symbolic_ll` and `predicted` are the perceived
        pose's, whose innovations the model error reads."""
        before = belief.log_weights.copy()
        view_before = self.action_view(belief, action)[0].copy()
        ll, perfect = self.log_likelihood(symbolic_ll, observed, predicted)
        if nodes:
            ll = self.node_log_likelihood(nodes, observed)
        self._evidence = normalised_evidence(view_before, ll, perfect)
        if self.config.use_measurements and self.channels.size:
            obs, pred = observed[self.channels], predicted[:, self.channels]
            if self.config.model_error in ("online", "centered") and self._all_matched(symbolic_ll):
                # The innovation of the weights before, where every particle predicted the
                # observed outcome: a reading of another regime (fingers closed on air where
                # particles grasp) is a mixture, not model error (early in a run such
                # readings made half the innovations and inflated the opening's sigma to
                # 29 mm).
                self.model_error.observe(obs, pred, belief.weights)
                if self.model_error.bias_z() > BIAS_Z:
                    self._biased = True
                    self.model_error.history = [[] for _ in self.model_error.history]   # tested anew
                else:
                    self._biased = False
            else:
                self._biased = False
        self._explained = math.exp(min(float(np.max(ll)) - perfect, 0.0)) >= EXPLAINED
        self._impoverished = self._mismatches(belief, symbolic_ll)
        alpha = self._update(belief, action, ll)
        kl = update_information(before, belief.log_weights)
        return UpdateOutcome(kl, kl > INFORMATIVE_NATS, self._explained, alpha)

    def _mismatches(self, belief: Belief, symbolic_ll: np.ndarray) -> bool:
        """Count this step's symbolic mispredictions per row, if some row predicted it, and
        say whether every row has now mispredicted one since the rows were last renewed:
        each step explained by some hypothesis, the sequence by none, the signature of a
        truth between the rows (a cycle of two failing grasp poses, docs/LOOP.md, "Readings
        of a world whose outcome was wrong")."""
        if not self.config.mismatch_move:
            return False
        if self._rows is None or not np.array_equal(self._rows, belief.particles):
            self.mismatched = np.zeros(belief.n, dtype=np.int64)      # renewed rows: counted anew
            self._rows = belief.particles.copy()
        agreed = matched(symbolic_ll, self.config.error_rate)
        if not agreed.any():
            return False            # no row predicted it: the outlier's business (eps), not the set's
        self.mismatched += ~agreed
        return bool(np.all(self.mismatched > 0))

    def start_episode(self) -> None:
        """Forget the mismatch counts (the move's window empties with the episode too)."""
        self.mismatched, self._rows, self._impoverished = None, None, False

    def _update(self, belief: Belief, action: str, ll: np.ndarray) -> float:
        """The (tempered) Bayes step, on the action's group when weights are per group."""
        if not self.regularised:
            alpha = ess_temper(belief.log_weights, ll, self.config.ess_keep)
            belief.update(ll if alpha == 1.0 else alpha * ll)
            return alpha
        groups = self._groups(belief)
        g = self._group(action, groups)
        alpha = ess_temper(groups.log_w[g], ll, self.config.ess_keep)
        step = ll if alpha == 1.0 else alpha * ll
        belief.update(step)                          # validation and the degenerate flag
        if not belief.last_update_degenerate:
            groups.add(g, step)
            belief.log_weights = groups.joint()
        return alpha

    def _all_matched(self, symbolic_ll: np.ndarray) -> bool:
        """Whether every particle predicted the observed symbolic outcome."""
        return bool(np.all(np.asarray(symbolic_ll) >= math.log1p(-self.config.error_rate) - 1e-12))

    def _measurement_ll(self, obs: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, float]:
        """Per-particle log-likelihood of the weighed channels, and an exact prediction's."""
        sigma, eps = self.sigma(), self.config.outlier_rate
        if eps == 0.0:        # the plain Gaussian, bit for bit what it was before issue 24
            exact = np.where(np.isnan(obs), 0.0, obs)[None, :]
            return (gaussian_log_likelihood(obs, pred, sigma),
                    float(gaussian_log_likelihood(obs, exact, sigma)[0]))
        width = OUTLIER_WIDTH_SIGMAS * self.sensor_sigma
        return (robust_log_likelihood(obs, pred, sigma, eps, width),
                perfect_log_likelihood(obs, sigma, eps, width))

    # ----------------------------------------------------------------- resampling
    def resample(self, belief: Belief, rng: np.random.Generator, action: str,
                 rejuvenate: bool = True) -> tuple[bool, int]:
        """Resample the action's group below ESS N/2; then, when the observation was
        unexplained, redraw the lock-in monitor's share of that group's rows from the
        prior. (resampled?, rows redrawn)."""
        c = self.config
        if not self.regularised:
            resampled = belief.maybe_resample(rng, jitter=c.jitter, jitter_floor=c.jitter_floor)
            group, groups = None, None
        else:
            groups = self._groups(belief)
            group = self._group(action, groups)
            resampled = groups.ess(group) < 0.5 * belief.n
            if resampled:
                self._resample_group(groups, group, belief, rng)
        if not (c.lock_in and rejuvenate):
            return resampled, 0
        key, dims = self._lock_in_key(action, belief.dim)
        move = c.recovery == "mh_move"
        share = self.lock_in.observe(key, self._explained, self._evidence if move else None)
        if move and (self._biased or self._impoverished):
            # the innovations' mean test failed, or no row predicted every outcome since
            # the rows were renewed: move now
            share = max(share, 1.0)
            self._impoverished = False
        if share <= 0.0 or dims.size == 0:
            return resampled, 0
        if move:
            # Uniform weights first (the move's target is the posterior the weights carry),
            # then the session moves every row's `dims` by Metropolis-Hastings. Whole rows
            # moving: every group's weights made uniform by resampling the joint ones.
            if groups is None:
                if not np.allclose(belief.log_weights, belief.log_weights[0]):
                    belief.resample(rng, jitter=c.jitter, jitter_floor=c.jitter_floor)
            elif dims.size == belief.dim and groups.all > 0:
                self.resample_to(belief, belief.n, rng)
            elif not np.allclose(groups.log_w[group], groups.log_w[group][0]):
                self._resample_group(groups, group, belief, rng)
            self.pending_move = dims
            return True, 0
        if groups is None:
            if not np.allclose(belief.log_weights, belief.log_weights[0]):
                belief.resample(rng, jitter=c.jitter, jitter_floor=c.jitter_floor)
        elif not np.allclose(groups.log_w[group], groups.log_w[group][0]):
            self._resample_group(groups, group, belief, rng)     # uniform before the redraw
        injected = inject_prior(belief, share, dims, rng)
        return resampled or injected > 0, injected

    def _resample_group(self, groups: GroupWeights, g: int, belief: Belief, rng: np.random.Generator) -> None:
        # Musso's bandwidth is for a sample of equally weighted points; a weighted set holds
        # ESS of them, so kernel_bandwidth "ess" takes the count from the ESS (docs/LOOP.md).
        count = belief.n if self.config.kernel_bandwidth == "n" else max(int(round(groups.ess(g))), 1)
        h = rpf_bandwidth(count, groups.groups[g].size)
        groups.resample(g, belief, rng, h, self.config.jitter_floor, shrink=self.shrink)

    def resample_to(self, belief: Belief, n: int, rng: np.random.Generator) -> None:
        """Systematic resampling of whole rows to `n` particles (the adaptive budget's step);
        every weight becomes uniform."""
        c = self.config
        if not self.regularised:
            belief.resample_to(n, rng, jitter=c.jitter, jitter_floor=c.jitter_floor)
            return
        std, mean = belief.std(), belief.mean()
        belief.resample_to(n, rng, jitter=0.0, jitter_floor=0.0)
        regularise(belief, std, rpf_bandwidth(n, belief.dim), c.jitter_floor, rng,
                   mean=mean if self.shrink else None)
        self.weights = GroupWeights.for_belief(belief, self._block_groups())

    def _lock_in_key(self, action: str, dim: int) -> tuple[str, np.ndarray]:
        """Whose averages an action feeds and the dimensions of L a redraw replaces: the first
        block it names (the one it moves) and that block's properties when L has one entry per
        block (an action that names none, e.g. a push, redraws nothing); else all of L."""
        if not self.per_block:
            return "all", np.arange(dim)
        named = action_blocks(action, self.block_names)
        if self.config.recovery == "mh_move" and len(set(named)) != 1:
            return "all", np.arange(dim)      # a move is posterior-preserving: whole rows may move
        if not named:
            return "none", np.zeros(0, dtype=np.int64)
        k, n_blocks = named[0], len(self.block_names)
        return self.block_names[k], np.array([j * n_blocks + k for j in range(self.n_properties)])

    # ----------------------------------------------------------------- checkpoints
    def to_dict(self) -> dict:
        return {"model_error": self.model_error.to_dict(), "lock_in": self.lock_in.to_dict(),
                "weights": self.weights.to_dict() if self.weights is not None else None}

    def load(self, data: dict | None, dim: int) -> None:
        """Restore `to_dict`'s state (None: a checkpoint from before issue 24, a fresh state;
        the block weights are then made from the belief's, all in the whole-row group)."""
        data = data or {}
        self.model_error = ModelError.from_dict(data.get("model_error"), self.sensor_sigma,
                                                centered=self.config.model_error == "centered")
        self.lock_in = LockInMonitor.from_dict(data.get("lock_in"), slow=self.config.lock_in_slow,
                                               fast=self.config.lock_in_fast)
        weights = data.get("weights")
        self.weights = GroupWeights.from_dict(weights, dim) if weights is not None else None
