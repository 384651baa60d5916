"""The move's early rejection (``resample_move.mh_move`` with ``step_bound``): the rows,
the accepted count and every later draw are those of the full replay, for fewer
particle-actions; and the bound it rejects against is a bound."""
from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.particle_filter.resample_move import KernelDensity, RealStep, mh_move
from coordinator.particle_filter.reweighting import Reweighting
from coordinator.run_config import RunConfig

SIGMA = 0.002
ERR = 0.05


def _world(start, rows, action, trajectory, start_time) -> dict:
    """A grasp that holds where the believed size (trajectory[0, 0]) fits the block, and
    reads the block's size as the opening when it holds, 0 when it does not."""
    size = np.asarray(rows, dtype=np.float64)[:, 0]
    believed = float(trajectory[0, 0])
    held = (1.25 * believed > size) & (believed - 0.010 < size - 0.001)
    meas = np.full((len(size), 2), np.nan)
    meas[:, 0] = np.where(held, size, 0.0)
    return {"states": [frozenset({"held"}) if h else frozenset() for h in held], "measurements": meas}


def _step(believed: float, held: bool, opening: float) -> RealStep:
    obs = np.array([opening if held else 0.0, np.nan])
    return RealStep(np.zeros(1), "pickup(r,b1,init)", np.array([[believed, 0, 0, 0, 0, 0.0]]), 0.0,
                    frozenset({"held"}), frozenset({"held"}) if held else frozenset(), obs)


def _reweighting(rule: str = "own") -> Reweighting:
    return Reweighting(RunConfig(disagreement_readings=rule), (np.array([0]), np.array([SIGMA])), ["b1"], 1, per_block=False)


def _counting(spent: list[int]):
    def simulate(start, rows, *args):
        spent[0] += len(rows)
        return _world(start, rows, *args)
    return simulate


def _loglik(rw: Reweighting):
    def step_ll(st: RealStep, res: dict) -> np.ndarray:
        hit = np.array([s == st.observed for s in res["states"]])
        return rw.log_likelihood(np.where(hit, math.log1p(-ERR), math.log(ERR)), st.measurements,
                                 res["measurements"])[0]
    return step_ll


WINDOW = [_step(0.045, True, 0.0431), _step(0.034, False, 0.0), _step(0.045, True, 0.0428),
          _step(0.052, False, 0.0), _step(0.045, True, 0.0435)]


@pytest.mark.parametrize("rule", ["own", "departure", "profile"])
@pytest.mark.parametrize("target", ["prior", "belief"])
def test_early_rejection_moves_every_row_as_the_full_replay_for_fewer_particle_actions(rule, target):
    rw = _reweighting(rule)
    lo, hi = np.array([0.030]), np.array([0.060])
    rows0 = np.random.default_rng(7).normal(0.0431, 0.0012, (32, 1))     # where the belief is
    before = (None if target == "prior"
              else KernelDensity.of(rows0, np.full(32, -math.log(32)), 0.4, np.array([1e-4])))
    out = {}
    for screened in (False, True):
        spent = [0]
        rng = np.random.default_rng(11)
        rows, accepted = mh_move(rows0, np.array([0]), lo, hi, np.array([0.003]), WINDOW, _counting(spent),
                                 _loglik(rw), rng, sweeps=8, before=before,
                                 step_bound=(lambda st: rw.log_likelihood_bound(st.measurements)) if screened else None)
        out[screened] = rows, accepted, spent[0], rng.random()
    (rows_f, acc_f, spent_f, next_f), (rows_s, acc_s, spent_s, next_s) = out[False], out[True]
    assert np.array_equal(rows_f, rows_s) and acc_f == acc_s and next_f == next_s
    assert acc_f > 0
    # 8 sweeps replaying 5 steps: 2 x 32 x 5 + 7 x 32 x 5 = 1440 in full.
    assert spent_f == 1440 and spent_s < 0.75 * spent_f, (spent_f, spent_s)


@pytest.mark.parametrize("rule", ["own", "departure", "profile"])
@pytest.mark.parametrize("outlier_rate", [0.0, 0.05])
def test_the_bound_is_above_every_rows_log_likelihood(rule, outlier_rate):
    """Predictions spanning exact to far off, matched or not, under every readings' rule:
    none scores above the bound, and an exact, matched prediction reaches it."""
    rw = Reweighting(RunConfig(disagreement_readings=rule, outlier_rate=outlier_rate),
                     (np.array([0, 1]), np.array([SIGMA, 0.5])), ["b1"], 1, per_block=False)
    rng = np.random.default_rng(0)
    observed = np.array([0.041, 3.0, np.nan])
    pred = np.column_stack([0.041 + rng.normal(0, 0.02, 400), 3.0 + rng.normal(0, 5.0, 400), np.zeros(400)])
    pred[0, :2] = observed[:2]
    sym = np.where(rng.random(400) < 0.5, math.log1p(-ERR), math.log(ERR))
    sym[0] = math.log1p(-ERR)
    ll = rw.log_likelihood(sym, observed, pred)[0]
    bound = rw.log_likelihood_bound(observed)
    assert np.all(ll <= bound + 1e-12)
    assert ll[0] == pytest.approx(bound) or rule == "departure" and outlier_rate == 0.0
