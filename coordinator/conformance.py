"""Conformance checks of a registered domain (in the spirit of Gymnasium's ``check_env``).

``tmoc check-domain NAME`` and the test suite (parametrised over every registered
domain) run the same checks: each is a small function that raises ``AssertionError`` (or
any error) with a message saying what is wrong; ``check_domain`` runs them all and
reports each by name.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from planner.domain import TaskDomain
from sim_workers.base import PhysicsDomain, missing_members
from sim_workers.domains import import_string
from sim_workers.engines import make_world
from sim_workers.grounded_world import GroundedWorld
from sim_workers.properties import PropertyError

from .domains import Domain, load, spec
from .loop.transit import workspace_of
from .transition.counterfactual import context_counts


@dataclass(frozen=True)
class CheckResult:
    name: str
    ok: bool
    detail: str
    seconds: float

    def to_dict(self) -> dict:
        return {"check": self.name, "ok": self.ok, "detail": self.detail,
                "seconds": round(self.seconds, 3)}


def check_structure(name: str) -> str:
    """Both halves implement their base class (sim_workers.base.PhysicsDomain,
    planner.domain.TaskDomain): every missing member is named, before anything is built."""
    s = spec(name)
    problems = []
    for half, path, base in (("physics", s.physics, PhysicsDomain), ("task", s.task, TaskDomain)):
        obj = import_string(path)
        if not isinstance(obj, type):
            continue        # a factory: its product is checked when the domain is loaded
        missing = missing_members(obj, base)
        if missing:
            problems.append(f"{half} half {path} lacks {', '.join(missing)}")
    assert not problems, "; ".join(problems)
    return f"{s.physics} and {s.task} implement the protocol"


def check_spec(d: Domain) -> str:
    """The physics half's options are a dataclass holding the object count."""
    assert dataclasses.is_dataclass(d.physics.spec), "physics.spec is not a dataclass of options"
    assert 1 <= d.n_objects <= d.physics.max_objects, f"n_objects {d.n_objects} outside [1, {d.physics.max_objects}]"
    return f"{len(dataclasses.fields(d.physics.spec))} fields"


def check_scene(d: Domain) -> str:
    """The scene is data an engine can build (``sim_workers.scene``): every object is a
    body, each body's boxes have positive extents and its mass is not negative, and the
    description survives pickling (it travels to engine backends as a value)."""
    import pickle

    truth = _truth(d)
    desc = d.physics.scene_description(d.physics.properties(truth))
    names = [b.name for b in desc.bodies]
    assert len(set(names)) == len(names), f"body names repeat: {names}"
    assert set(desc.objects) <= set(names), f"objects {set(desc.objects) - set(names)} are not bodies"
    n_objects = len(d.physics.initial_configuration(truth).objects)
    assert len(desc.objects) == n_objects, f"{len(desc.objects)} objects declared, {n_objects} in a configuration"
    for b in desc.bodies:
        assert b.shapes and all(s.extent() > 0 for s in b.shapes), f"body {b.name}: a shape without extent"
        assert b.mass >= 0 and b.friction >= 0, f"body {b.name}: negative mass or friction"
    assert pickle.loads(pickle.dumps(desc)) == desc, "the description does not survive pickling"
    return f"{len(desc.bodies)} bodies, {len(desc.objects)} objects"


def _truth(d: Domain) -> dict:
    return d.physics.true_properties()


def _sized(d: Domain, value: float) -> dict:
    """The hypothesis with L's first property at `value` (a size in the block worlds) and
    every other at its default truth."""
    row = np.array(d.physics.L.truth, dtype=np.float64)
    row[0] = float(value)
    return d.physics.props_from_row(row)


def _prior(d: Domain) -> tuple[float, float]:
    L = d.physics.L
    return float(L.low[0]), float(L.high[0])


def _at(d: Domain, index: int, value: float) -> dict:
    """The hypothesis with L's property `index` at `value` and every other at its default truth."""
    row = np.array(d.physics.L.truth, dtype=np.float64)
    row[index] = float(value)
    return d.physics.props_from_row(row)


