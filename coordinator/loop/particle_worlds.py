"""The particle worlds as the loop sees them: one call simulates an action in the grounded
world of every row of L (the shard pool's), at the perceived configuration and, where the
domain declares the action sensitive to perception, at each quadrature node of the
perception error (``coordinator.particle_filter.perception``); and what they predicted, for
the observers that draw it."""
from __future__ import annotations

import math
import zlib

import numpy as np

from sim_workers.configuration import Configuration
from sim_workers.reality_gap import perceived_planar

from ..particle_filter.perception import gauss_hermite
from .observer import Prediction

__all__ = ["simulate_rows", "perception_nodes", "perception_draws", "predictions"]


def simulate_rows(pool, domain, config, start: np.ndarray, rows: np.ndarray, action: str, trajectory,
                  start_time, arm=None, samples: int = 1, first: dict | None = None) -> dict:
    """The shards' result at the perceived configuration `start`, with ``particle_actions``
    and ``particle_steps`` spent and, where the domain declares the action sensitive to
    perception (``misalignment``), ``perception``: (log weight, result) at each Gauss-Hermite
    node of the perception error, the perceived pose's own result among them. `config` is
    the run's (``perception_nodes``, ``perception_sigma``); `arm` an arm's joints the worlds
    move its links along (``sim_workers.robots.motion.ArmMotion``), None for the gripper.
    `samples` > 1 (``perception_samples``; where no quadrature node applies): the same at
    `samples` - 1 more perceptions as well (``perception_draws``), ``perception`` the
    equally weighted results. `first`: the perceived start's result, already simulated."""
    extra = {} if arm is None else {"arm": arm}
    out = dict(first) if first is not None else dict(pool.simulate(start, rows, action, trajectory, start_time,
                                                                   **extra))
    results = [out]
    shifted = perception_nodes(domain, config.perception_nodes, config.perception_sigma, start, action)
    if not shifted and samples > 1:
        shifted = perception_draws(domain, samples, config.perception_sigma, start, action, config.seed)
    if shifted:
        out["perception"] = []
        for lw, node_start in shifted:
            r = out if node_start is None else pool.simulate(node_start, rows, action, trajectory, start_time,
                                                             **extra)
            if node_start is not None:
                results.append(r)
            out["perception"].append((lw, r))
    out["particle_actions"] = len(rows) * len(results)
    out["particle_steps"] = int(sum(int(np.asarray(r["steps"]).sum()) for r in results))
    return out


def perception_nodes(domain, n: int, sigma: float, start: np.ndarray,
                     action: str) -> list[tuple[float, np.ndarray | None]]:
    """(log weight, start) per quadrature node of the perception error along the domain's
    ``misalignment`` axis, None for the perceived start itself; [] where the action is not
    perception-sensitive or the run integrates nothing (`n` <= 1 or `sigma` <= 0)."""
    if n <= 1 or sigma <= 0.0:
        return []
    where = domain.misalignment(Configuration.from_array(start), action)
    if where is None:
        return []
    row, axis = where
    x, log_w = gauss_hermite(n)
    out = []
    for xk, lw in zip(x.tolist(), log_w.tolist()):
        if xk == 0.0:
            out.append((lw, None))
            continue
        config = Configuration.from_array(start)
        objects = config.objects.copy()
        objects[row, :2] += xk * sigma * np.asarray(axis, dtype=np.float64)
        out.append((lw, Configuration(config.robot, objects).to_array()))
    return out


def perception_draws(domain, k: int, sigma: float, start: np.ndarray, action: str,
                     seed: int) -> list[tuple[float, np.ndarray | None]]:
    """(log weight, start) of `k` equally weighted perceptions of the step: the perceived
    start itself (None) and `k` - 1 with every movable object's planar position moved by
    N(0, sigma^2) per axis, common to every row of L. The draws come from a generator
    seeded by the run's seed, the action and the start configuration, so that a step's
    draws are the same whenever it is replayed (the resample-move's window re-scores it
    as the update did) and on every shard; [] for `k` <= 1 or `sigma` <= 0."""
    if k <= 1 or sigma <= 0.0:
        return []
    start = np.ascontiguousarray(start, dtype=np.float64)
    entropy = [int(seed) % (1 << 63), zlib.crc32(action.encode()), zlib.crc32(start.tobytes())]
    rng = np.random.default_rng(np.random.SeedSequence(entropy))
    config = Configuration.from_array(start)
    lw = -math.log(k)
    out: list[tuple[float, np.ndarray | None]] = [(lw, None)]
    for _ in range(k - 1):
        objects = perceived_planar(rng, config.objects, domain.jittered_objects, sigma)
        out.append((lw, Configuration(config.robot, objects).to_array()))
    return out


def predictions(match: str, expected: frozenset[str], observed: frozenset[str], res: dict,
                weights: np.ndarray, rows: np.ndarray) -> Prediction:
    """What the worlds of `res` predicted, as the likelihood matched it against `observed`
    (`match` "state": the whole symbolic state; else whether the planned effect happened),
    with the weights before the update (copies: observers only read)."""
    if match == "state":
        matched = [s == observed for s in res["states"]]
    else:
        real_ok = observed == expected
        matched = [(s == expected) == real_ok for s in res["states"]]
    return Prediction(np.array(res["configurations"], copy=True), list(res["states"]),
                      np.asarray(weights).copy(), np.array(matched, dtype=bool), np.asarray(rows).copy())
