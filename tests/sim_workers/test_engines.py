"""The second engine (issue 27): MuJoCo builds every domain's one scene declaration, with
the contact laws it declares, and the physics claims hold in it as in pybullet.

Real pybullet and real MuJoCo; determinism is in test_determinism.py (parametrised over
both engines), the conformance checks in tests/coordinator/test_domains.py.
"""
from __future__ import annotations

from dataclasses import replace

import mujoco
import numpy as np
import pytest

from coordinator.cli import main
from sim_workers import engines
from sim_workers.domains import load, names
from sim_workers.engines.mujoco_engine import build_model
from sim_workers.grounded_world import GroundedWorld, act
from sim_workers.probe import probe

ENGINES = list(engines.ENGINES)      # the registry's one list


def test_unknown_engine_is_named_with_the_known_ones():
    with pytest.raises(engines.EngineError,
                       match=r"^engine: unknown engine 'bullet' \(known: pybullet, mujoco, mujoco_warp\)"):
        engines.check_engine("bullet")
    with pytest.raises(engines.EngineError, match="engine: unknown"):
        load("container", engine="bullet")
    assert engines.check_engine(None) == "pybullet"      # installed here: every result's engine


@pytest.mark.parametrize("engine", [None, *ENGINES])
def test_the_session_s_physics_half_learns_the_run_s_engine(engine):
    """Issue 39 item 1: the session built its physics half (Y, Y^-1, measurements) without
    the run's engine although the docs say runs set it, so a domain whose Y depends on the
    engine silently planned for the default one under --engine mujoco."""
    from coordinator.run_config import RunConfig
    from coordinator.loop.session import Session

    session = Session(RunConfig(engine=engine, particles=2, episodes=1, n_blocks=2))
    assert session.domain.engine == engine


def test_a_missing_engine_names_its_package(monkeypatch):
    monkeypatch.setattr(engines.registry, "installed", lambda e: e not in ("pybullet", "mujoco_warp"))
    with pytest.raises(engines.EngineError, match="the pybullet engine needs the Python package 'pybullet'"):
        engines.check_engine("pybullet")
    assert engines.default_engine() == "mujoco"
    # the batch engine names the extra that brings it
    with pytest.raises(engines.EngineError, match=r"pip install 'tmoc-service\[warp\]'"):
        engines.check_engine("mujoco_warp")


@pytest.mark.parametrize("flag", ["--engine", "--reality-engine"])
def test_cli_refuses_an_unknown_engine_in_one_line(flag, capsys, tmp_path):
    assert main(["run", flag, "ode", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and flag in err[0] and "ode" in err[0], err


@pytest.mark.parametrize("name", names())
def test_every_domain_compiles_in_mujoco_from_its_one_declaration(name):
    domain = load(name)
    desc = domain.scene_description(domain.properties(domain.true_properties()))
    scene = build_model(desc)
    m = scene.model
    # every body of the declaration, each free one with its declared mass
    for body in desc.bodies:
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body.name)
        assert bid >= 0, body.name
        if body.mass:
            assert m.body_mass[bid] == pytest.approx(body.mass, rel=1e-9)
    assert len(scene.objects) == len(desc.objects)
    assert m.opt.timestep == desc.time_step


def test_friction_is_the_declared_product_per_pair():
    """Bullet multiplies two bodies' coefficients and the domains' mu_* are chosen for that
    product; MuJoCo would take the larger one. The explicit pairs carry the product."""
    domain = load("container", n_blocks=2)
    desc = domain.scene_description(domain.properties(domain.true_properties()))
    m = build_model(desc).model
    mu = {b.name: b.friction for b in desc.bodies}
    mu["palm"] = mu["finger_l"] = mu["finger_r"] = desc.gripper.friction

    def body_of(geom):
        return mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.geom_bodyid[geom])

    seen = set()
    for k in range(m.npair):
        a, b = body_of(m.pair_geom1[k]), body_of(m.pair_geom2[k])
        assert m.pair_friction[k, 0] == pytest.approx(mu[a] * mu[b]), (a, b)
        seen.add(frozenset((a, b)))
    assert frozenset(("b1", "table")) in seen and frozenset(("b1", "b2")) in seen
    assert frozenset(("b1", "finger_l")) in seen and frozenset(("table", "container")) in seen
    assert all(m.geom_contype == 0) and all(m.geom_conaffinity == 0)   # nothing else collides