def _each_property(d: Domain, k: int) -> list[tuple[int, str, np.ndarray]]:
    """(index, name, k values from the prior's low to its high end) for every property of L."""
    L = d.physics.L
    return [(i, str(n), np.linspace(float(L.low[i]), float(L.high[i]), k)) for i, n in enumerate(L.names)]


def _first_actions(d: Domain, k: int = 3) -> list[tuple[frozenset, str]]:
    """(state, action) for the first `k` actions of the optimistic plan, states by apply()."""
    task = d.task
    state = task.initial_state(d.n_objects)
    plan = task.plan(state, task.optimistic_transition(d.n_objects))
    out = []
    for action in plan.actions[:k]:
        out.append((state, action))
        state = task.apply(state, action)
    return out


def check_initial_state(d: Domain) -> str:
    """Y^-1 of the initial configuration is the task's initial state, canonical, no goal."""
    config = d.physics.initial_configuration(_truth(d))
    assert len(config.objects) == len(d.physics.object_names), \
        f"{len(config.objects)} object rows for objects {d.physics.object_names}"
    state = d.physics.symbolic_state(config)
    assert d.task.parse_state(sorted(state)) == state, "Y^-1 state is not canonical"
    assert state == d.task.initial_state(d.n_objects), \
        f"Y^-1 of the initial configuration {sorted(state)} != task.initial_state"
    assert not d.task.is_goal(state), "the initial state is already a goal"
    return f"{len(state)} atoms"


def check_place_keeps_state(d: Domain) -> str:
    """Re-grounding under any hypothesis across the prior keeps Y^-1 (every property of L
    moved over its prior, the others at their default truth)."""
    config = d.physics.initial_configuration(_truth(d))
    state = d.physics.symbolic_state(config)
    for i, name, values in _each_property(d, 5):
        for value in values:
            placed = d.physics.place(config, _at(d, i, value))
            got = d.physics.symbolic_state(placed)
            assert got == state, f"place() at {name} {value:.4g} changes Y^-1: {sorted(got ^ state)}"
    return ", ".join(f"5 values of {name}" for _, name, _ in _each_property(d, 5)) + " across the prior"


def _outcome(world: GroundedWorld, d: Domain, config, props: dict, action: str):
    placed = world.reset(config, props)
    key = d.physics.action_pose(props, placed, action)
    traj = d.physics.action_trajectory(placed, action, key)
    t0 = d.physics.transit_end_time(placed, action, key)
    return world.execute(traj, action, start_time=t0)


def check_outcomes_depend_on_L(d: Domain) -> str:
    """Every property of L changes what the particle worlds report: for each, at the
    prior's two ends (the others at their default truth), some one of the optimistic plan's
    first three actions (each from the state the truth reaches) ends in a different
    configuration or different measurements. A property nothing depends on cannot be
    learned, and a domain whose outcomes ignore L would pass every other check."""
    truth = _truth(d)
    steps, config = [], d.physics.initial_configuration(truth)
    seen: dict[str, str] = {}
    with make_world(d.physics) as world:
        for _, action in _first_actions(d):
            steps.append((config, action))
            config = _outcome(world, d, config, truth, action).configuration
        for i, name, (low, high) in ((i, n, v) for i, n, v in _each_property(d, 2)):
            for start, action in steps:
                a = _outcome(world, d, start, _at(d, i, low), action)
                b = _outcome(world, d, start, _at(d, i, high), action)
                moved = not np.allclose(a.configuration.to_array(), b.configuration.to_array(), rtol=0, atol=1e-6)
                read = not np.allclose(a.measurements, b.measurements, rtol=0, atol=1e-9, equal_nan=True)
                if moved or read:
                    seen[name] = action
                    break
    blind = [n for n in d.physics.L.names if n not in seen]
    assert not blind, (f"the outcomes of {', '.join(a for _, a in steps)} do not depend on "
                       f"{', '.join(blind)} across the prior: nothing can learn it")
    return ", ".join(f"{n} (by {a})" for n, a in seen.items())


