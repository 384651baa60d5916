"""The domain registry and conformance checks, parametrised over every registered domain
(issue 13): what `tmoc domains` lists and `tmoc check-domain` checks."""
from __future__ import annotations

import contextlib

import json

import numpy as np
import pytest

from coordinator import domains
from coordinator.cli import main
from coordinator.conformance import CHECKS, check_domain
from sim_workers.base import PhysicsDomain
from coordinator.transition.transition_model import TransitionModel
from planner.domain import UnknownAction
from sim_workers import domains as physics_registry
from sim_workers.container import ContainerDomain

NAMES = domains.names()
from sim_workers.engines import ENGINES  # noqa: E402  (the registry's one list)


def test_the_built_in_domains_are_registered():
    # Both, by name: a built-in left out of the registry (it was dropped when a half failed
    # to import) would shrink every test parametrised over NAMES, which would still pass.
    assert {"container", "stack_and_push"} <= set(NAMES)
    assert set(domains.BUILTIN) <= set(NAMES)


def test_a_built_in_whose_half_fails_to_import_is_an_error(monkeypatch):
    monkeypatch.setitem(domains.BUILTIN, "half_built", domains.DomainSpec(
        "half_built", "sim_workers.no_such_module:Domain", "planner.container:ContainerTask"))
    assert "half_built" in domains.names()
    with pytest.raises(ValueError, match="no_such_module"):
        domains.load("half_built", n_blocks=2)


@pytest.mark.slow          # the session's Ray (the --no-ray checks stay fast, below)
@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", NAMES)
def test_every_domain_passes_the_conformance_checks(name, engine, ray_cluster):
    results = check_domain(name, engine=engine)
    assert [r.name for r in results] == list(CHECKS)
    failed = {r.name: r.detail for r in results if not r.ok}
    assert not failed, failed


@pytest.mark.parametrize("name", NAMES)
def test_unknown_actions_are_errors_never_a_silent_none(name):
    task = domains.task_half(name)
    state = task.initial_state(4)
    for bad in ("fly(r,b1)", "pickup(r,b1)", "not an action"):
        with pytest.raises(UnknownAction):
            task.context_of(state, bad)
    t = TransitionModel(4, contexts=task.contexts(4), context_fn=task.context_of)
    with pytest.raises(ValueError, match="context 9"):
        t.probability(task.contexts(4)[-1][0], 9)


