"""The container domain's physics claims (issue 2, "Must show"), from seeded trials.

Every rate here comes from ``sim_workers.probe.probe``: each trial jitters block placement
(a few mm) and every friction coefficient (about 10 %) from its own child generator, takes
the action's poses from Y with the *believed* size and lets pybullet decide. Nothing is
scripted: a failure is the fingers closing on air or landing on the block, a push loses
blocks because a tall pile topples.

Thresholds (issue 2) and what these seeds measure (successes / trials):
  pickup, believed == true 0.045        >= 90 %                    measured 20/20
  pickup, believed 25 % and 30 % small  fails in >= half           measured 0/16 for each of
  (at 1.15 sides, grasp_clearance 0:                               0.70, 0.75 x true
  the default 6 mm holds a belief up to 2c small: 16/16)
  pickup, believed 25 % and 30 % large  succeeds in >= 90 %        measured 16/16 each: the grip
                                        (the grip deepens with     is a third of the believed
                                        the believed size)         side deep
  pickup, believed 1.67 x (30 mm block) fails in >= half           measured 0/16: fingertips
                                                                   above the block's top
  stack of the first 4 blocks           >= 90 %                    measured 12/12
  push with 2 loaded                    >= 90 %                    measured 20/20
  push with 8 loaded                    >= 25 points below load 2  measured 3/20
  (push with 4 and 6 loaded, same seed: 20/20 and 16/20; not asserted)
"""
from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from sim_workers.configuration import Configuration
from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld
from sim_workers.probe import probe

TRUE = 0.045


# -- the four claims, as rates --------------------------------------------------------------
def test_pickup_with_true_size_succeeds():
    r = probe("pickup", TRUE, trials=20, seed=11, domain="container")
    assert r.trials == 20
    assert r.success_rate >= 0.9, r.to_dict()


@pytest.mark.parametrize("true, factor", [(TRUE, 0.70), (TRUE, 0.75), (0.030, 5 / 3)],
                         ids=["30pc_smaller", "25pc_smaller", "67pc_larger"])
def test_pickup_with_wrong_believed_size_fails_in_at_least_half(true, factor):
    believed = factor * true
    r = probe("pickup", true, believed, trials=16, seed=12, domain="container", options={"grasp_clearance": 0.0})
    assert r.believed_size == believed and r.true_size == true
    assert 1 - r.success_rate >= 0.5, r.to_dict()


def test_the_default_clearance_holds_a_belief_up_to_2c_small():
    # The trade the 6 mm clearance makes (docs/BUILTIN_DOMAINS.md): a 31.5 mm belief opens
    # 43.5 mm over a 45 mm block and holds it, so the grasp's width, not a failed pickup,
    # corrects the belief; 1.67 x too large still closes above the block.
    assert probe("pickup", TRUE, 0.70 * TRUE, trials=8, seed=12, domain="container").success_rate == 1.0
    assert probe("pickup", 0.030, 0.050, trials=8, seed=12, domain="container").success_rate <= 0.5


@pytest.mark.parametrize("factor", [1.25, 1.30], ids=["25pc_larger", "30pc_larger"])
def test_pickup_with_a_larger_believed_size_still_grasps(factor):
    # The fingertips go a third of the believed side below its believed top: a block up
    # to 1.5 x smaller than believed is still between them (issue 40's shallow grip: 0/16).
    r = probe("pickup", TRUE, factor * TRUE, trials=16, seed=12, domain="container")
    assert r.success_rate >= 0.9, r.to_dict()


@pytest.mark.slow
def test_stacking_first_four_blocks_with_true_sizes():
    r = probe("stack", TRUE, load_k=4, trials=12, seed=13, domain="container")
    assert r.success_rate >= 0.9, r.to_dict()


@pytest.mark.slow
def test_push_loses_blocks_more_often_with_a_heavier_load():
    light = probe("push", TRUE, load_k=2, trials=20, seed=14, domain="container")
    heavy = probe("push", TRUE, load_k=8, trials=20, seed=14, domain="container")
    assert light.success_rate >= 0.9, light.to_dict()
    assert light.success_rate - heavy.success_rate >= 0.25, (light.to_dict(), heavy.to_dict())


def test_probe_is_reproducible_from_its_seed():
    a = probe("pickup", TRUE, 0.040, trials=3, seed=5, domain="container")
    b = probe("pickup", TRUE, 0.040, trials=3, seed=5, domain="container")
    assert a == b


