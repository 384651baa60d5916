"""Calibration on a small grid (issue 24): the posterior's +-2 std holds the truth across
the prior, in both domains, with the realistic 3.5 N wrist sensor included. The sweep
(`benchmarks/bench_learning.py`) measures coverage over the whole grid; this checks the
mechanism at a small scale. Real pybullet, clingo and the session's two-CPU Ray."""
from __future__ import annotations

import math

import pytest

from coordinator.domains import load
from coordinator.experiments.sweep import COVERAGE_Z
from coordinator.experiments.tails import true_row
from coordinator.run_config import RunConfig
from coordinator.loop.runner import run

# (domain, true size in m, truth by name beyond the size, domain options): the prior's two
# ends and its middle for the container; stack-and-push with the density unknown at both
# ends of its prior, read by the precise and by the realistic sensor.
GRID = [
    ("container", 0.033, {}, {}),
    ("container", 0.045, {}, {}),
    ("container", 0.057, {}, {}),
    ("stack_and_push", 0.050, {"density": 900.0}, {"unknown_density": True, "force_sigma": 0.1}),
    ("stack_and_push", 0.038, {"density": 2200.0}, {"unknown_density": True, "force_sigma": 3.5}),
]


@pytest.mark.usefixtures("ray_cluster")
@pytest.mark.slow
@pytest.mark.timeout(1200)
def test_posteriors_cover_the_truth_across_a_small_grid():
    zs, sharp = [], []
    for domain, size, truth, options in GRID:
        cfg = RunConfig(domain=domain, n_blocks=4, true_size=size, truth=truth, options=options,
                        particles=12, particle_budget="fixed", episodes=2, seed=1, max_steps=40,
                        counterfactual_rows=0)      # calibration, not T's prior: the paper's loop
        result = run(cfg)
        posterior = result["episodes"][-1]["posterior"]
        L = load(domain, n_blocks=4, **options).physics.L
        prior_std = {n: (float(hi) - float(lo)) / math.sqrt(12.0) for n, lo, hi in zip(L.names, L.low, L.high)}
        for name, _, t, mean, std in true_row(result["config"], posterior):
            zs.append((domain, size, name, abs(mean - t) / std if std > 0 else float("inf")))
            sharp.append((domain, size, name, std / prior_std[name]))
    covered = [z for z in zs if z[-1] <= COVERAGE_Z]
    # Every entry within 2 std but at most two, and none beyond 3 std. For a calibrated
    # posterior (z ~ N(0, 1)) over the 7 entries that fails 2.3 % of the time (3 or more
    # misses: 0.4 %; some |z| > 3: 1.9 %); for one twice as confident as it should be
    # (z ~ N(0, 4)) it fails about 3 times in 4 (each entry misses 2 std with 32 %, exceeds
    # 3 std with 13 %). The rule it replaces (at most one miss, none beyond 4 std) failed a
    # calibrated posterior 4.4 % of the time with about the same power: at seed 1 the
    # container's 33 and 45 mm entries end 2.32 and 2.25 std off (12 particles, 2
    # episodes; over seeds 1-4 at 33, 45 and 57 mm: 2 misses of 12, the largest 2.32; at
    # the 1.15 sides' grasp 2 of 12 too, the largest 2.39).
    assert len(covered) >= len(zs) - 2, zs
    assert max(z[-1] for z in zs) < 3.0, zs
    # ... and the posterior learned: a posterior as wide as the prior covers every truth
    # (issue 37: this test passed one). Two episodes pin the size to a few per cent of the
    # prior's std, and the density read by the precise 0.1 N sensor to under half of it.
    # (Not through the 3.5 N wrist: measured over seeds 1-4 it ends at 0.36-0.97 of the
    # prior's std after two episodes.)
    assert max(s[-1] for s in sharp if s[2] == "size") < 0.15, sharp
    assert max(s[-1] for s in sharp if s[2] == "density" and s[1] == 0.050) < 0.5, sharp
    # ... and not collapsed through the 3.5 N wrist: with the Liu-West kernel's bandwidth
    # from the particle count, a resample after a topple kept two density values on an
    # Intel Xeon (2657 +- 86 kg/m^3 for 2200, 0.11 of the prior's std, z 5.3); the
    # bandwidth from the ESS (the default) ended at 1828 +- 464 (docs/LOOP.md).
    assert min(s[-1] for s in sharp if s[2] == "density" and s[1] == 0.038) >= 0.2, sharp
