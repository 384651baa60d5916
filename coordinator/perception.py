"""Where the perceived objects truly are, as the particle worlds start from them.

A robot perceives the planar position of each movable object with noise of a declared std
(``RunConfig.perception_sigma``, per axis; the simulated reality adds exactly that). The
action's trajectory is computed from the perceived positions, so in the real world the
gripper meets each object off by the perception error. A particle world that started
from the perceived positions themselves would meet every object exactly where the plan
aimed: it predicts a grasp with a few millimetres of clearance to succeed every time,
and when the real one fails for the misalignment, the failure is charged to L (the
large-block runs of issue 37: one such failure moved the belief from the truth, 57.9 mm,
to 34 mm, and eight failed pickups followed).

Each particle world therefore starts from its own draw of the true positions given the
perceived ones, N(perceived, sigma^2) per axis (the posterior of a position under a flat
prior and Gaussian perception), heights and orientations as perceived. Its outcome is
then a one-sample Monte Carlo estimate of the outcome marginalised over perception, so
the likelihood of a real outcome under a row of L is the probability that the action
succeeds at that L *given the robot's perception* (a pseudo-marginal likelihood: unbiased,
and the filter's resampling averages its noise over steps). The draws come from the
session's seeded generator, before the fan-out, so shards and machines change nothing.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from sim_workers.configuration import Configuration
from sim_workers.reality_gap import perceived_planar

__all__ = ["world_starts"]


def world_starts(start: np.ndarray, n: int, objects: Sequence[int], sigma: float,
                 rng: np.random.Generator) -> np.ndarray:
    """`n` starting configurations (n, D) for the particle worlds: the perceived `start`
    (D,) with the planar position of each of `objects` drawn N(perceived, sigma^2) per
    axis, one draw per world. With sigma 0 (or no objects): `start` itself (D,), no draw."""
    start = np.asarray(start, dtype=np.float64)
    rows = list(objects)
    if sigma <= 0 or not rows or n <= 0:
        return start
    config = Configuration.from_array(start)
    out = np.empty((n, start.size), dtype=np.float64)
    for i in range(n):
        out[i] = Configuration(config.robot, perceived_planar(rng, config.objects, rows, sigma)).to_array()
    return out