def check_refused_properties(d: Domain) -> str:
    """Bad properties are refused with a message naming the field, before any change."""
    truth = _truth(d)
    key = next(iter(truth))          # the first property (block_sizes in the block worlds)
    value = np.asarray(truth[key], dtype=np.float64)
    cases = [({**truth, key: np.full_like(value, np.nan)}, key),
             ({**truth, key: value * 1000.0}, key),
             ({**truth, "weight": 1.0}, "weight")]
    for props, field in cases:
        try:
            d.physics.properties(props)
        except PropertyError as exc:
            assert field in str(exc), f"refusal of {field} does not name it: {exc}"
        else:
            raise AssertionError(f"properties {sorted(props)} with a bad {field} were accepted")
    return f"{len(cases)} refusals name their field"


def _outcome_bits(world: GroundedWorld, d: Domain, config, props: dict, action: str) -> bytes:
    placed = world.reset(config, props)
    key = d.physics.action_pose(props, placed, action)
    traj = d.physics.action_trajectory(placed, action, key)
    t0 = d.physics.transit_end_time(placed, action, key)
    return world.execute(traj, action, start_time=t0).configuration.to_array().tobytes()


def check_determinism(d: Domain, ray_actors: bool = True) -> str:
    """The same (configuration, properties, action) gives the same bits in fresh worlds,
    in a world with a past and (optionally) on two Ray actors."""
    props = _truth(d)
    config = d.physics.initial_configuration(props)
    (_, action), *rest = _first_actions(d)
    # Particle worlds, as shards build them (leaving out what an action cannot reach, for
    # the action kinds the domain names): a Ray actor must match them bit for bit.
    with make_world(d.physics, leave_out=True) as a, make_world(d.physics, leave_out=True) as b:
        first = _outcome_bits(a, d, config, props, action)
        assert _outcome_bits(b, d, config, props, action) == first, "two fresh worlds differ"
        if rest:
            _outcome_bits(b, d, config, props, rest[0][1] if rest[0][1] != action else action)
        assert _outcome_bits(b, d, config, props, action) == first, "a world with a past differs"
    if not ray_actors:
        return f"{action}: fresh and with a past"
    import ray

    from sim_workers.shard import remote_shard

    from .distributed.fanout import init_ray

    init_ray()
    Actor = remote_shard(num_cpus=0)
    actors = [Actor.remote(d.name, dict(d.options)) for _ in range(2)]
    try:
        key = d.physics.action_pose(props, config, action)
        traj = d.physics.action_trajectory(config, action, key)
        t0 = d.physics.transit_end_time(config, action, key)
        # The truth as the wire carries it: a row of L per particle.
        rows = np.asarray(d.physics.L.truth, dtype=np.float64)[None, :]
        outs = ray.get([x.simulate.remote(config.to_array(), rows, action, traj, t0) for x in actors])
        assert np.array_equal(outs[0]["configurations"], outs[1]["configurations"]), "two Ray actors differ"
        assert outs[0]["configurations"][0].tobytes() == first, "a Ray actor differs from in-process"
    finally:
        for x in actors:
            ray.kill(x)
    return f"{action}: fresh, with a past, two Ray actors"