def test_a_guarded_move_caps_the_wrist_force_in_mujoco():
    """Pressing the empty hand onto the table with a 3 N limit: the drive never exceeds it,
    and the arm carries the gripper's weight (gravity compensation), as in pybullet."""
    domain = load("stack_and_push", engine="mujoco")
    props = domain.true_properties()
    with GroundedWorld(domain) as world:
        config = world.reset(domain.initial_configuration(props), props)
        x, y = 0.3, 0.25                       # bare table
        traj = np.array([[0.0, x, y, 0.05, 0.0, 0.0, 5.0, 3.0],
                         [0.5, x, y, -0.05, 0.0, 0.0, 5.0, 3.0],
                         [1.0, x, y, -0.05, 0.0, 0.0, 5.0, 3.0]])
        world._apply(type(config)(np.array([x, y, 0.05, 0.0, 0.0]), config.objects))
        forces = []
        for row in traj[1:]:
            world._set_gripper(row[1:])
            for _ in range(40):
                world._step()
                forces.append(world._wrist_force())
        forces = np.array(forces)
        assert np.all(np.abs(forces) <= 3.0 + 1e-9)
        tip = world.observe().robot[2]
    assert tip > -0.002          # held up by the table: the limit kept it from driving through


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("name", ["container", "stack_and_push"])
def test_a_pickup_holds_at_the_true_size_and_misses_far_off_it(name, engine):
    """The first probe claims of docs/BUILTIN_DOMAINS.md, in both engines, small: 4 seeded
    trials each, at the 1.15 sides' opening (grasp_clearance 0, stack-and-push's default
    before it). A belief 25 % small lands the fingers on the block; one 25 % large still
    grasps (the grip deepens with the believed size); one 1.67 x too large closes above it."""
    def successes(true: float, believed: float) -> int:
        return probe("pickup", true, believed, trials=4, seed=1, n_blocks=4, domain=name,
                     options={"engine": engine, "grasp_clearance": 0.0}).successes

    assert successes(0.045, 0.045) == 4 and successes(0.045, 0.045 * 0.75) == 0
    assert successes(0.045, 0.045 * 1.25) == 4 and successes(0.030, 0.050) == 0


def test_both_engines_agree_on_a_carried_stack():
    """The same pickup and stack from the same start: the same symbolic outcome, and the
    stacked block within 3 mm of where pybullet put it."""
    out = {}
    for engine in ENGINES:
        domain = load("container", n_blocks=4, engine=engine)
        truth = domain.true_properties()
        with GroundedWorld(domain) as w:
            c = w.reset(domain.initial_configuration(truth), truth)
            o = act(w, domain, c, truth, "pickup(r,b1,init)")
            o = act(w, domain, o.configuration, truth, "stack(r,b1,c)")
        out[engine] = o
    assert out["pybullet"].state == out["mujoco"].state
    assert "at_container(b1,c)" in out["mujoco"].state
    a, b = (out[e].configuration.objects[1, :3] for e in ENGINES)
    assert np.abs(a - b).max() < 0.003


def _model_fields(m) -> dict:
    """Every array of a model, and the statistics and options the simulation reads."""
    out = {k: getattr(m, k).tobytes() for k in dir(m)
           if not k.startswith("_") and isinstance(getattr(m, k), np.ndarray) and getattr(m, k).dtype != object}
    out.update({f"stat.{k}": repr(getattr(m.stat, k)) for k in dir(m.stat)
                if not k.startswith("_") and k not in ("meanmass", "meansize")})   # rendering only
    out.update({f"opt.{k}": repr(getattr(m.opt, k)) for k in dir(m.opt) if not k.startswith("_")})
    return out


@pytest.mark.parametrize("name,options", [("container", {}), ("stack_and_push", {"unknown_density": True})])
def test_a_patched_model_is_the_compiled_one_bit_for_bit(name, options):
    """A world moves from hypothesis to hypothesis by writing boxes and masses into its
    model; that model must be what compiling the hypothesis gives, every field."""
    from sim_workers.engines.mujoco_engine import patch

    domain = load(name, **options)
    L = domain.L
    rng = np.random.default_rng(7)
    prev = domain.scene_description(domain.properties(domain.props_from_row(np.array(L.truth))))
    scene = build_model(prev)
    data = mujoco.MjData(scene.model)
    for _ in range(12):
        new = domain.scene_description(domain.properties(domain.props_from_row(rng.uniform(L.low, L.high))))
        assert patch(scene, prev, new, data)
        fresh, got = _model_fields(build_model(new).model), _model_fields(scene.model)
        assert [k for k in fresh if fresh[k] != got[k]] == []
        prev = new


