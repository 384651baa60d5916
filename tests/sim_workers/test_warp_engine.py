"""The MuJoCo Warp batch engine against CPU MuJoCo (issue 42, item 5).

The same particles (sizes across the prior) and the same trajectories through a
``Shard`` in each engine: the outcome tables must match. Warp computes in float32 and
is not bit-identical (``sim_workers/engines/warp_batch.py``), so the judge is the one the
engines face against each other: per action, the same symbolic outcome for (nearly)
every particle, the same counts of the action's intended effect within sampling error,
and the weighed channel (the grasp width) within a fraction of its sensor sigma. Runs on
Warp's CPU device (its kernels compile once per machine, ~30 s, then come from Warp's
cache); on a machine with a GPU, on the GPU.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

# Found, not imported: importing Warp costs 1.4 s, and collection runs on every worker.
if importlib.util.find_spec("mujoco_warp") is None:
    pytest.skip("the warp extra (pip install 'tmoc-service[warp]') is part of [test]", allow_module_level=True)

from sim_workers.domains import load  # noqa: E402
from sim_workers.engines import BATCH_ENGINES, EngineError, check_engine  # noqa: E402
from sim_workers.shard import Shard  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from bench_worlds import make_cases  # noqa: E402

N = 12
EFFECT = {"pickup": "is_holding(r,b3)", "stack": "on(b3,", "push": "in(c,goal)"}


def _sizes(domain, n: int) -> np.ndarray:
    """Sizes spread over the prior (its ends included), one per particle, shared by its blocks."""
    s = np.linspace(domain.spec.prior_low, domain.spec.prior_high, n)
    return np.repeat(s[:, None], domain.spec.n_blocks, axis=1)


@pytest.fixture(scope="module")
def tables():
    domain = load("container", engine="mujoco")
    cases = make_cases(domain, 0)
    sizes = _sizes(domain, N)
    cpu, warp = Shard("container", {"engine": "mujoco"}), Shard("container", {"engine": "mujoco_warp"})
    try:
        out = {kind: (cpu.simulate(start, sizes, action, traj, t0), warp.simulate(start, sizes, action, traj, t0))
               for kind, (start, action, traj, t0) in cases.items()}
        steps = warp._batch.kernel_steps
    finally:
        cpu.close()
        warp.close()
    return out, steps


def test_the_batch_engine_is_registered_apart_from_the_bit_identical_ones():
    assert "mujoco_warp" in BATCH_ENGINES and check_engine("mujoco_warp") == "mujoco_warp"
    with pytest.raises(EngineError, match="unknown engine 'warp'.*mujoco_warp"):
        check_engine("warp")


@pytest.mark.slow
@pytest.mark.timeout(600)          # a cold Warp kernel cache compiles for ~30 s on 2 cores
@pytest.mark.parametrize("kind", ["pickup", "stack", "push"])
def test_warp_outcome_tables_match_cpu_mujoco(tables, kind):
    out, steps = tables
    cpu, warp = out[kind]
    # One batch step advances all N worlds: the steps are the longest particle's, not N x.
    assert 0 < steps < 3 * 600
    same = np.mean([a == b for a, b in zip(cpu["states"], warp["states"])])
    effect = EFFECT[kind]
    hits = [sum(any(atom.startswith(effect) for atom in s) for s in r["states"]) for r in (cpu, warp)]
    # Between pybullet and MuJoCo 56-94 % of particles share Y^-1 (docs/ENGINES.md); one
    # engine on two backends must do at least as well, the push (contacts decided in
    # float32 at the tray's edge) the loosest.
    assert same >= (0.7 if kind == "push" else 0.9), (kind, same)
    # The intended effect's count within two binomial standard deviations of CPU MuJoCo's.
    p = max(hits[0], 1) / N
    assert abs(hits[0] - hits[1]) <= max(1, 2 * np.sqrt(N * p * (1 - p))), (kind, hits)
    # The weighed channel (the grasp width, sigma 2 mm) where both worlds hold the block.
    both = [i for i in range(N) if cpu["states"][i] == warp["states"][i]]
    cols, sigmas = load("container").measurement_model()
    gap = np.abs(cpu["measurements"][np.ix_(both, cols)] - warp["measurements"][np.ix_(both, cols)])
    gap = np.nan_to_num(gap) / sigmas
    # Nearly all to a hundredth of a sigma; a grip at the prior's edge (a 60 mm block held
    # by its rim) may settle differently in float32, still within the sensor's noise.
    assert np.mean(gap < 0.01) >= 0.9 and gap.max() < 2.0, (kind, np.round(gap.ravel(), 3))


@pytest.mark.slow
def test_the_pickup_table_is_the_physics_not_a_constant(tables):
    """The table compared above has both outcomes: small beliefs' grasps miss or hold
    differently from large ones (a table of all-equal rows would match any engine)."""
    cpu, warp = tables[0]["pickup"]
    held = ["is_holding(r,b3)" in s for s in warp["states"]]
    assert 0 < sum(held) < N or len({tuple(r) for r in np.round(warp["configurations"], 4)}) > N // 2
