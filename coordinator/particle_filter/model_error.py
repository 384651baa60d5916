"""How far the particle worlds are from the real one, per weighed channel, measured online.

The measurement likelihood's sigma is the sensor's. The particle worlds are not reality
(the simulated reality jitters friction and placement every episode, a real robot differs
in more ways), so a likelihood with the sensor's sigma alone treats model error as
information and the posterior ends confidently wrong. Here the likelihood's variance per
channel is ``sigma_sensor^2 + sigma_model^2``, sigma_model chosen so that the normalised
innovations of the belief's predictions,

    z_t^2 = (y_t - E_w[f(L)])^2 / (Var_w[f(L)] + sigma_sensor^2 + sigma_model^2),

(the weights w before observation t: the predictive distribution) have the median of a
chi-square with one degree of freedom (0.455), as they would if the belief's predictive
distribution were right. The session counts the innovations of observations whose symbolic
outcome every particle predicted (one regime: a grasp that closed on air where particles
grasp is a mixture of regimes, not model error). The median, not the mean: an outlier that no particle explains
(the robust likelihood's business) moves it by one rank, not by its square. sigma_model is
0 until ``MIN_COUNT`` observations of the channel and whenever the innovations are no
larger than the sensor explains; only a scatter of residuals inflates it (a constant bias
is indistinguishable from a different L, and the posterior absorbs it).

Deterministic (a function of the observations), and checkpointed with the session.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["CHI2_1_MEDIAN", "MIN_COUNT", "ModelError"]

CHI2_1_MEDIAN = 0.454936423119572     # median of a chi-square with one degree of freedom
MIN_COUNT = 10                        # innovations of a channel before sigma_model is estimated
MAX_HISTORY = 400                     # the latest innovations kept per channel ("online")
# "centered" (issue 37): the latest innovations kept per channel. The median of 40 chi-square
# draws has a relative standard error of about 1.25 / (sqrt(40) x 0.455 x f) ~ 0.2, fine for a
# sigma that enters the likelihood squared; a belief that moves forgets its old residuals
# within about one episode's readings (the container: ~16 weighed readings an episode).
CENTERED_HISTORY = 40
# The innovation test's window and threshold (`bias_z`): the last 8 innovations of a
# channel (the resample-move's window, coordinator.particle_filter.resample_move.MOVE_WINDOW), and 3: under a
# calibrated belief their normalised sum is standard normal, so |z| > 3 has probability
# 0.0027 per reading (about one needless, harmless move in 400 readings).
BIAS_WINDOW = 8
BIAS_Z = 3.0


def model_variance(r2: np.ndarray, v: np.ndarray, sensor_var: float) -> float:
    """The sigma_model^2 >= 0 for which median(r2 / (v + sensor_var + sigma_model^2)) is
    the chi-square median (bisection; the median falls as sigma_model grows).

    >>> rng = np.random.default_rng(0)
    >>> r = rng.normal(0.0, 0.003, 2000)     # 3 mm residuals, a 2 mm sensor: sqrt(9 - 4) = 2.24 mm
    >>> round(float(np.sqrt(model_variance(r * r, np.zeros(2000), 0.002 ** 2))), 4)
    0.0023
    """
    def med(c: float) -> float:
        return float(np.median(r2 / (v + c)))

    if r2.size < MIN_COUNT or med(sensor_var) <= CHI2_1_MEDIAN:
        return 0.0
    lo, hi = 0.0, float(np.max(r2)) / CHI2_1_MEDIAN + sensor_var
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if med(sensor_var + mid) > CHI2_1_MEDIAN:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass
class ModelError:
    """Innovations (r^2, predictive variance) per weighed channel, and the sigma they imply."""

    sensor_sigma: np.ndarray                       # (C,) the sensors' sigma per weighed channel
    history: list[list[list[float]]] = field(default_factory=list)   # per channel: [r^2, v] rows
    # centered: rows are [r, v] with r signed, and sigma_model comes from the innovations'
    # scatter about their median: a belief biased by b reads r ~ b + noise, which says L is
    # off (the posterior's business), not that the worlds scatter (issue 37: a belief 7.5 mm
    # off read as 7.6 mm of model error, slowing the recovery it needed).
    centered: bool = False
    _model_sigma: np.ndarray | None = field(default=None, repr=False)   # cache of the estimate

    def __post_init__(self) -> None:
        self.sensor_sigma = np.asarray(self.sensor_sigma, dtype=np.float64).reshape(-1)
        if not self.history:
            self.history = [[] for _ in self.sensor_sigma]
        if len(self.history) != self.sensor_sigma.size:
            raise ValueError("model error: one history per channel")

    @property
    def model_sigma(self) -> np.ndarray:
        """(C,) sigma_model per channel (estimated when first asked after new data)."""
        if self._model_sigma is None:
            self._model_sigma = self._estimate()
        return self._model_sigma

    def sigma(self) -> np.ndarray:
        """The likelihood's sigma per channel: sqrt(sensor^2 + model^2)."""
        return np.sqrt(self.sensor_sigma ** 2 + self.model_sigma ** 2)

    def observe(self, observed: np.ndarray, predicted: np.ndarray, weights: np.ndarray) -> None:
        """Add the innovation of each measured channel (`observed` (C,), NaN: not measured;
        `predicted` (N, C); `weights` (N,) before the update) and re-estimate."""
        obs = np.asarray(observed, dtype=np.float64).reshape(-1)
        pred = np.asarray(predicted, dtype=np.float64).reshape(-1, obs.size)
        w = np.asarray(weights, dtype=np.float64)
        w = w / w.sum()
        keep = CENTERED_HISTORY if self.centered else MAX_HISTORY
        for c in np.flatnonzero(~np.isnan(obs)):
            mean = float(w @ pred[:, c])
            var = float(w @ (pred[:, c] - mean) ** 2)
            r = obs[c] - mean
            self.history[c].append([float(r) if self.centered else r ** 2, var])
            del self.history[c][:-keep]
        self._model_sigma = None

    def _estimate(self) -> np.ndarray:
        out = np.zeros(self.sensor_sigma.size)
        for c, rows in enumerate(self.history):
            if rows:
                a = np.asarray(rows, dtype=np.float64)
                r2 = (a[:, 0] - np.median(a[:, 0])) ** 2 if self.centered else a[:, 0]
                out[c] = np.sqrt(model_variance(r2, a[:, 1], float(self.sensor_sigma[c]) ** 2))
        return out

    def bias_z(self, window: int = BIAS_WINDOW) -> float:
        """The largest |sum r_t| / sqrt(sum (Var_w f + sigma^2)) over the channels' last
        `window` innovations (centred mode only; 0 with fewer): the filter-consistency test
        of the innovations' mean (Bar-Shalom, Li and Kirubarajan, 5.4). A calibrated belief's
        innovations are independent with those variances, so this is standard normal; a
        belief that has collapsed a reading or more away from the truth (every particle
        alike, so no reading can move it) reads readings on one side, and it grows as
        sqrt(window) x bias / sigma."""
        if not self.centered:
            return 0.0
        sigma2 = self.sigma() ** 2
        worst = 0.0
        for c, rows in enumerate(self.history):
            if len(rows) >= window:
                a = np.asarray(rows[-window:], dtype=np.float64)
                worst = max(worst, abs(float(a[:, 0].sum())) / float(np.sqrt(np.sum(a[:, 1] + sigma2[c]))))
        return worst

    def to_dict(self) -> dict:
        """The innovations (the estimate is a function of them)."""
        return {"sensor_sigma": self.sensor_sigma.tolist(), "history": self.history,
                "centered": self.centered}

    @classmethod
    def from_dict(cls, data: dict | None, sensor_sigma: np.ndarray, centered: bool = False) -> "ModelError":
        """From `to_dict`; None (an old checkpoint), another channel set or another kind of
        innovation: a fresh one."""
        sensor = np.asarray(sensor_sigma, dtype=np.float64).reshape(-1)
        if (data is None or bool(data.get("centered", False)) != centered
                or not np.array_equal(np.asarray(data["sensor_sigma"], dtype=np.float64), sensor)):
            return cls(sensor, centered=centered)
        return cls(sensor, [[list(map(float, row)) for row in rows] for rows in data["history"]],
                   centered=centered)