def test_a_scene_that_is_not_boxes_is_compiled_not_patched():
    from sim_workers.engines.mujoco_engine import _patchable

    domain = load("container", n_blocks=2)
    a = domain.scene_description(domain.properties(domain.props_from_row(np.array([0.04]))))
    b = domain.scene_description(domain.properties(domain.props_from_row(np.array([0.05]))))
    assert _patchable(a, b)
    moved_tray = replace(b, bodies=tuple(replace(x, friction=0.9) if x.name == "container" else x for x in b.bodies))
    assert not _patchable(a, moved_tray)       # a friction is a pair's: compiled


def test_blocks_cut_where_efforts_change_and_after_each_rest_check():
    from sim_workers.engines.mujoco_world import blocks
    from sim_workers.grounded_world import REST_CHECK_EVERY

    times = np.arange(1, 61) * 0.01
    targets = np.zeros((60, 7))
    targets[:, 6] = 50.0
    targets[10:20, 6] = 3.0                      # a guarded move: its start and release
    out = blocks(times, targets, t_end=0.30)     # late from step 30 on (t > 0.30)
    edges = [a for a, _, _ in out] + [out[-1][1]]
    checks = [b for _, b, c in out if c]
    assert checks == [k + 1 for k in range(36, 60, REST_CHECK_EVERY)]
    assert edges == sorted({0, 10, 20, 60, *checks})
    assert blocks(times, targets[:, :6], t_end=1.0) == [(0, 60, False)]


@pytest.mark.parametrize("name,options,actions", [
    ("container", {"n_blocks": 4}, ["pickup(r,b1,init)", "stack(r,b1,c)"]),
    ("stack_and_push", {"unknown_density": True},
     ["pickup(r,b1,init)", "stack(r,b1,start)", "pickup(r,b2,init)", "stack(r,b2,tower)",
      "push(r,tower,start,goal)"]),
])
def test_mujoco_stepping_in_blocks_is_the_one_step_loop_bit_for_bit(name, options, actions, monkeypatch):
    """A MuJoCo world steps an action in blocks (rollout calls and mj_step(nstep)); the
    outcome, sensor log and step count must be the one-step loop's exactly, with a belief
    10 % off so that grasps, guarded pushes and settling all happen."""
    from sim_workers.engines.mujoco_world import MujocoWorld

    def episode():
        domain = load(name, engine="mujoco", **options)
        truth = domain.true_properties()
        believed = domain.props_from_row(np.asarray(domain.L.truth) * 1.1)
        outs = []
        with GroundedWorld(domain) as w:
            config = w.reset(domain.initial_configuration(truth), truth)
            for action in actions:
                o = act(w, domain, config, believed, action)
                outs.append(o)
                config = o.configuration
        return outs

    blocked = episode()
    monkeypatch.setattr(MujocoWorld, "_run", GroundedWorld._run)
    stepped = episode()
    assert any(np.isfinite(o.measurements).any() for o in blocked)
    for a, b in zip(blocked, stepped):
        assert a.state == b.state and a.steps == b.steps
        assert np.array_equal(a.configuration.to_array(), b.configuration.to_array())
        assert np.array_equal(a.measurements, b.measurements, equal_nan=True)


# -- the centre of mass, one declaration in both engines (issue 39) -----------------------
from sim_workers.container import ContainerDomain  # noqa: E402
from sim_workers.scene import Body, BoxShape, inertial  # noqa: E402


