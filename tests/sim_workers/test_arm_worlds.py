"""An arm in the grounded worlds (issue 41): its links follow the executed joints as
kinematic bodies in pybullet and MuJoCo and push what they meet; a position-controlled arm
in MuJoCo tracks a joint trajectory with a small, bounded error.

Real pybullet, real MuJoCo, the UR5e declaration; no part is replaced.
"""
from __future__ import annotations

import numpy as np
import pytest

from sim_workers import engines
from sim_workers.configuration import Configuration
from sim_workers.domains import load
from sim_workers.engines import make_world
from sim_workers.grounded_world import GroundedWorld
from sim_workers.robots import robot
from sim_workers.robots.collision import link_spheres, sphere_chain
from sim_workers.robots.kinematics import frames
from sim_workers.robots.motion import ArmMotion, frames_batch, link_poses
from sim_workers.robots.servo import CONTROL_DT, ServoArm, follow, tool_rows
from sim_workers.shard import Shard

ENGINES = [e for e in engines.ENGINES if e != "mujoco_warp"]
SIZE = 0.045


def _arm(domain):
    return robot("ur5e").placed(domain.robot_base)


def test_the_batched_kinematics_are_the_one_pose_kinematics():
    arm = robot("ur5e")
    q = np.random.default_rng(0).uniform(-3, 3, (5, 6))
    batch = frames_batch(arm.dh, q)
    for k in range(5):
        assert np.allclose(batch[k], np.array(frames(arm.dh, q[k])), atol=1e-12)


def test_each_link_capsule_is_placed_on_its_collision_spheres():
    """The world's capsule for a link sits where the planner's sphere chain for it does:
    its centre is the chain's middle, its axis along the chain."""
    domain = load("stack_and_push")
    arm = _arm(domain)
    q = arm.home + np.random.default_rng(1).uniform(-0.5, 0.5, 6)
    pos, quat = link_poses(arm, q[None])
    spheres, _ = link_spheres(arm, q)
    start = 0
    for k, cap in enumerate(arm.links):
        chain, _ = sphere_chain(cap)
        mine = spheres[start:start + len(chain)]
        start += len(chain)
        assert np.allclose(pos[0, k], 0.5 * (mine[0] + mine[-1]), atol=1e-12)
        x, y, z, w = quat[0, k]
        axis = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
        along = mine[-1] - mine[0]
        assert abs(abs(axis @ along) - np.linalg.norm(along)) < 1e-9


def _sweep(domain):
    """The first block in the path of the last wrist link, the arm moving the flange
    across the table from one side of the block to the other (the link, pointing down,
    reaching below the table's top, pushes the block's side), the tool rows held far from
    it: (start configuration, tool rows, the arm's motion). The arm's joints are not the
    rows' (a world takes both as given)."""
    arm = _arm(domain)
    cfg = domain.initial_configuration({"block_sizes": np.full(domain.n_objects, SIZE)})
    bx, by = cfg.objects[0, :2]
    q, joints = arm.home, []
    for y in np.linspace(by - 0.15, by + 0.08, 24):
        q = arm.joints_for(bx, y, -0.13, 0.0, q)
        joints.append(q)
    robot_pose = cfg.robot.copy()
    robot_pose[:3] = (0.3, -0.3, 0.4)
    rows = np.array([[0.0, *robot_pose[:5]], [2.0, *robot_pose[:5]]])
    motion = ArmMotion("ur5e", domain.robot_base, np.linspace(0.0, 2.0, len(joints)), np.array(joints))
    return Configuration(robot_pose, cfg.objects), rows, motion


