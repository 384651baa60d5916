"""What one observation does to the belief: the likelihood of every particle's prediction,
the Bayes update, resampling with a regularising kernel and, when no particle explained the
observation, fresh draws from the prior (issue 24).

The session simulates the particles and scores the symbolic outcome; this module adds the
measurement channels (``coordinator.likelihood``: a robust mixture, with the likelihood's
sigma widened by the measured model error, ``coordinator.model_error``), updates the belief
and says whether the update was informative, then resamples with the Musso kernel and
watches for lock-in (``coordinator.rejuvenation``). Its state (model error, lock-in
averages) goes into the session's checkpoint.

Settings (RunConfig): ``outlier_rate`` (0: the plain Gaussian), ``model_error``
("online" | "none"), ``resample_kernel`` ("rpf" | "jitter": the fixed ``jitter``),
``lock_in`` with ``lock_in_slow`` / ``lock_in_fast``. With 0, "none", "jitter" and off
(what a stored config from before issue 24 gets) every number is what it was before.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .belief import Belief, gaussian_log_likelihood
from .likelihood import (INFORMATIVE_NATS, OUTLIER_WIDTH_SIGMAS, perfect_log_likelihood,
                         robust_log_likelihood, update_information)
from .model_error import ModelError
from .rejuvenation import EXPLAINED, LockInMonitor, action_blocks, inject_prior, rpf_bandwidth
from .run_config import RunConfig

__all__ = ["Reweighting", "UpdateOutcome"]


@dataclass(frozen=True)
class UpdateOutcome:
    """One update: its information (KL, nats), whether it counts as informative, and whether
    the best particle explained the observation."""

    information: float
    informative: bool
    explained: bool


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
        self.model_error = ModelError(self.sensor_sigma)
        self.lock_in = LockInMonitor(config.lock_in_slow, config.lock_in_fast)
        self._explained = True

    # ----------------------------------------------------------------- likelihood
    def sigma(self) -> np.ndarray:
        """The likelihood's sigma per weighed channel (sensor, widened by the model error)."""
        if self.config.model_error == "online":
            return self.model_error.sigma()
        return self.sensor_sigma

    def weigh(self, belief: Belief, symbolic_ll: np.ndarray, observed: np.ndarray,
              predicted: np.ndarray) -> UpdateOutcome:
        """Bayes-update `belief` with the symbolic log-likelihood and the weighed channels of
        `observed` (M,) against each particle's `predicted` (N, M)."""
        before = belief.log_weights.copy()
        ll = np.asarray(symbolic_ll, dtype=np.float64)
        perfect = math.log1p(-self.config.error_rate)
        if self.config.use_measurements and self.channels.size:
            obs, pred = observed[self.channels], predicted[:, self.channels]
            meas_ll, meas_perfect = self._measurement_ll(obs, pred)
            ll, perfect = ll + meas_ll, perfect + meas_perfect
            if self.config.model_error == "online":     # the innovation of the weights before
                self.model_error.observe(obs, pred, belief.weights)
        best = math.exp(min(float(np.max(ll)) - perfect, 0.0))
        belief.update(ll)
        kl = update_information(before, belief.log_weights)
        self._explained = best >= EXPLAINED
        return UpdateOutcome(kl, kl > INFORMATIVE_NATS, self._explained)

    def _measurement_ll(self, obs: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, float]:
        """Per-particle log-likelihood of the weighed channels, and an exact prediction's."""
        sigma, eps = self.sigma(), self.config.outlier_rate
        if eps == 0.0:        # the plain Gaussian, bit for bit what it was before issue 24
            ll = gaussian_log_likelihood(obs, pred, sigma)
            return ll, float(gaussian_log_likelihood(obs, np.where(np.isnan(obs), 0.0, obs)[None, :], sigma)[0])
        width = OUTLIER_WIDTH_SIGMAS * self.sensor_sigma
        return (robust_log_likelihood(obs, pred, sigma, eps, width),
                perfect_log_likelihood(obs, sigma, eps, width))

    # ----------------------------------------------------------------- resampling
    def kernel(self, n: int, dim: int) -> float:
        """The resampled copies' jitter, in posterior stds."""
        return rpf_bandwidth(n, dim) if self.config.resample_kernel == "rpf" else self.config.jitter

    def resample(self, belief: Belief, rng: np.random.Generator, action: str,
                 rejuvenate: bool = True) -> tuple[bool, int]:
        """Resample below ESS N/2; then, when the observation was unexplained, redraw the
        lock-in monitor's share of rows from the prior. (resampled?, rows redrawn)."""
        c = self.config
        h = self.kernel(belief.n, belief.dim)
        resampled = belief.maybe_resample(rng, jitter=h, jitter_floor=c.jitter_floor)
        if not (c.lock_in and rejuvenate):
            return resampled, 0
        key, dims = self._lock_in_key(action, belief.dim)
        share = self.lock_in.observe(key, self._explained)
        if share <= 0.0 or dims.size == 0:
            return resampled, 0
        injected = inject_prior(belief, share, dims, rng, h, c.jitter_floor)
        return resampled or injected > 0, injected

    def resample_to(self, belief: Belief, n: int, rng: np.random.Generator) -> None:
        """Systematic resampling to `n` particles (the adaptive budget's step)."""
        belief.resample_to(n, rng, jitter=self.kernel(n, belief.dim), jitter_floor=self.config.jitter_floor)

    def _lock_in_key(self, action: str, dim: int) -> tuple[str, np.ndarray]:
        """Whose averages an action feeds and the dimensions of L a redraw replaces: the first
        block it names (the one it moves) and that block's properties when L has one entry per
        block (an action that names none, e.g. a push, redraws nothing); else all of L."""
        if not self.per_block:
            return "all", np.arange(dim)
        named = action_blocks(action, self.block_names)
        if not named:
            return "none", np.zeros(0, dtype=np.int64)
        k, n_blocks = named[0], len(self.block_names)
        return self.block_names[k], np.array([j * n_blocks + k for j in range(self.n_properties)])

    # ----------------------------------------------------------------- checkpoints
    def to_dict(self) -> dict:
        return {"model_error": self.model_error.to_dict(), "lock_in": self.lock_in.to_dict()}

    def load(self, data: dict | None) -> None:
        """Restore `to_dict`'s state (None: a checkpoint from before issue 24, a fresh state)."""
        data = data or {}
        self.model_error = ModelError.from_dict(data.get("model_error"), self.sensor_sigma)
        self.lock_in = LockInMonitor.from_dict(data.get("lock_in"), slow=self.config.lock_in_slow,
                                               fast=self.config.lock_in_fast)