# -- how a grasp works and how it fails -----------------------------------------------------
def _world(**options):
    domain = load("container", **options)
    truth = domain.true_properties()
    world = GroundedWorld(domain)
    config = world.reset(domain.initial_configuration(truth), truth)
    return domain, world, config


def _pickup_trajectory(domain, config, believed: float, block: str = "b3"):
    action = f"pickup(r,{block},init)"
    key = domain.action_pose({"block_sizes": np.full(domain.spec.n_blocks, believed)}, config, action)
    return action, key, domain.action_trajectory(config, action, key)


def _constraint_bodies(world) -> list[tuple[int, int]]:
    c = world.client
    out = []
    for k in range(pb.getNumConstraints(physicsClientId=c)):
        info = pb.getConstraintInfo(pb.getConstraintUniqueId(k, physicsClientId=c), physicsClientId=c)
        out.append((info[0], info[2]))            # parent body, child body (-1: the world)
    return out


def test_a_held_block_is_held_by_friction_not_by_a_constraint():
    domain, world, config = _world()
    with world:
        before = _constraint_bodies(world)
        action, _, traj = _pickup_trajectory(domain, config, TRUE)
        out = world.execute(traj, action, start_time=float(traj[3, 0]))
        assert "is_holding(r,b3)" in out.state and "hand_empty(r)" not in out.state
        block = out.configuration.objects[3]
        assert block[2] > 0.15                              # really up in the air
        # Exactly the gripper's two constraints (base carrier, finger gear), before and after;
        # none of them touches a block.
        after = _constraint_bodies(world)
        assert len(after) == 2 and after == before
        g = world.handles.gripper
        assert all(parent == g and child in (g, -1) for parent, child in after)
        assert not set(world.handles.blocks) & {b for pair in after for b in pair}
        # The fingers touch the block on both sides: contact, and the measured opening is
        # the block's width.
        contacts = pb.getContactPoints(g, world.handles.blocks[2], physicsClientId=world.client)
        assert {cp[3] for cp in contacts} == {0, 1}         # both finger links
        assert out.configuration.robot[4] == pytest.approx(TRUE, abs=0.004)
        # Open the hand in the air: nothing but friction held it, so it drops to the table.
        r = out.configuration.robot
        release = np.array([[0.0, *r[:4], 0.0], [0.5, *r[:4], domain.spec.max_opening - 0.005]])
        dropped = world.execute(release, action)
        assert "hand_empty(r)" in dropped.state and "is_holding(r,b3)" not in dropped.state
        assert dropped.configuration.objects[3, 2] == pytest.approx(TRUE / 2, abs=0.003)


def test_without_finger_friction_the_grasp_slips():
    # Same geometry, same commands; only finger friction almost gone: the block stays down.
    domain, world, config = _world(mu_finger=0.05)
    with world:
        action, _, traj = _pickup_trajectory(domain, config, TRUE)
        out = world.execute(traj, action, start_time=float(traj[3, 0]))
        assert "hand_empty(r)" in out.state
        assert out.configuration.objects[3, 2] < 0.05


@pytest.mark.parametrize("believed", [0.0315, 0.075])
def test_a_wrong_believed_size_fails_physically(believed):
    # 0.075: 1.67 x the 45 mm block, the fingertips 50 mm up (the grip is a third deep).
    # At 1.15 sides (no clearance; the default's 6 mm holds a belief up to 12 mm small).
    domain, world, config = _world(grasp_clearance=0.0)
    with world:
        action, key, traj = _pickup_trajectory(domain, config, believed)
        block0 = config.objects[3].copy()
        out = world.execute(traj, action, start_time=float(traj[3, 0]))
        # Y's failure is physical: the block was not lifted and the hand holds nothing.
        assert "hand_empty(r)" in out.state and "is_holding(r,b3)" not in out.state
        assert out.configuration.objects[3, 2] < TRUE           # still on the table
        assert out.configuration.robot[2] > 0.15                # while the gripper went up
        assert out.configuration.robot[4] < 0.002               # fingers closed on nothing
        if believed > TRUE:
            # Too large: the fingertips stop above the block's top and close on air; the
            # block is not even touched.
            assert key[2] > TRUE
            np.testing.assert_allclose(out.configuration.objects[3, :3], block0[:3], atol=5e-4)