@pytest.mark.parametrize("engine", ENGINES)
def test_a_link_that_sweeps_through_a_block_pushes_it(engine):
    domain = load("stack_and_push", n_blocks=4, engine=engine)
    start, rows, motion = _sweep(domain)
    props = {"block_sizes": np.full(4, SIZE)}
    with make_world(domain) as w:
        w.reset(start, props, place=False)
        still = w.execute(rows, "noop")
        w.reset(start, props, place=False)
        swept = w.execute(rows, "noop", arm=motion)
    moved = np.linalg.norm(swept.configuration.objects[0, :2] - start.objects[0, :2])
    stayed = np.linalg.norm(still.configuration.objects[0, :2] - start.objects[0, :2])
    assert moved > 0.01 and stayed < 0.002, (moved, stayed)


@pytest.mark.parametrize("engine", ENGINES)
def test_links_clear_of_the_scene_change_nothing_and_repeat_bit_for_bit(engine):
    """A pickup with the arm standing clear of everything: the outcome is the gripper's own,
    and the same again in a world that ran other actions first."""
    domain = load("stack_and_push", n_blocks=4, engine=engine)
    truth = {"block_sizes": np.full(4, SIZE)}
    arm = _arm(domain)
    high = arm.home.copy()
    high[1] = -2.2                                      # the upper arm up and back, over the base
    motion = ArmMotion("ur5e", domain.robot_base, [0.0], [high])
    cfg = domain.initial_configuration(truth)

    def pickup(world, arm_motion):
        placed = world.reset(cfg, truth)
        return _act_with(world, domain, placed, truth, arm_motion)

    with make_world(domain) as w:
        bare = pickup(w, None)
        first = pickup(w, motion)
        again = pickup(w, motion)
    assert first.state == bare.state == again.state
    assert np.array_equal(first.configuration.to_array(), bare.configuration.to_array())
    assert np.array_equal(first.configuration.to_array(), again.configuration.to_array())


def _act_with(world, domain, config, believed, motion):
    key = domain.action_pose(believed, config, "pickup(r,b1,init)")
    traj = domain.action_trajectory(config, "pickup(r,b1,init)", key)
    return world.execute(traj, "pickup(r,b1,init)", arm=motion)


def test_mujoco_blocks_with_the_links_as_controls_are_the_one_step_loop(monkeypatch):
    from sim_workers.engines.mujoco_world import MujocoWorld

    domain = load("stack_and_push", n_blocks=4, engine="mujoco")
    start, rows, motion = _sweep(domain)
    props = {"block_sizes": np.full(4, SIZE)}

    def run():
        with make_world(domain) as w:
            w.reset(start, props, place=False)
            return w.execute(rows, "noop", arm=motion)

    blocked = run()
    monkeypatch.setattr(MujocoWorld, "_run", GroundedWorld._run)
    stepped = run()
    assert blocked.steps == stepped.steps
    assert np.array_equal(blocked.configuration.to_array(), stepped.configuration.to_array())


@pytest.mark.parametrize("engine", ENGINES)
def test_a_shard_s_arm_results_do_not_depend_on_its_worlds(engine):
    domain = load("stack_and_push", n_blocks=4, engine=engine)
    start, rows, motion = _sweep(domain)
    sizes = np.array([[0.035], [0.045], [0.055]])
    one = Shard("stack_and_push", {"n_blocks": 4, "engine": engine}, n_worlds=1)
    two = Shard("stack_and_push", {"n_blocks": 4, "engine": engine}, n_worlds=2, threads=2)
    a = one.simulate(start.to_array(), sizes, "noop", rows, 0.0, arm=motion)
    b = two.simulate(start.to_array(), sizes, "noop", rows, 0.0, arm=motion)
    c = one.simulate(start.to_array(), sizes, "noop", rows, 0.0)
    one.close()
    two.close()
    assert np.array_equal(a["configurations"], b["configurations"])
    assert not np.array_equal(a["configurations"], c["configurations"])     # the arm did something
    with pytest.raises(ValueError, match="arm"):
        Shard("stack_and_push", {"n_blocks": 4, "engine": engine}).simulate(
            start.to_array(), sizes, "noop", np.stack([rows] * 3), 0.0, arm=motion)


