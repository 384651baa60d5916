"""Perception in the likelihood (issue 37): each particle world's outcome integrated over
the robot's perception error, by Gauss-Hermite quadrature.

The particle worlds replay an action from the perceived configuration, so they meet the
object exactly where the plan aimed; the real gripper meets it off by the perception
error. Where that error decides the outcome (a grasp with little clearance), a world that
grasps at the perceived pose predicts success with certainty, a real failure by
misalignment has no explanation but a wrong L, and one such failure moved a 57.9 mm
belief to 34 +- 2 mm (docs/LOOP.md, "Perception in the likelihood"). The likelihood
of an observation y under L_i is really

    p(y | L_i) = E_e[ p(y | world_i at error e) ],   e ~ N(0, sigma_p^2) along the axis,

an expectation over the error component that matters (the domain's ``misalignment``:
one object, one planar axis). One random draw of e per particle (a pseudo-marginal
estimate) made the weights follow the draws' luck and broke calibration; a K-node
Gauss-Hermite rule evaluates the same expectation deterministically, every particle at the
same nodes, exact for outcomes polynomial in e up to degree 2K - 1. The nodes are the
probabilists' Hermite roots x_k with weights w_k / sqrt(2 pi) (summing to 1): K = 3
gives e = 0, +-sqrt(3) sigma_p at 2/3, 1/6, 1/6. The cost is K worlds per particle for
the actions the domain names (pickups in the block domains), nothing for the others.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["gauss_hermite", "mixture_log_likelihood"]


def gauss_hermite(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes (in standard deviations) and log-weights (summing to 1) of the `n`-point rule
    for E[f(e)], e ~ N(0, 1); n odd, so that node 0 (the perceived pose itself) is one.

    >>> x, lw = gauss_hermite(3)
    >>> [round(float(v), 4) for v in x], [round(float(v), 4) for v in np.exp(lw)]
    ([-1.7321, 0.0, 1.7321], [0.1667, 0.6667, 0.1667])
    """
    if n < 1 or n % 2 == 0:
        raise ValueError(f"perception nodes: need an odd count >= 1, got {n}")
    x, w = np.polynomial.hermite_e.hermegauss(n)
    w = w / w.sum()
    x[np.argmin(np.abs(x))] = 0.0          # exactly the perceived pose
    return x, np.log(w)


def mixture_log_likelihood(parts: Sequence[tuple[float, np.ndarray]]) -> np.ndarray:
    """log sum_k w_k p_k(y) per particle, from (log w_k, log p_k(y)) per node.

    >>> lw = np.log([0.5, 0.5])
    >>> [round(float(v), 4) for v in mixture_log_likelihood([(lw[0], np.log([1.0, 0.2])), (lw[1], np.log([0.0 + 1e-300, 0.2]))])]
    [-0.6931, -1.6094]
    """
    stacked = np.vstack([np.asarray(ll, dtype=np.float64) + float(lw) for lw, ll in parts])
    return np.logaddexp.reduce(stacked, axis=0)