def check_planner(d: Domain) -> str:
    """The plan reaches the goal; its expected utility is the Python EU of its actions and
    at least that of any random valid plan; every context is one the domain lists."""
    task, n = d.task, d.n_objects
    rng = np.random.default_rng(0)
    contexts = set(task.contexts(n))
    state0 = task.initial_state(n)
    for trial in range(3):
        T = task.optimistic_transition(n) if trial == 0 else _random_transition(task.optimistic_transition(n), rng)
        plan = task.plan(state0, T)
        state = state0
        for action in plan.actions:
            ctx = task.context_of(state, action)
            assert ctx is None or tuple(ctx) in contexts, f"context {ctx} of {action} not listed"
            state = task.apply(state, action)
        assert task.is_goal(state), f"plan {plan.actions} does not reach the goal"
        eu = task.expected_utility(state0, plan.actions, T)
        assert abs(eu - plan.expected_utility) < 1e-6, f"plan EU {plan.expected_utility} != Python EU {eu}"
        assert plan.optimal, "optimality not proven"
        for _ in range(10):
            other = task.satisficing(state0, rng=rng, transition=T)
            assert other.expected_utility <= plan.expected_utility + 1e-6, \
                f"a random plan beats the optimum: {other.expected_utility} > {plan.expected_utility}"
    return f"3 transition models, {len(plan.actions)} actions"


def _random_transition(template: dict, rng: np.random.Generator) -> dict:
    return {k: (float(rng.uniform(0.3, 1.0)) if not isinstance(v, list)
                else [float(p) for p in rng.uniform(0.3, 1.0, len(v))]) for k, v in template.items()}


def check_y(d: Domain) -> str:
    """Y is finite and inside the motion planner's workspace at the prior's bounds."""
    workspace = workspace_of(d.physics)
    config = d.physics.initial_configuration(_truth(d))
    n = 0
    for i, name, values in _each_property(d, 2):
        for value in values:
            for _state, action in _first_actions(d, 1):
                pose = d.physics.action_pose(_at(d, i, value), config, action)
                assert np.all(np.isfinite(pose)), f"Y({action}) at {name} {value:.4g} is not finite: {pose}"
                assert np.all(pose[:3] >= workspace.low[:3]) and np.all(pose[:3] <= workspace.high[:3]), \
                    f"Y({action}) at {name} {value:.4g} = {pose[:3]} is outside the workspace"
                n += 1
    return f"{n} poses"


def check_y_batch(d: Domain) -> str:
    """A domain's vectorised Y (`action_poses`) is its per-row Y to the bit, for rows of L
    drawn over the prior: the coordinator calls it for every particle."""
    L = d.physics.L
    rows = np.random.default_rng(0).uniform(L.low, L.high, size=(16, len(L.names)))
    config = d.physics.initial_configuration(_truth(d))
    for _, action in _first_actions(d):
        batch = d.physics.action_poses(rows, config, action)
        single = np.array([d.physics.action_pose(d.physics.props_from_row(r), config, action) for r in rows])
        assert batch.shape == single.shape and np.array_equal(batch, single), \
            f"action_poses({action}) differs from action_pose row by row"
    return f"{len(rows)} rows x {len(_first_actions(d))} actions, bit for bit"


def check_measurements(d: Domain) -> str:
    """The measurement vector has a fixed length and the likelihood's channels index it."""
    config = d.physics.initial_configuration(_truth(d))
    m = d.physics.measurements(config)
    # NaN is "not measured" (e.g. a held weight with nothing held); never an infinity.
    assert m.ndim == 1 and not np.any(np.isinf(m)), "measurements not a vector of finite values or NaN"
    # (A weighed channel may be NaN at rest: a held weight or a strike's force is read
    # only during an action; the filter skips what is not measured. Issue 39: this check
    # asked for the first weighed channel at rest, a rule no caller needs.)
    from .domains import measurement_channels

    chans = measurement_channels(d.physics)
    assert len(chans) == len(m), f"{len(chans)} channels described, {len(m)} measured"
    idx, sigma = d.physics.measurement_model()
    assert len(idx) == len(sigma), "channel indices and sigmas differ in length"
    assert np.all((np.asarray(idx) >= 0) & (np.asarray(idx) < len(m))), "a channel index is out of range"
    assert np.all(np.asarray(sigma) > 0), "a weighed channel has no positive sigma"
    return f"{len(m)} values, {len(idx)} weighed"