@pytest.mark.parametrize("name", NAMES)
def test_domains_json_describes_each_domain(name, capsys):
    assert main(["domains", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["domains"][name]
    assert d["name"] == name and d["objects"] and d["actions"]
    assert d["properties"][0]["unit"] and d["properties"][0]["prior"]["low"] < d["properties"][0]["prior"]["high"]
    assert d["contexts"] and {a for a, _ in d["contexts"]} <= set(d["actions"]) and d["utility"]["fail"] > 0
    if name in ("container", "stack_and_push"):
        assert ["pickup", 0] in d["contexts"] and d["utility"]["fail"] == 50.0
    assert d["measurements"]["count"] >= len(d["measurements"]["weighed"]) >= 1


@contextlib.contextmanager
def _registered(monkeypatch, name: str, cls: type, description: str):
    """Physics half `cls` registered as domain `name` (the container's task half) for a test."""
    physics_registry.register(name, cls)
    monkeypatch.setitem(domains.BUILTIN, name, domains.DomainSpec(
        name, f"{cls.__module__}:{cls.__name__}", "planner.container:ContainerTask", description))
    try:
        yield
    finally:
        physics_registry._REGISTRY.pop(name, None)


class _Drifting(ContainerDomain):
    """A broken physics half: re-grounding moves block 1 off the row (Y^-1 changes)."""

    name = "broken_drift"

    def place(self, config, props):
        placed = super().place(config, props)
        objects = placed.objects.copy()
        objects[1, 0] += 0.3
        return type(placed)(placed.robot, objects)


def test_check_domain_names_the_failed_check_and_exits_1(capsys, monkeypatch):
    with _registered(monkeypatch, "broken_drift", _Drifting, "a broken domain"):
        assert main(["check-domain", "broken_drift", "--no-ray"]) == 1
        out = capsys.readouterr().out
        assert "FAIL place_keeps_state" in out and "failed: place_keeps_state" in out
        assert main(["check-domain", "container", "--no-ray"]) == 0
        assert main(["check-domain", "nope"]) == 2


class _Incomplete:
    """A physics half written against no base class, missing most of the protocol."""

    name = "incomplete"

    def __init__(self, **options):
        self.spec = None

    def build(self, client, props):
        return None


class _HalfDone(PhysicsDomain):
    """A subclass that leaves two abstract members out."""

    name = "half_done"

    def __init__(self, **options):
        self.spec = ContainerDomain().spec

    for _m in sorted(set(PhysicsDomain.__abstractmethods__) - {"measurements", "obstacles", "object_names"}):
        locals()[_m] = getattr(ContainerDomain, _m)
    object_names = ContainerDomain.object_names
    del _m


def test_check_domain_names_every_missing_member_first(capsys, monkeypatch):
    """The structural check runs first and names every member a half lacks, at once; a
    half that is not a subclass of the base says so (issue 26)."""
    for name, cls in (("incomplete", _Incomplete), ("half_done", _HalfDone)):
        monkeypatch.setitem(domains.BUILTIN, name, domains.DomainSpec(
            name, f"{cls.__module__}:{cls.__name__}", "planner.container:ContainerTask", "broken"))
    assert main(["check-domain", "half_done", "--no-ray"]) == 1
    out = capsys.readouterr().out
    assert "FAIL structure" in out and "lacks measurements, obstacles" in out
    assert "1 checks" in out or "0/1" in out          # nothing is built from an incomplete protocol
    results = check_domain("incomplete", ray_actors=False)
    assert [r.name for r in results] == ["structure"] and not results[0].ok
    detail = results[0].detail
    assert "(a subclass of PhysicsDomain)" in detail
    for member in ("action_pose", "measurements", "symbolic_state", "true_properties", "object_names"):
        assert member in detail
    assert ", build" not in detail                  # it has build
    with pytest.raises(ValueError, match="does not implement sim_workers.base.PhysicsDomain"):
        domains.load("incomplete")


def test_the_protocol_lists_required_and_optional_members():
    """The base classes are the protocol: what a domain must write and what has a default."""
    from planner.domain import TaskDomain
    from sim_workers.base import optional_members, required_members

    assert {"name", "scene_description", "symbolic_state", "action_pose", "measurements"} <= set(required_members())
    assert {"props_from_row", "action_poses", "pose_classes", "workspace", "senses", "L",
            "measurement_channels", "probe_loads", "execution_jitter"} <= set(optional_members())
    # Issue 39: what no caller needs is not required (check_action, default_transit: defaults),
    # and pybullet's build is the engine's, not the protocol's.
    assert {"check_action", "default_transit"} <= set(optional_members())
    assert len(required_members()) == 16 and "build" not in optional_members()
    assert {"name", "plan", "context_of", "contexts"} <= set(required_members(TaskDomain))
    assert {"http_options", "http_truth", "actions_for_loads"} <= set(optional_members(TaskDomain))
    for name in domains.names():
        d = domains.load(name)
        assert isinstance(d.physics, PhysicsDomain) and isinstance(d.task, TaskDomain)


def test_http_bounds_of_the_task_halves_are_the_physics_bounds():
    """The request bounds a task half declares (planner cannot import sim_workers) are the
    physics half's: a density just inside builds, just outside is refused."""
    from planner.domain import DENSITY_BOUNDS
    from sim_workers.properties import MAX_DENSITY, MIN_DENSITY

    assert (DENSITY_BOUNDS["gt"], DENSITY_BOUNDS["le"]) == (MIN_DENSITY, MAX_DENSITY)
    for name in domains.names():
        for key, decl in domains.task_half(name).http_options.items():
            for bound in ("ge", "le"):
                if bound in decl:
                    domains.load(name, **{key: decl[bound]})


def test_a_second_domain_with_the_same_action_names_learns_its_own_contexts():
    """Reusing pickup/stack/push must not be learned with the container's contexts (which
    count `at_container` atoms and would put every stack in context 0)."""
    class Tower:
        name = "tower"

        def contexts(self, n):
            return (("pickup", 0),) + tuple(("stack", k) for k in range(n)) + \
                tuple(("push", k) for k in range(1, n + 1))

        def context_of(self, state, action):
            if action.startswith("stack"):
                return ("stack", sum(a.startswith("on(") for a in state))
            if action.startswith("push"):
                return ("push", sum(a.startswith("on(") for a in state))
            if action.startswith("pickup"):
                return ("pickup", 0)
            raise UnknownAction(action)

    task = Tower()
    t = TransitionModel(4, contexts=task.contexts(4), context_fn=task.context_of)
    tower3 = frozenset({"on(b1,start)", "on(b2,b1)", "on(b3,b2)", "is_holding(r,b4)"})
    t.observe_transition(tower3, "stack(r,b4,tower)", success=False)
    assert t.probability("stack", 3) == 0.5 and t.probability("stack", 0) == 1.0
    assert np.isclose(t.to_planner()["stack"][3], 0.5)


def test_every_measurement_channel_is_listed_by_name():
    """Issue 25 (the robot integrator): the container's listing showed one channel while an
    observation must carry 17; every domain now names them all, in order."""
    from coordinator.domains import describe

    for name in ("container", "stack_and_push"):
        m = describe(name)["measurements"]
        assert [c["index"] for c in m["channels"]] == list(range(m["count"])), name
    names = [c["name"] for c in describe("container")["measurements"]["channels"]]
    assert names[:3] == ["finger_opening", "b1_x", "b1_y"] and names[-1] == "b8_y" and len(names) == 17


# -- versions (issue 26, item 2) ---------------------------------------------------------

def test_every_domain_has_a_version_and_a_versioned_id(capsys):
    for name in NAMES:
        s = domains.spec(name)
        assert s.version >= 1 and s.id == f"{name}-v{s.version}"
        assert domains.spec(s.id) == s                       # "name-vN" names the same spec
    assert main(["domains", "--json"]) == 0
    listed = json.loads(capsys.readouterr().out)["domains"]
    assert all(listed[n]["id"] == f"{n}-v{listed[n]['version']}" for n in NAMES)
    with pytest.raises(ValueError, match="container-v9.*is not installed.*container-v1"):
        domains.spec("container-v9")


def test_a_run_config_takes_a_versioned_id_and_stores_the_name():
    from coordinator.run_config import RunConfig

    assert RunConfig(domain="stack_and_push-v1").domain == "stack_and_push"
    with pytest.raises(ValueError, match="stack_and_push-v2.*is not installed"):
        RunConfig(domain="stack_and_push-v2")
    assert main(["run", "--domain", "container-v7", "--episodes", "1"]) == 2


def test_a_checkpoint_carries_the_domain_version_and_a_changed_domain_refuses_it(monkeypatch):
    """A checkpoint without a version (every one before issue 26) is version 1's; one made
    with another version than the installed domain's is refused by name, not resumed with
    a scene or contexts it was not learned in."""
    from coordinator.run_config import RunConfig
    from coordinator.loop.session import Session

    s = Session(RunConfig(particles=8, seed=2, particle_budget="fixed"))
    data = json.loads(json.dumps(s.to_checkpoint()))
    assert data["domain_version"] == 1
    old = dict(data)
    old.pop("domain_version")
    assert Session.from_checkpoint(old).to_checkpoint() == data
    monkeypatch.setitem(domains.BUILTIN, "container", domains.DomainSpec(
        "container", domains.BUILTIN["container"].physics, domains.BUILTIN["container"].task, version=2))
    with pytest.raises(ValueError, match="made with container-v1; the installed domain is container-v2"):
        Session.from_checkpoint(data)


def test_a_plugin_version_must_be_a_positive_integer():
    from sim_workers.domains import _version

    assert _version(3, "x") == 3
    for bad in (0, -1, "2", 1.5, True):
        with pytest.raises(ValueError, match="version"):
            _version(bad, "x")


def test_a_scene_is_one_value():
    """(domain, object count, options) travel as one hashable value: equal scenes share a
    pool of worlds whatever the options' order (issue 26)."""
    from coordinator.run_config import RunConfig
    from sim_workers.domains import Scene

    a = Scene.of("stack_and_push", 4, {"unknown_density": True, "force_sigma": 0.5})
    b = Scene.of("stack_and_push", 4, {"force_sigma": 0.5, "unknown_density": True})
    assert a == b and hash(a) == hash(b) and len({a, b, Scene.of("stack_and_push", 5)}) == 2
    assert a.physics().L.names == ("size", "density") and a.physics().n_blocks == 4
    config = RunConfig(domain="stack_and_push", n_blocks=4, options={"unknown_density": True, "force_sigma": 0.5})
    assert config.scene == a


def test_a_run_config_is_validated_with_one_build_of_the_domain(monkeypatch):
    """Validating a spec builds its physics half once (it was 3 to 4 times; issue 26)."""
    from coordinator.run_config import RunConfig

    RunConfig(domain="stack_and_push")                       # the domain's option defaults, once
    builds = []
    real = physics_registry.load
    monkeypatch.setattr(physics_registry, "load", lambda *a, **k: builds.append(a) or real(*a, **k))
    RunConfig(domain="stack_and_push", n_blocks=4, options={"unknown_density": True},
              truth={"size": 0.05, "density": 900.0})
    assert len(builds) == 1


def test_the_domain_guide_names_every_member_of_the_protocol():
    """docs/DOMAINS.md documents each required and optional member of both bases."""
    from pathlib import Path

    from planner.domain import TaskDomain
    from sim_workers.base import PhysicsDomain, optional_members, required_members

    doc = (Path(__file__).resolve().parents[2] / "docs" / "DOMAINS.md").read_text()
    missing = [m for base in (PhysicsDomain, TaskDomain) for m in required_members(base) + optional_members(base)
               if f"`{m}" not in doc]
    assert not missing, f"docs/DOMAINS.md does not name {missing}"


@pytest.mark.parametrize("name", NAMES)
def test_the_simulated_reality_jitters_every_movable_object(name):
    """Issue 26: the reality placed every row but 0 with jitter ("row 0 is the container"),
    so stack-and-push's b1 never moved. Now the domain says which rows it keeps still."""
    from coordinator.loop.reality import SimulatedReality

    d = domains.load(name, n_blocks=3)
    truth = d.physics.true_properties()
    nominal = d.physics.initial_configuration(truth).objects
    reality = SimulatedReality(name, {"n_blocks": 3}, truth)
    placed = reality.start_episode(np.random.default_rng(4)).configuration.objects
    moved = {i for i in range(len(nominal)) if not np.allclose(placed[i, :2], nominal[i, :2], atol=1e-6)}
    assert moved == set(d.physics.jittered_objects)
    assert {d.physics.object_names[i] for i in moved} >= set(d.physics.block_names) - {"container"}


class _ThreeBlocks(ContainerDomain):
    """A domain whose own object count is 3 (issue 39: runs had 8 whatever it declared)."""

    name = "three_blocks"

    def __init__(self, spec=None, **overrides) -> None:
        from sim_workers.container.spec import ContainerSpec

        super().__init__(spec or ContainerSpec(n_blocks=3), **overrides)


def test_the_object_count_is_the_domains_own_unless_set(capsys, monkeypatch):
    from api.schemas.requests import task_spec_model
    from coordinator.run_config import RunConfig, stored_run_config
    from pydantic import TypeAdapter, ValidationError

    with _registered(monkeypatch, "three_blocks", _ThreeBlocks, "three blocks by default"):
        assert RunConfig(domain="three_blocks").n_blocks == 3
        assert RunConfig(domain="three_blocks", n_objects=5).n_blocks == 5
        assert RunConfig().n_blocks == 8                          # the container's own
        assert stored_run_config({"domain": "three_blocks"}).n_blocks == 8   # dumps before kept 8
        with pytest.raises(ValidationError, match="n_objects: 2 disagrees with n_blocks 4"):
            RunConfig(n_objects=2, n_blocks=4)
        # the CLI: --objects, a config file's n_objects, and the default
        assert main(["run", "--domain", "three_blocks", "--print-config"]) == 0
        assert json.loads(capsys.readouterr().out)["n_blocks"] == 3
        assert main(["run", "--domain", "three_blocks", "--objects", "4", "--print-config"]) == 0
        assert json.loads(capsys.readouterr().out)["n_blocks"] == 4
        assert main(["run", "--objects", "17"]) == 2
        assert "--objects: Input should be less than or equal to 16" in capsys.readouterr().err
        assert main(["run", "--option", "n_blocks=3"]) == 2
        assert "(--objects N; n_objects over HTTP)" in capsys.readouterr().err
        # HTTP: the field defaults to the domain's count, both names are taken
        spec = TypeAdapter(task_spec_model(64, 10))
        assert spec.validate_python({"domain": "three_blocks"}).n_blocks == 3
        assert spec.validate_python({"domain": "three_blocks", "n_objects": 2.0}).n_blocks == 2
        assert spec.validate_python({"n_blocks": 5}).n_blocks == 5
        with pytest.raises(ValidationError, match="n_objects"):
            spec.validate_python({"n_objects": 0})
        described = domains.describe("three_blocks")
        assert described["n_objects"] == described["n_blocks"] == 3


class _Blind(ContainerDomain):
    """A domain whose worlds ignore L: every hypothesis is built as the default truth."""

    name = "blind"

    action_poses = PhysicsDomain.action_poses        # Y row by row, through props_from_row

    def props_from_row(self, row):
        return super().props_from_row(np.asarray(self.L.truth, dtype=np.float64))


def test_a_domain_whose_outcomes_ignore_L_fails_conformance_by_name(monkeypatch):
    """Issue 39: such a domain passed every check (11/11); nothing in it can be learned."""
    with _registered(monkeypatch, "blind", _Blind, "ignores L"):
        results = {r.name: r for r in check_domain("blind", ray_actors=False)}
        failed = [n for n, r in results.items() if not r.ok]
        assert failed == ["outcomes_depend_on_L"], {n: results[n].detail for n in failed}
        assert "do not depend on size across the prior" in results["outcomes_depend_on_L"].detail


def test_every_property_of_L_is_varied_by_the_checks():
    """With the density unknown, the checks move the density over its prior too (they moved
    only L's first property: a Y or a place() broken at a heavy block went unseen)."""
    d = domains.load("stack_and_push", unknown_density=True)
    from coordinator.conformance import check_outcomes_depend_on_L, check_place_keeps_state

    assert "density (by " in check_outcomes_depend_on_L(d)
    assert "5 values of density" in check_place_keeps_state(d)


@pytest.mark.parametrize("domain, truth, variation", [
    ("container", 0.046, False), ("container", 0.032, True), ("stack_and_push", 0.052, False)])
def test_the_reality_holds_the_truth_exactly_by_one_path(domain, truth, variation):
    """Issue 39: a size-only L scaled the domain's default sizes by true_size / default
    (0.046 m came out one ulp off); the truth is L's row, built like a particle's."""
    from coordinator.run_config import RunConfig
    from coordinator.loop.runner import reality_for
    from coordinator.loop.session import Session

    session = Session(RunConfig(domain=domain, true_size=truth, sizes_variation=variation, particles=2,
                                particle_budget="fixed", n_blocks=3))
    reality = reality_for(session.config, session)
    try:
        sizes = np.asarray(reality.truth["block_sizes"])
        want = np.array([truth * (1.2 if variation else 1.0), truth, truth])
        assert np.array_equal(sizes, want), (sizes, want)
    finally:
        reality.close()


class _OldNames(ContainerDomain):
    """A physics half written before issue 39: it sets the protocol's old names."""

    name = "old_names"
    max_blocks = 5

    @property
    def block_names(self) -> list[str]:
        return ["b2", "b1"]


class _NewNames(ContainerDomain):
    """One written after: it sets the new names only."""

    name = "new_names"
    max_objects = 6

    @property
    def learned_objects(self) -> list[str]:
        return ["b1"]


def test_the_protocol_s_object_words_are_generic_and_the_old_ones_still_answer():
    """The core asks `learned_objects`, `n_objects`, `max_objects` (issue 39: no block-world
    words in the protocol); a domain that sets the old names is read through the new ones,
    and one that sets the new names answers the old ones."""
    old, new = _OldNames(n_blocks=3), _NewNames(n_blocks=2)
    assert old.learned_objects == old.block_names == ["b2", "b1"]
    assert old.max_objects == old.max_blocks == 5
    assert new.block_names == new.learned_objects == ["b1"]
    assert new.max_blocks == new.max_objects == 6
    assert (old.n_objects, old.n_blocks, new.n_objects, new.n_blocks) == (3, 3, 2, 2)
    assert domains.load("container", n_blocks=4).n_objects == 4
    assert domains.describe("container")["n_objects"] == domains.describe("container")["n_blocks"] == 8


class _ProbedByName(ContainerDomain):
    """A probe declared by L's names alone: it records what it was handed."""

    name = "probed_by_name"
    seen: list = []

    def probe_trial(self, action, load_k, rng, *, truth, belief):
        type(self).seen.append((action, load_k, dict(truth), dict(belief)))
        return truth["size"] == belief["size"]


def test_a_probe_declared_by_name_gets_the_truth_and_belief_in_full(monkeypatch):
    from sim_workers.probe import by_name, probe

    assert by_name(_ProbedByName()) and not by_name(ContainerDomain())
    with _registered(monkeypatch, "probed_by_name", _ProbedByName, "a probe by name"):
        _ProbedByName.seen.clear()
        # T*'s call: a size, the belief equal to the truth
        assert probe("pickup", 0.05, load_k=2, trials=2, seed=1, n_blocks=3, domain="probed_by_name").successes == 2
        # tmoc probe's call: the truth and the belief by name
        r = probe("pickup", 0.05, 0.04, load_k=1, trials=1, n_blocks=3, domain="probed_by_name",
                  truth={"size": 0.05}, belief={"size": 0.04})
        assert r.successes == 0
    assert _ProbedByName.seen == [("pickup", 2, {"size": 0.05}, {"size": 0.05})] * 2 + [
        ("pickup", 1, {"size": 0.05}, {"size": 0.04})]


class _Baseless(ContainerDomain):
    """The container with no place for an arm to stand."""

    name = "baseless"
    robot_base = None


def test_check_domain_with_a_robot_plans_the_arm_from_the_declared_base(capsys, monkeypatch):
    """`tmoc check-domain NAME --robot ur5e` (issue 41): the arm plans the first action from
    the domain's robot_base at both ends of the prior; a domain without a base fails that
    check by name; an unknown robot is a usage error."""
    assert main(["check-domain", "container", "--no-ray", "--robot", "ur5e"]) == 0
    assert "ok   robot" in capsys.readouterr().out
    with _registered(monkeypatch, "baseless", _Baseless, "no base"):
        assert main(["check-domain", "baseless", "--no-ray", "--robot", "ur5e"]) == 1
        out = capsys.readouterr().out
        assert "FAIL robot" in out and "robot_base" in out
        assert main(["check-domain", "baseless", "--no-ray"]) == 0        # without an arm: nothing to check
    assert main(["check-domain", "container", "--robot", "ur6"]) == 2
    assert "--robot" in capsys.readouterr().err