def _timed_path(arm, q0, q1):
    from planner.motion.joint_space import time_joint_path

    w = q0 + np.linspace(0.0, 1.0, 40)[:, None] * (q1 - q0)
    return time_joint_path(w, np.full(6, np.pi), np.full(6, arm.acceleration))


def test_the_simulated_arm_tracks_a_timed_path_to_a_millimetre_and_settles_on_its_end():
    domain = load("stack_and_push")
    arm = _arm(domain)
    q0 = arm.home
    q1 = q0 + np.array([0.8, -0.3, 0.5, 0.2, 0.3, 1.0])
    path = _timed_path(arm, q0, q1)
    ref = ArmMotion("ur5e", domain.robot_base, path.t, path.q)
    out = ServoArm(arm, payload=0.6).track(ref)
    assert np.allclose(np.diff(out.times), CONTROL_DT)
    want = ref.at(out.times)
    tool = np.array([arm.tool(q)[:3, 3] for q in out.joints])
    wanted = np.array([arm.tool(q)[:3, 3] for q in want])
    err = np.linalg.norm(tool - wanted, axis=1)
    # it lags (not exact): 1.3 mm at the peak, the tool at 0.9 m/s (10 Hz joint loops)
    assert 1e-5 < err.max() < 2e-3
    assert err[-1] < 1e-5                   # and stands on the end
    again = ServoArm(arm, payload=0.6).track(ref)
    assert np.array_equal(again.joints, out.joints)


def test_the_tool_rows_of_the_tracked_joints_keep_the_commanded_fingers_and_efforts():
    domain = load("stack_and_push")
    arm = _arm(domain)
    q0 = arm.joints_for(0.0, 0.0, 0.2, 0.0, arm.home)
    q1 = arm.joints_for(0.05, 0.02, 0.15, 0.3, q0)
    path = _timed_path(arm, q0, q1)
    ref = ArmMotion("ur5e", domain.robot_base, path.t, path.q)
    rows = tool_rows(np.column_stack([path.t, np.zeros((len(path.t), 4)), np.full(len(path.t), 0.08),
                                      np.full(len(path.t), 5.0), np.full(len(path.t), 40.0)]), ref)
    assert np.allclose(rows[:, 1:4], [arm.tool(q)[:3, 3] for q in path.q], atol=1e-12)
    assert np.allclose(rows[-1, 1:4], (0.05, 0.02, 0.15), atol=1e-9) and abs(rows[-1, 4] - 0.3) < 1e-9
    assert np.all(rows[:, 5] == 0.08) and np.all(rows[:, 6] == 5.0) and np.all(rows[:, 7] == 40.0)
    tracked, actual = follow(rows, ref, None, 0.6)
    assert len(tracked) == len(actual.times) and abs(tracked[-1, 4] - 0.3) < 1e-4


def test_a_body_in_a_link_s_sweep_is_never_left_out():
    """pybullet leaves out of an action the bodies it cannot reach; a link's sweep reaches
    too, so the swept block is kept (it is pushed) and the outcome is the full world's (the
    left-out bodies to their resting settle of microns, as in any left-out action)."""
    domain = load("stack_and_push", n_blocks=4, engine="pybullet")
    action = next(a for a in ("pickup(r,b4,init)",) if a.partition("(")[0] in domain.leave_out_actions)
    start, rows, motion = _sweep(domain)
    props = {"block_sizes": np.full(4, SIZE)}
    outs = []
    for leave_out in (True, False):
        w = make_world(domain, leave_out=leave_out)
        w.reset(start, props, place=False)
        outs.append(w.execute(rows, action, arm=motion))
        w.close()
    assert np.linalg.norm(outs[0].configuration.objects[0, :2] - start.objects[0, :2]) > 0.05
    assert outs[0].state == outs[1].state
    assert np.array_equal(outs[0].configuration.objects[0], outs[1].configuration.objects[0])
    assert np.allclose(outs[0].configuration.objects, outs[1].configuration.objects, atol=1e-4)