def check_misalignment(d: Domain) -> str:
    """Where a domain names an action perception-sensitive (``misalignment``), the row is a
    movable object (the one perception jitters) and the axis a planar unit vector: the
    filter shifts that object's perceived position along it (docs/LOOP.md)."""
    config = d.physics.initial_configuration(_truth(d))
    named = 0
    for _, action in _first_actions(d):
        where = d.physics.misalignment(config, action)
        if where is None:
            continue
        row, axis = where
        axis = np.asarray(axis, dtype=np.float64)
        assert int(row) in d.physics.jittered_objects, f"misalignment({action}): row {row} is not a movable object"
        assert axis.shape == (2,) and abs(float(np.hypot(*axis)) - 1.0) < 1e-9, \
            f"misalignment({action}): the axis is not a planar unit vector"
        named += 1
    return f"{named} of {len(_first_actions(d))} actions perception-sensitive"


def check_pose_alternatives(d: Domain) -> str:
    """Y's alternatives (``pose_alternatives``), where a domain offers any at the prior's
    bounds, are poses of Y's shape, finite, inside the workspace and not Y's pose itself:
    the coordinator runs each in every particle world."""
    low, high = _prior(d)
    workspace = workspace_of(d.physics)
    config = d.physics.initial_configuration(_truth(d))
    L = d.physics.L
    offered = 0
    for size in (low, high):
        rows = np.full((2, len(L.names)), np.asarray(L.low, dtype=np.float64))
        rows[:, 0] = size
        for _, action in _first_actions(d):
            pose = d.physics.action_pose(_sized(d, size), config, action)
            for alt in d.physics.pose_alternatives(config, action, pose, rows):
                alt = np.asarray(alt, dtype=np.float64)
                assert alt.shape == pose.shape and np.all(np.isfinite(alt)), \
                    f"pose_alternatives({action}) at {size}: not a finite pose of Y's shape"
                assert np.all(alt[:3] >= workspace.low[:3]) and np.all(alt[:3] <= workspace.high[:3]), \
                    f"pose_alternatives({action}) at {size} = {alt[:3]} is outside the workspace"
                assert not np.array_equal(alt, pose), f"pose_alternatives({action}) at {size} repeats Y's pose"
                offered += 1
    return f"{offered} alternatives at the prior's bounds"


def check_option_bounds(d: Domain) -> str:
    """Every numeric option a request may set (the task half's ``http_options``) declares a
    lower and an upper bound, and every range the physics half declares
    (``option_ranges``) is an option's, holding its default: a request or run outside them
    is refused by name, never failing later (issue 38)."""
    from .domains import options_of

    for key, decl in dict(d.task.http_options).items():
        if decl.get("type") in (int, float):
            assert any(k in decl for k in ("ge", "gt")) and any(k in decl for k in ("le", "lt")), \
                f"http_options[{key!r}]: a number needs a lower and an upper bound (ge/gt, le/lt)"
    known = options_of(d.physics)
    ranges = dict(type(d.physics).option_ranges)
    for key, (low, high) in ranges.items():
        assert key in known, f"option_ranges[{key!r}]: not an option of the domain"
        default = known[key]
        assert low <= high and (default is None or low <= default <= high), \
            f"option_ranges[{key!r}] = ({low}, {high}) does not hold the default {default!r}"
    return f"{len(dict(d.task.http_options))} request options bounded, {len(ranges)} ranges"


