"""Slide (docs/examples/tmoc-slide-domain), the smallest example domain, from the checkout:
it passes every conformance check in both engines, the mechanism that makes grounding L pay
(Y lets go for the believed friction) works in the physics, its plan is what it says, and
TMOC learns a puck's friction with it, judged against the exact posterior's width."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

PLUGIN = Path(__file__).resolve().parents[2] / "docs" / "examples" / "tmoc-slide-domain"
if str(PLUGIN) not in sys.path:
    sys.path.insert(0, str(PLUGIN))

from tmoc_slide_domain import DOMAIN  # noqa: E402
from tmoc_slide_domain.physics import SlidePhysics  # noqa: E402
from tmoc_slide_domain.task import SlideTask  # noqa: E402

from planner.domain import TaskDomain, UnknownAction  # noqa: E402
from sim_workers.base import missing_members, required_members  # noqa: E402
from sim_workers.engines import ENGINES, make_world  # noqa: E402
from sim_workers.grounded_world import act  # noqa: E402


@pytest.fixture
def slide_registered(monkeypatch):
    """Slide in the registry as its entry point would put it (this process only)."""
    import sim_workers.domains as registry

    real = registry.plugin_entries
    monkeypatch.setattr(registry, "plugin_entries",
                        lambda: {**real(), "slide": {**DOMAIN, "distribution": "tmoc-slide-domain"}})


def test_it_is_small_and_implements_the_protocol():
    assert missing_members(SlidePhysics) == [] and missing_members(SlideTask, TaskDomain) == []
    lines = sum(len(p.read_text().splitlines()) for p in (PLUGIN / "tmoc_slide_domain").glob("*.py"))
    assert lines < 400, lines         # read in one sitting: both halves together
    assert len(required_members()) == 16


def _push(truth: float, belief: float, engine: str = "pybullet") -> str:
    d = SlidePhysics(n_blocks=2)
    d.engine = engine
    T, B = {"friction": np.full(2, truth)}, {"friction": np.full(2, belief)}
    with make_world(d) as world:
        config = world.reset(d.initial_configuration(T), T)
        out = act(world, d, config, B, "push(p1)")
    assert "waiting(p2)" in out.state            # the other puck is not touched
    return next(a for a in out.state if a.endswith("(p1)")).split("(")[0]


@pytest.mark.parametrize("truth", [0.3, 0.6])
def test_y_at_the_truth_places_the_puck_and_a_wrong_belief_misses_both_ways(truth):
    assert _push(truth, truth) == "placed"
    assert _push(truth, truth / 2) == "waiting"      # let go too early: short of the line
    if truth * 1.6 <= 0.6:
        assert _push(truth, truth * 1.6) == "lost"   # too late: past it


@pytest.mark.parametrize("engine", ENGINES)
def test_slide_passes_every_conformance_check_in_both_engines(slide_registered, engine):
    """In this process (its Ray actors could not import a plugin this test only put on
    sys.path; installed, `tmoc check-domain slide` runs them too)."""
    from coordinator.conformance import CHECKS, check_domain

    results = check_domain("slide", ray_actors=False, engine=engine)
    assert [r.name for r in results] == list(CHECKS)
    assert not {r.name: r.detail for r in results if not r.ok}


def test_the_plan_pushes_every_waiting_puck_and_is_worth_what_it_says():
    task = SlideTask()
    state = task.parse_state(["placed(p1)", "waiting(p2)", "waiting(p3)", "lost(p4)"])
    plan = task.plan(state, {"push": 0.5})
    assert plan.actions == ("push(p2)", "push(p3)") and plan.optimal
    c = task.default_costs
    assert plan.expected_utility == pytest.approx(2 * (0.5 * c["place"] - c["push"] - 0.5 * c["fail"]))
    assert task.is_goal(task.apply(task.apply(state, "push(p2)"), "push(p3)"))
    with pytest.raises(UnknownAction):
        task.context_of(state, "shove(p2)")
    with pytest.raises(ValueError, match="p1 is also"):
        task.parse_state(["placed(p1)", "lost(p1)"])
    assert task.context_of(state, "push(p1)") is None and task.context_of(state, "push(p2)") == ("push", 0)


@pytest.mark.slow          # two episodes of 64 particle worlds (~60 s)
def test_tmoc_learns_the_friction_with_it_and_gets_better(slide_registered):
    """Two pucks of friction 0.2 (the prior: 0.15-0.6), readings with the camera's noise:
    the posterior ends within 2.5 std of the truth, identified, and the second episode
    places both pucks at the first push (the optimum, 80). 64 particles: a slide read to
    2 mm pins the friction to ~0.002, a hundredth of the prior, and 16 particles (0.03 apart)
    hold no row there (docs/DOMAINS.md, "The smallest example")."""
    from coordinator.distributed.fanout import ShardPool
    from coordinator.loop.runner import run
    from coordinator.run_config import RunConfig

    cfg = RunConfig(domain="slide", truth={"friction": 0.2}, particles=64, episodes=2, seed=3,
                    particle_budget="fixed", n_objects=2)
    pool = ShardPool("slide", {"n_blocks": 2}, n_shards=0)
    try:
        result = run(cfg, pool=pool)
    finally:
        pool.close()
    post = result["summary"]["posterior"]["friction"]
    assert abs(post["mean"] - 0.2) <= 2.5 * post["std"] and post["std"] < 0.01 and post["identified"]
    first, last = (e["utility"] for e in result["episodes"])
    assert last == 80.0 and last > first


def test_the_http_schema_offers_each_domain_its_own_utility_terms(slide_registered):
    """A request the published schema allows is one the domain accepts: with slide
    installed, schemathesis sent slide the container's `all_delivered` at a value of its
    choosing, valid under one `costs` model for every domain and refused with a 422, then a
    `true_size` slide has no size for."""
    from pydantic import TypeAdapter, ValidationError

    from api.schemas.requests import run_config, spec_body, task_spec_model

    spec = TypeAdapter(task_spec_model(8, 2))
    own = spec.json_schema()["$defs"]["SlideCosts"]
    assert own["additionalProperties"] is False
    free = {k for k, v in own["properties"].items() if v.get("type") == "number" and v["maximum"] == 1e4}
    assert free == set(SlideTask.default_costs), own
    # Its own terms at any value in range, the container's only at their defaults (as a
    # config dumped by the container carries them): both run.
    body = spec_body(spec.validate_python({"domain": "slide", "costs": {"place": 3, "pickup": 15}}))
    assert run_config(body).costs.place == 3.0
    for bad, field in (({"pickup": 16}, "pickup"), ({"all_delivered": 9999.0}, "all_delivered"),
                       ({"bogus": 1}, "bogus")):
        with pytest.raises(ValidationError) as err:
            spec.validate_python({"domain": "slide", "costs": bad})
        assert f"costs.{field}" in str(err.value), err.value
    # The same for a size L does not hold: only its default (stored specs carry it).
    assert spec.json_schema()["$defs"]["TaskSpecSlide"]["properties"]["true_size"]["maximum"] == 0.045
    with pytest.raises(ValidationError, match="true_size"):
        spec.validate_python({"domain": "slide", "true_size": 0.08})