def _closing_phase(believed: float) -> Configuration:
    """The configuration just after the fingers closed (before the lift), at 1.15 sides."""
    domain, world, config = _world(grasp_clearance=0.0)
    with world:
        action, _, traj = _pickup_trajectory(domain, config, believed)
        return world.execute(traj[:6], action, start_time=float(traj[3, 0]),
                             max_settle_s=0.3).configuration


def test_fingers_that_land_on_a_block_stop_on_its_top():
    after = _closing_phase(0.0315)            # opening 0.036 < 0.045: fingers land on the top
    assert after.objects[3, 2] > TRUE / 2 - 0.003       # the block is not pushed into the table
    assert after.robot[2] > TRUE - 0.005                # the fingertips rest on its top


# -- the engine seam (issue 26, item 5) ---------------------------------------------------

@pytest.mark.parametrize("name", ["container", "stack_and_push"])
def test_the_scene_is_declared_as_data_and_follows_L(name):
    """Which properties of L set which physical parameter is explicit in the description:
    a block's size is its box, its mass the body's mass; the fixtures do not move with L."""
    domain = load(name, n_blocks=3)
    small = domain.properties({"block_sizes": np.array([0.03, 0.04, 0.05])})
    big = domain.properties({"block_sizes": np.array([0.05, 0.05, 0.06])})
    a, b = domain.scene_description(small), domain.scene_description(big)
    for i, (s, m) in enumerate(zip(small["block_sizes"], small["block_masses"])):
        body = a.body(f"b{i + 1}")
        assert body.shapes[0].half == pytest.approx((s / 2,) * 3) and body.mass == pytest.approx(m)
    assert a.body("b3").mass < b.body("b3").mass
    fixtures = [n for n in (x.name for x in a.bodies) if not n.startswith("b")]
    assert fixtures and all(a.body(n) == b.body(n) for n in fixtures)
    assert a.gripper == b.gripper and a.objects == b.objects


def test_the_pybullet_backend_builds_cylinders_meshes_and_compounds(tmp_path):
    """Non-block scenes (issue 26): a cylinder, a mesh a domain ships, and a compound of
    both kinds build with the declared mass, friction and extent."""
    from sim_workers.engines.pybullet_engine import build_scene
    from sim_workers.scene import Body, BoxShape, CylinderShape, MeshShape, SceneDescription

    obj = tmp_path / "cube.obj"
    corners = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    faces = [(1, 3, 4, 2), (5, 6, 8, 7), (1, 2, 6, 5), (3, 7, 8, 4), (1, 5, 7, 3), (2, 4, 8, 6)]
    obj.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in corners)
                   + "".join("f " + " ".join(map(str, f)) + "\n" for f in faces))
    gripper = load("container").scene_description(load("container").true_properties()).gripper
    desc = SceneDescription(1 / 240, 50, (
        Body("table", (BoxShape((2, 2, 0.05)),), 0, (0, 0, -0.05), 0.5),
        Body("can", (CylinderShape(0.03, 0.12),), 0.4, (0.3, 0.0, 0.06), 0.7),
        Body("rock", (MeshShape(str(obj), (0.02, 0.03, 0.04)),), 0.2, (0.5, 0.2, 0.04), 0.9),
        Body("mug", (CylinderShape(0.04, 0.1), BoxShape((0.01, 0.02, 0.03), (0.05, 0, 0))), 0.3,
             (0.6, -0.2, 0.05), 0.6)), ("can", "rock", "mug"), gripper)
    client = pb.connect(pb.DIRECT)
    try:
        h = build_scene(client, desc)
        for name, mass, mu, size in (("can", 0.4, 0.7, (0.06, 0.06, 0.12)), ("rock", 0.2, 0.9, (0.04, 0.06, 0.08))):
            info = pb.getDynamicsInfo(h.bodies[name], -1, physicsClientId=client)
            assert info[0] == pytest.approx(mass) and info[1] == pytest.approx(mu)
            lo, hi = pb.getAABB(h.bodies[name], physicsClientId=client)
            assert np.allclose(np.subtract(hi, lo), size, atol=0.01)
        lo, hi = pb.getAABB(h.bodies["mug"], physicsClientId=client)
        assert hi[0] - lo[0] == pytest.approx(0.04 + 0.06, abs=0.01)      # the handle sticks out
        assert h.objects == tuple(h.bodies[n] for n in ("can", "rock", "mug"))
    finally:
        pb.disconnect(client)