def check_counterfactual(d: Domain) -> str:
    """The counterfactual contexts (issue 40): every job is a probe action at a load its
    probe accepts, and the rates of trials that all succeeded reach T's contexts (and are
    1 there). No physics runs: the probes themselves are T*'s."""
    phys, task, n = d.physics, d.task, d.n_objects
    jobs = phys.counterfactual_jobs(n)
    if not jobs:
        return "no counterfactual contexts (no probes declared): T learns from executed actions only"
    for action, k in jobs:
        assert action in phys.probe_actions, f"counterfactual_jobs: {action!r} is not in probe_actions"
        assert int(k) in phys.probe_loads(action), f"counterfactual_jobs: load {k} outside {action}'s probe_loads"
    contexts = task.contexts(n)
    counts = context_counts(phys.counterfactual_rates({tuple(j): 1 for j in jobs}, 1, n), contexts, 1)
    assert counts, "counterfactual_rates: no rate names one of T's actions"
    wrong = {c: v for c, v in counts.items() if v != (1.0, 1.0)}
    assert not wrong, f"counterfactual_rates: trials that all succeeded give rates below 1 at {sorted(wrong)}"
    return f"{len(jobs)} probe jobs reach {len(counts)} of {len(contexts)} T contexts"


CHECKS: dict[str, Callable[[Domain], str]] = {
    "structure": check_structure,
    "spec": check_spec,
    "scene": check_scene,
    "initial_state": check_initial_state,
    "place_keeps_state": check_place_keeps_state,
    "refused_properties": check_refused_properties,
    "determinism": check_determinism,
    "outcomes_depend_on_L": check_outcomes_depend_on_L,
    "planner": check_planner,
    "y_in_workspace": check_y,
    "y_batch": check_y_batch,
    "measurements": check_measurements,
    "misalignment": check_misalignment,
    "pose_alternatives": check_pose_alternatives,
    "option_bounds": check_option_bounds,
    "counterfactual": check_counterfactual,
}


def check_robot(d: Domain, robot_name: str) -> str:
    """With an arm (`robot_name`), the domain declares where it stands (``robot_base``) and
    the arm plans the first action's whole tool path from there (inverse kinematics, every
    link clear of the scene, toppra's timing: ``coordinator.loop.arm_motion``) at both ends
    of L's first property's prior; a floating gripper needs nothing."""
    from sim_workers.robots import Arm, robot

    from .loop.arm_motion import plan_arm_step, robot_of, start_joints

    if not isinstance(robot(robot_name), Arm):
        return f"{robot_name}: the tool point is commanded directly"
    arm = robot_of(robot_name, d.physics)
    n = 0
    for value in _prior(d):
        props = _sized(d, value)
        config = d.physics.initial_configuration(props)
        sizes = np.asarray(d.physics.object_sizes(props), dtype=np.float64)
        obstacles = d.physics.obstacles(config, sizes)
        for _state, action in _first_actions(d, 1):
            pose = d.physics.action_pose(props, config, action)
            rows = d.physics.action_trajectory(config, action, pose)
            plan = plan_arm_step(arm, rows, obstacles, start=start_joints(arm, config.robot, obstacles), seed=0,
                                 contact_from=0.0)
            assert np.all(plan.path.q >= arm.low) and np.all(plan.path.q <= arm.high)
            n += len(plan.rows)
    return f"{robot_name} from {tuple(round(float(v), 4) for v in d.physics.robot_base)}: {n} tool rows planned"


def check_domain(name: str, *, ray_actors: bool = True, robot: str | None = None,
                 **options) -> list[CheckResult]:
    """Run every check on domain `name`, and with `robot` the arm's (``check_robot``);
    one result per check (never raises for a failed check, so a report lists them all)."""
    results = []
    d = None
    checks = dict(CHECKS)
    if robot is not None:
        checks["robot"] = lambda dom: check_robot(dom, robot)
    for check, fn in checks.items():
        t0 = time.perf_counter()
        try:
            if fn is check_structure:
                detail = fn(name)
            else:
                if d is None:
                    if not results[0].ok:
                        # Nothing can be built from an incomplete protocol: one report.
                        return results
                    d = load(name, **options)
                detail = fn(d, ray_actors) if fn is check_determinism else fn(d)
            results.append(CheckResult(check, True, detail, time.perf_counter() - t0))
        except Exception as exc:  # noqa: BLE001 - each failure is reported by name
            results.append(CheckResult(check, False, f"{type(exc).__name__}: {exc}",
                                       time.perf_counter() - t0))
    return results