def test_a_compound_s_mass_properties_are_its_uniform_solid_s():
    """Two boxes side by side are the one box they make: its centre and its moments."""
    halves = Body("pair", (BoxShape((0.05, 0.1, 0.02), (-0.05, 0.0, 0.1)), BoxShape((0.05, 0.1, 0.02), (0.05, 0.0, 0.1))),
                  2.0, (0, 0, 0), 0.5)
    com, moments = inertial(halves)
    one = Body("one", (BoxShape((0.1, 0.1, 0.02)),), 2.0, (0, 0, 0), 0.5)
    assert np.allclose(com, (0.0, 0.0, 0.1)) and np.allclose(moments, inertial(one)[1], rtol=1e-12)
    declared = replace(halves, center_of_mass=(0.01, 0.0, 0.0), inertia=(1.0, 2.0, 3.0))
    assert np.allclose(inertial(declared)[0], (0.01, 0, 0)) and np.allclose(inertial(declared)[1], (1, 2, 3))


class _UniformTray(ContainerDomain):
    """The container with its tray's mass properties left to its walls (a uniform solid:
    the centre 15 mm above the frame's origin)."""

    def scene_description(self, props):
        desc = super().scene_description(props)
        bodies = tuple(replace(b, center_of_mass=None, inertia=None) if b.name == "container" else b
                       for b in desc.bodies)
        return replace(desc, bodies=bodies)


def test_both_engines_build_the_declared_centre_of_mass():
    """The same declaration is the same body in both engines: pybullet put the centre at
    the frame's origin and MuJoCo at the walls' centroid. And the pybullet world reports
    and places the body's frame, not Bullet's centre-of-mass pose."""
    import pybullet as pb

    domain = _UniformTray()
    props = domain.properties(domain.true_properties())
    desc = domain.scene_description(props)
    tray = desc.body("container")
    com, moments = inertial(tray)
    assert 0.010 < com[2] < 0.020 and np.allclose(com[:2], 0.0)
    m = build_model(desc).model
    bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "container")
    assert np.allclose(m.body_ipos[bid], com, atol=1e-12) and np.allclose(m.body_inertia[bid], moments, rtol=1e-9)
    with GroundedWorld(domain) as world:
        config = domain.initial_configuration(props)
        placed = world.reset(config, props)
        uid = world.handles.bodies["container"]
        info = pb.getDynamicsInfo(uid, -1, physicsClientId=world.client)
        assert np.allclose(info[2], moments, rtol=1e-9)
        # (a maximal-coordinates body's reported inertial frame is not filled in: Bullet's
        # base pose, which is the centre's, says where the centre is)
        base = pb.getBasePositionAndOrientation(uid, physicsClientId=world.client)[0]
        assert np.allclose(np.subtract(base, placed.objects[0][:3]), com, atol=1e-9)
        assert np.allclose(world.observe().objects[0], placed.objects[0], atol=1e-12)   # the frame, both ways
        out = act(world, domain, placed, props, "pickup(r,b1,init)")
        assert abs(out.configuration.objects[0][2] - placed.objects[0][2]) < 1e-4       # the tray stays put
    # The built-in tray declares its own (the figures' tray): both engines build that one.
    builtin = ContainerDomain().scene_description(props).body("container")
    assert builtin.center_of_mass == (0.0, 0.0, 0.0)
    m = build_model(ContainerDomain().scene_description(props)).model
    assert np.allclose(m.body_ipos[bid], 0.0) and np.allclose(m.body_inertia[bid], builtin.inertia, rtol=1e-9)


def test_an_engine_is_made_by_the_factory_and_must_define_every_hook():
    """Issue 39: the engine hooks were `NotImplementedError` (an engine missing one failed
    mid-action); they are abstract, and `make_world` is the factory (the base's
    `GroundedWorld(domain)` is kept as the same factory for existing callers)."""
    from sim_workers.engines import make_world
    from sim_workers.engines.pybullet_world import PybulletWorld
    from sim_workers.grounded_world import GroundedWorld

    domain = load("container")
    for engine in ENGINES:
        with make_world(domain, engine=engine) as world, GroundedWorld(domain, engine=engine) as old:
            assert type(world) is type(old) and world.engine == engine
    hooks = GroundedWorld.__abstractmethods__
    assert {"_connect", "_rebuild", "_apply", "observe", "_step", "_wrist_force", "close"} <= hooks

    class HalfAnEngine(PybulletWorld):
        pass

    del_hook = type("NoObserve", (GroundedWorld,), {k: getattr(PybulletWorld, k) for k in hooks - {"observe"}})
    with pytest.raises(TypeError, match="observe"):
        del_hook(domain)
    with HalfAnEngine(domain) as w:                      # a subclass of a whole engine is whole
        assert w.engine == "pybullet"
