"""An outcome is a sample (``perception_samples``, docs/LOOP.md): where the particle worlds
disagree about a step, each is replayed at more perceptions of the start, common to every
row, and weighed by the share that agreed with reality.

A filter-only stand-in world whose push succeeds 90 % of the time at every size (which
worlds fail is a jagged function of the row and the start, as a pile's push is in the
container's physics) and whose pickups read the size with the sensor's noise: the exact
posterior is the readings' alone. Scored one replay at a time, the rare failures cut random
rows at 19:1 and the posterior drifts off the truth; weighed over three perceptions it is
calibrated. A threshold of the physics (worlds above a size fail, whatever the
perception) keeps its information unchanged.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.domains import load
from coordinator.loop.particle_worlds import perception_draws
from coordinator.loop.session import Session
from coordinator.particle_filter.resample_move import RealStep
from coordinator.run_config import PRE_ISSUE_37_FILTER, RunConfig, stored_run_config
from sim_workers.configuration import Configuration

SIGMA = 0.002
N = 16
OK = frozenset({"ok"})
CONTAINER = load("container").physics


class _Planned:
    expected = OK


def _world(start: np.ndarray, rows: np.ndarray, action: str, threshold: float | None) -> dict:
    rows = np.asarray(rows)
    meas = np.full((len(rows), 17), np.nan)
    if action.startswith("pickup"):
        meas[:, 0] = rows[:, 0]
        ok = np.ones(len(rows), dtype=bool)
    else:
        meas[:, 0] = 0.085
        if threshold is None:        # a chance: which rows fail depends on the start, jaggedly
            h = float(np.sum(start[:40])) * 1e4
            ok = np.array([(math.sin(r * 1.3e5 + h) * 43758.5453) % 1.0 < 0.9 for r in rows[:, 0]])
        else:
            ok = rows[:, 0] < threshold
    return {"states": [OK if o else frozenset() for o in ok], "measurements": meas, "steps": np.ones(len(rows))}


def _simulator(seed: int, threshold: float | None):
    """The particle worlds as the session calls them, perception draws included."""
    def simulate(start, rows, action, trajectory, start_time, samples=1, first=None):
        out = dict(first) if first is not None else _world(start, rows, action, threshold)
        if samples > 1:
            out["perception"] = [(lw, out if st is None else _world(st, rows, action, threshold))
                                 for lw, st in perception_draws(CONTAINER, samples, SIGMA, start, action, seed)]
        out["particle_actions"] = len(rows) * samples
        out["particle_steps"] = len(rows) * samples
        return out
    return simulate


def _run(seed: int, samples: int, threshold_offset: float | None = None, readings: int = 24) -> tuple[float, float]:
    """One run's z against the truth and its std over the exact posterior's."""
    s = Session(RunConfig(particles=N, seed=seed, particle_budget="fixed", perception_samples=samples))
    rng = np.random.default_rng(seed + 100)
    truth = 0.035 + 0.020 * rng.random()
    threshold = None if threshold_offset is None else truth + threshold_offset
    simulate = _simulator(seed, threshold)
    start0 = CONTAINER.initial_configuration({"block_sizes": np.full(8, 0.045)}).to_array()
    reads = []
    for _ in range(readings):
        for action in ("pickup(r,b1,init)", "push(r,c,init,goal)", "push(r,c,init,goal)"):
            start = start0.copy()
            start[12:14] += rng.normal(0, 0.01, 2)
            obs = np.full(17, np.nan)
            if action.startswith("pickup"):
                obs[0] = truth + rng.normal(0, SIGMA)
                reads.append(obs[0])
                real = OK
            else:
                obs[0] = 0.085 + rng.normal(0, SIGMA)
                real = OK if threshold is not None or rng.random() < 0.9 else frozenset()
            res = simulate(start, s.belief.particles, action, None, 0.0)
            sym = s._symbolic_loglik(_Planned(), real, res["states"])
            k = s._samples(res, sym)
            if k > 1:
                res = simulate(start, s.belief.particles, action, None, 0.0, samples=k, first=res)
            nodes = ([(lw, s._symbolic_loglik(_Planned(), real, r["states"]), r["measurements"])
                      for lw, r in res["perception"]] if res.get("perception") else None)
            step = RealStep(start, action, np.zeros((2, 6)), 0.0, OK, real, obs, None, k)
            s.filter.update(step, sym, res["measurements"], s.rng, simulate, s._symbolic_loglik, nodes)
    grid = np.linspace(0.03, 0.06, 30001)
    log_p = sum(-0.5 * ((r - grid) / SIGMA) ** 2 for r in reads)
    if threshold is not None:
        log_p = log_p + np.where(grid < threshold, 0.0, 2 * readings * math.log(0.05 / 0.95))
    w = np.exp(log_p - log_p.max())
    w /= w.sum()
    exact_mean = float(w @ grid)
    exact_std = math.sqrt(float(w @ (grid - exact_mean) ** 2))
    mean, std = float(s.belief.mean()[0]), float(s.belief.std()[0])
    return (mean - truth) / std, std / exact_std


def test_a_chance_outcome_weighed_over_perceptions_keeps_the_posterior_calibrated():
    """40 truths across the prior, 24 readings and 48 pushes each: one replay per step leaves
    mean z^2 2.4 and 33 of 40 covered (median sharpness 0.93, one run at 0.17); three
    perceptions give 0.95 and 38 of 40, as the readings alone do (0.85, 38)."""
    def judged(samples: int) -> tuple[float, int, float]:
        z, sharp = map(np.array, zip(*[_run(seed, samples) for seed in range(40)]))
        return float(np.mean(z ** 2)), int(np.sum(np.abs(z) <= 2)), float(np.min(sharp))

    one, three = judged(1), judged(3)
    assert one[0] > 2.0 and one[1] <= 34 and one[2] < 0.3, one
    assert 0.5 <= three[0] <= 1.5 and three[1] >= 37 and three[2] > 0.5, three


def test_a_threshold_of_the_physics_keeps_its_information():
    """Worlds above a size 0.3 mm over the truth fail, at every perception: the steps are
    weighed exactly as with one replay (every perception agrees), row for row."""
    for seed in range(6):
        assert _run(seed, 3, threshold_offset=0.0003) == _run(seed, 1, threshold_offset=0.0003)


def test_perception_draws_are_a_fixed_function_of_the_step():
    """The perceived start first, then k - 1 perceptions of every movable object, equally
    weighted, the same whenever the step is replayed and another for another start."""
    start = CONTAINER.initial_configuration({"block_sizes": np.full(8, 0.045)}).to_array()
    draws = perception_draws(CONTAINER, 3, SIGMA, start, "push(r,c,init,goal)", 7)
    assert [lw for lw, _ in draws] == pytest.approx([-math.log(3)] * 3)
    assert draws[0][1] is None and all(st is not None for _, st in draws[1:])
    again = perception_draws(CONTAINER, 3, SIGMA, start.copy(), "push(r,c,init,goal)", 7)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(draws[1:], again[1:]))
    moved = start.copy()
    moved[12] += 1e-3
    other = perception_draws(CONTAINER, 3, SIGMA, moved, "push(r,c,init,goal)", 7)
    assert not np.array_equal(other[1][1][12:14] - moved[12:14], draws[1][1][12:14] - start[12:14])
    before, after = Configuration.from_array(start), Configuration.from_array(draws[1][1])
    delta = after.objects - before.objects
    assert np.array_equal(after.robot, before.robot) and np.all(delta[:, 2:] == 0)
    movable = list(CONTAINER.jittered_objects)
    assert np.all(delta[movable, :2] != 0) and not np.any(np.delete(delta, movable, axis=0))
    assert perception_draws(CONTAINER, 1, SIGMA, start, "push(r,c,init,goal)", 7) == []
    assert perception_draws(CONTAINER, 3, 0.0, start, "push(r,c,init,goal)", 7) == []


def test_only_a_step_the_worlds_disagree_on_is_replayed_again():
    s = Session(RunConfig(particles=4, seed=0, particle_budget="fixed", perception_samples=3))
    agree, split = np.full(4, math.log(0.95)), np.log([0.95, 0.05, 0.95, 0.95])
    assert s._samples({}, agree) == 1 and s._samples({}, split) == 3
    assert s._samples({"perception": [(0.0, {})]}, split) == 1          # the quadrature's step
    assert Session(RunConfig(particles=4, seed=0, particle_budget="fixed"))._samples({}, split) == 1


def test_stored_configs_keep_the_one_replay():
    assert stored_run_config({}).perception_samples == 1
    assert PRE_ISSUE_37_FILTER["perception_samples"] == 1
    with pytest.raises(ValueError, match="perception_samples"):
        RunConfig(perception_samples=0)
