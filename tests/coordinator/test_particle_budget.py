"""Issue 15, item 1 (part): the adaptive particle budget by KLD-sampling. Real pybullet
worlds in an in-process shard pool, real clingo; determinism from the seed alone."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.particle_filter.belief import Belief
from coordinator.distributed.fanout import ShardPool
from coordinator.particle_filter.particle_budget import kld_count, next_count, occupied_bins
from coordinator.run_config import RunConfig
from coordinator.loop.runner import run


def test_kld_bound_matches_the_localisation_figures():
    """Fox 2003 with epsilon 0.05, quantile 0.99: 66 particles at 2 occupied bins, 134 at 5
    (the figures of the issue); one bin needs one; a looser epsilon scales it down."""
    assert kld_count(1) == 1 and kld_count(0) == 1
    assert kld_count(2) == 66 and kld_count(5) == 134
    assert kld_count(2, 0.2) == 17 and kld_count(5, 0.2) == 34
    assert kld_count(50) > kld_count(20) > kld_count(10)
    with pytest.raises(ValueError):
        kld_count(3, 0.0)


def test_a_tiny_epsilon_asks_for_the_maximum_not_an_overflow():
    """Any positive kld_epsilon is a valid request; 5e-324 made the bound infinite and the
    task failed with an OverflowError (found by schemathesis over HTTP)."""
    assert kld_count(5, 5e-324) == 2**62
    rng = np.random.default_rng(0)
    particles = rng.uniform(0.03, 0.06, (64, 1))
    n = next_count(particles, np.full(64, 1 / 64), np.array([0.03]), np.array([0.06]),
                   n_min=8, n_max=48, epsilon=5e-324)
    assert n == 48


def test_bins_are_per_property_in_its_own_scale():
    low, width = np.array([0.03, 300.0]), np.array([0.003, 270.0])
    same = np.array([[0.0401, 1000.0], [0.0405, 1100.0]])
    assert occupied_bins(same, np.ones(2), low, width) == 1
    apart = np.array([[0.0401, 1000.0], [0.0401, 1400.0], [0.0450, 1000.0]])
    assert occupied_bins(apart, np.ones(3), low, width) == 3
    assert occupied_bins(apart, np.array([1.0, 0.0, 0.0]), low, width) == 1     # weightless: not counted
    wide = np.random.default_rng(0).uniform(low, low + 30 * width, (500, 2))
    assert next_count(wide, np.ones(500), low, low + 30 * width, n_min=8, n_max=100) == 100
    assert next_count(same, np.ones(2), low, low + 10 * width, n_min=8, n_max=100) == 8
    assert next_count(same, np.ones(2), low, low + 10 * width, n_min=50, n_max=20) == 20   # floor <= max


def test_resample_to_a_new_count_is_seeded_and_keeps_the_ancestors():
    rng = np.random.default_rng(1)
    b = Belief.from_prior(40, [0.03], [0.06], rng)
    b.update(-((b.particles[:, 0] - 0.04) / 0.002) ** 2)
    twins = [Belief(b.particles.copy(), b.log_weights.copy(), b.low, b.high) for _ in range(2)]
    for t in twins:
        t.resample_to(12, np.random.default_rng(7), jitter=0.1, jitter_floor=0.02)
    assert twins[0].n == 12 and np.array_equal(twins[0].particles, twins[1].particles)
    assert np.allclose(twins[0].weights, 1 / 12)
    assert np.isin(twins[0].particles[0, 0], b.particles[:, 0])       # an ancestor's first copy is exact
    assert abs(twins[0].mean()[0] - 0.04) < 0.003


def _run(budget: str, episodes: int = 3, n_blocks: int = 8) -> dict:
    # At the 1.15 sides' grasp (grasp_clearance 0, the container's default until 2026-12-01),
    # where a too-small belief's pickup fails and the belief narrows within the first
    # episode, so the budget has something to adapt to in these short runs. With the 6 mm
    # clearance the same seed spends 87 % of the fixed budget's particle-actions (1299 for
    # 62 actions) and the five-block run does not narrow below 24 within two episodes: the
    # grasp's width, not a failed pickup, then corrects a small belief (docs/LOOP.md).
    cfg = RunConfig(particles=24, episodes=episodes, seed=0, true_size=0.034, particle_budget=budget,
                    min_particles=6, n_blocks=n_blocks, counterfactual_rows=0, grasp_clearance=0.0)
    return run(cfg, pool=ShardPool(cfg.domain, {"n_blocks": n_blocks, "grasp_clearance": 0.0}, n_shards=0))


@pytest.fixture(scope="module")
def runs():
    return {"kld": _run("kld")}


@pytest.mark.slow
@pytest.mark.timeout(600)          # the run (fixture): 140 s measured alone on 2 cores
def test_the_count_falls_as_the_belief_converges(runs):
    kld = runs["kld"]["episodes"]
    assert kld[0]["particles_per_action"][0] == 24                     # the prior is wide
    # Converged to within two 3 mm bins: the truth, 34 mm, is 1 mm from the 33 mm bin edge
    # and the calibrated posterior (issue 37: noisy readings, Liu-West kernel) keeps a
    # +-2 std of about 1 mm, so it straddles the edge and KLD asks for kld_count(2) = 17;
    # the old filter's narrower posterior sat in one bin and fell to the floor, 6.
    assert max(kld[-1]["particles_per_action"]) <= kld_count(2, 0.2) < 24
    # Against a fixed 24 on the same actions: measured with the noisy reality, 1180
    # particle-actions of replay for 62 actions, 79 % of 24 x 62 (a fixed-budget run of
    # the same seed takes other actions; issue 24's noise-free filter: 54 %).
    actions = sum(len(e["particles_per_action"]) for e in kld)
    assert sum(e["particle_actions"] for e in kld) < 0.85 * 24 * actions
    # ... and it learns: the optimum (two trips of 4, 110) at the end, the posterior
    # within 1 mm of the truth.
    assert kld[-1]["utility"] == 110.0
    assert abs(kld[-1]["posterior"]["size_mean"] - 0.034) < 0.001


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_an_adaptive_run_depends_on_its_seed_alone():
    # A three-episode run's first two episodes again, as a two-episode run: the result
    # depends on the seed, not on how many episodes were asked for, including actions
    # whose count has adapted (the first action runs at the maximum: comparing it alone,
    # as this test once did, checked no adaptation). Five blocks, in 17 + 14 s on 2 cores.
    # Where the count adapts is the physics' last bits, which differ between CPU models
    # (an Intel Xeon: episode 2 at 6; an AMD EPYC: one action of episode 1 at 17, episode
    # 2 at 24), so the check is that some compared action adapted, not which.
    three, two = _run("kld", episodes=3, n_blocks=5), _run("kld", episodes=2, n_blocks=5)
    counts = [n for e in two["episodes"] for n in e["particles_per_action"]]
    assert min(counts) < 24, counts
    strip = lambda eps: [{k: v for k, v in e.items() if not k.endswith("_s")} for e in eps]  # noqa: E731
    assert strip(two["episodes"]) == strip(three["episodes"][:2])


def test_stored_settings_from_before_the_budget_keep_the_fixed_budget():
    """The default is kld, but a stored dump without `particle_budget` (a checkpoint or a
    task spec written before the field existed) ran fixed and resumes fixed."""
    from coordinator.run_config import RunConfig, stored_run_config
    from coordinator.loop.session import Session

    assert RunConfig().particle_budget == "kld"
    old = RunConfig(particles=6, episodes=1).model_dump()
    old.pop("particle_budget")
    assert stored_run_config(old).particle_budget == "fixed"
    assert stored_run_config({**old, "particle_budget": "kld"}).particle_budget == "kld"
    session = Session(RunConfig(particles=6, episodes=1, particle_budget="fixed"))
    checkpoint = session.to_checkpoint()
    checkpoint["config"].pop("particle_budget")
    assert Session.from_checkpoint(checkpoint).config.particle_budget == "fixed"
