"""The chute (docs/examples/tmoc-chute-domain), a domain that is not a block world, at a
small scale from the checkout: its planner against brute force, and the mechanism that
makes grounding L pay (Y's stroke limit from the believed friction). Installed into a
fresh venv it is checked end to end in tests/installed (check-domain, tmoc run, HTTP)."""
from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

PLUGIN = Path(__file__).resolve().parents[2] / "docs" / "examples" / "tmoc-chute-domain"
if str(PLUGIN) not in sys.path:
    sys.path.insert(0, str(PLUGIN))

from tmoc_chute_domain.physics import ChutePhysics  # noqa: E402
from tmoc_chute_domain.task import ChuteTask, sweep_value  # noqa: E402

from planner.domain import Plan, PlanningError, UnknownAction  # noqa: E402
from sim_workers.base import missing_members  # noqa: E402
from sim_workers.grounded_world import GroundedWorld, act  # noqa: E402


def test_both_halves_implement_the_protocol():
    from planner.domain import TaskDomain

    assert missing_members(ChutePhysics) == [] and missing_members(ChuteTask, TaskDomain) == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_plan_is_the_best_split_by_brute_force(seed):
    task, n = ChuteTask(), 6
    rng = np.random.default_rng(seed)
    T = {"sweep": sorted(rng.uniform(0.05, 1.0, n), reverse=True)}
    plan = task.plan(task.initial_state(n), T)
    assert isinstance(plan, Plan) and plan.optimal and sum(plan.loads) == n
    best = max(sum(sweep_value(task.default_costs, T["sweep"][k - 1], k) for k in loads)
               for loads in _splits(n))
    assert plan.expected_utility == pytest.approx(best, abs=1e-3 * n)
    state = task.initial_state(n)
    for a in plan.actions:
        state = task.apply(state, a)
    assert task.is_goal(state)


def _splits(n: int):
    for cuts in itertools.product((0, 1), repeat=n - 1):
        loads, run = [], 1
        for c in cuts:
            if c:
                loads.append(run)
                run = 1
            else:
                run += 1
        yield loads + [run]


def test_contexts_and_bad_input():
    task = ChuteTask()
    state = task.apply(task.initial_state(5), "sweep(p2)")
    assert task.context_of(state, "sweep(p4)") == ("sweep", 2)
    with pytest.raises(UnknownAction):
        task.context_of(state, "push(r,c,init,goal)")
    with pytest.raises(ValueError, match="p1 is not queued"):
        task.apply(state, "sweep(p1)")
    with pytest.raises(PlanningError, match="transition.sweep"):
        task.plan(state, {"sweep": [1.0]})


def _sweep(mu: float, believed: float, k: int):
    d = ChutePhysics(n_blocks=4)
    truth = {"friction": np.full(4, mu)}
    with GroundedWorld(d) as world:
        config = world.reset(d.initial_configuration(truth), truth)
        out = act(world, d, config, {"friction": np.full(4, believed)}, f"sweep(p{k})")
    return all(f"delivered(p{i + 1})" in out.state for i in range(k)), out.measurements[-1], \
        d.action_pose({"friction": np.full(4, believed)}, config, f"sweep(p{k})")[5]


@pytest.mark.slow
def test_a_belief_below_the_truth_stalls_the_train_and_the_wrist_says_so():
    """At friction 0.6 a train of 3 goes through when Y believes 0.6 and stalls at the
    limit Y chose when it believes 0.3; the stroke force grows with the friction."""
    ok, force, limit = _sweep(0.6, 0.6, 3)
    assert ok and force < limit
    stalled, force_low, limit_low = _sweep(0.6, 0.3, 3)
    assert not stalled and limit_low < limit and force_low == pytest.approx(limit_low, rel=0.05)
    ok_light, force_light, _ = _sweep(0.3, 0.3, 3)
    assert ok_light and force_light < force


@pytest.fixture
def chute_registered(monkeypatch):
    """The chute in the registry as its entry point would put it (this process only)."""
    import sim_workers.domains as registry
    from tmoc_chute_domain import DOMAIN

    real = registry.plugin_entries
    monkeypatch.setattr(registry, "plugin_entries",
                        lambda: {**real(), "chute": {**DOMAIN, "distribution": "tmoc-chute-domain"}})


def test_a_dumped_config_reads_back_with_the_domains_utility(chute_registered):
    """A stored run, checkpoint or task is a dumped RunConfig: read back, it must keep the
    chute's terms (fail 30, deliver 20), not the block worlds' defaults (50, 40)."""
    from coordinator.domains import task_half
    from coordinator.loop.episode import utility_terms
    from coordinator.run_config import RunConfig

    task = task_half("chute")
    first = RunConfig(domain="chute", truth={"friction": 0.6}, costs={"sweep": 25.0})
    again = RunConfig(**first.model_dump())
    assert utility_terms(task, again) == utility_terms(task, first) == {**task.default_costs, "sweep": 25.0}
    assert again.truth_values() == {"friction": 0.6}


@pytest.mark.parametrize("fields, named", [({"true_size": 0.05}, "true_size"),
                                           ({"truth": {"size": 0.04}}, "truth.size"),
                                           ({"truth": {"friction": 3.0}}, "truth.friction"),
                                           ({"costs": {"pickup": 3.0}}, "costs.pickup")])
def test_what_the_chute_does_not_have_is_refused_by_name(chute_registered, fields, named):
    from pydantic import ValidationError

    from coordinator.run_config import RunConfig

    with pytest.raises(ValidationError, match=named.replace(".", r"\.")):
        RunConfig(domain="chute", **fields)


@pytest.mark.parametrize("options, named", [({"force_sigma": 1e-300}, "options.force_sigma"),
                                            ({"position_sigma": 0.0}, "options.position_sigma")])
def test_a_sigma_without_width_is_refused_by_name(chute_registered, options, named):
    """Issue 38, row 7: `force_sigma: 1e-300` passed validation; every observation then
    failed with "sigma/width: must be positive". The domain's bounds refuse it."""
    from pydantic import ValidationError

    from coordinator.run_config import RunConfig

    with pytest.raises(ValidationError, match=named.replace(".", r"\.")):
        RunConfig(domain="chute", truth={"friction": 0.6}, options=options)


def test_tmoc_probe_takes_the_chutes_truth_by_name_and_refuses_a_size(chute_registered, capsys):
    """Issue 39: `tmoc probe` required --true-size for a domain that has no size (and
    ignored it); the chute's truth is `--truth friction=V`, its belief `--belief`."""
    import json

    from coordinator.cli import main

    base = ["probe", "--domain", "chute", "--action", "sweep", "--load", "4", "--trials", "2", "--json"]
    rates = {}
    for mu in (0.3, 0.7):
        assert main(base + ["--truth", f"friction={mu}"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["truth"] == {"friction": mu} and out["true_size"] is None
        rates[mu] = out["success_rate"]
    assert rates == {0.3: 1.0, 0.7: 0.0}
    assert main(["probe", "--domain", "chute", "--action", "sweep", "--true-size", "0.045"]) == 2
    assert "--true-size: the chute domain has no size in L (properties: friction)" in capsys.readouterr().err
    assert main(base + ["--truth", "size=0.04"]) == 2
    assert "--truth size: not a property of L for domain 'chute'" in capsys.readouterr().err
