"""Robots as declarations (issue 41, first part): the UR5e's kinematics from its published
parameters, the closed-form inverse with every branch, the branch a real arm would take, and
poses no branch reaches named rather than crashed on."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from coordinator.cli import main
from sim_workers.robots import Arm, RobotError, Unreachable, describe, names, robot
from sim_workers.robots.base import Joint, tool_pose
from sim_workers.robots.kinematics import forward, inverse

UR = robot("ur5e")


def _turn_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def _least_move(branches: np.ndarray, current: np.ndarray) -> float:
    """Brute force: the smallest largest-joint move over every branch and every choice of
    -1, 0 or +1 turn per joint that stays within the UR5e's limits."""
    turns = np.array(np.meshgrid(*[[-1, 0, 1]] * 6)).reshape(6, -1).T * 2 * math.pi
    best = math.inf
    for b in branches:
        cand = b[None, :] + turns
        ok = np.all((cand >= UR.low) & (cand <= UR.high), axis=1)
        if ok.any():
            best = min(best, float(np.abs(cand[ok] - current).max(axis=1).min()))
    return best


def test_the_zero_pose_is_the_published_geometry_stretched_out():
    d = UR.dh
    p = forward(d, np.zeros(6))[:3, 3]
    np.testing.assert_allclose(p, [d.a2 + d.a3, -(d.d4 + d.d6), d.d1 - d.d5], atol=1e-12)


def test_every_branch_reaches_the_pose_and_the_joints_it_came_from_are_one_of_them():
    rng = np.random.default_rng(7)
    sizes = []
    for _ in range(400):
        q = rng.uniform(-math.pi, math.pi, 6)
        pose = forward(UR.dh, q)
        branches = inverse(UR.dh, pose)
        sizes.append(len(branches))
        for b in branches:
            assert np.abs(forward(UR.dh, b) - pose).max() < 1e-9
        assert _turn_distance(branches, q).max(axis=1).min() < 1e-7
        # distinct branches, not one solution repeated
        assert len({tuple(np.round(b, 6)) for b in branches}) == len(branches)
    assert max(sizes) == 8 and min(sizes) >= 2


def test_at_a_wrist_singularity_the_free_joint_takes_the_hint():
    q = np.array([0.3, -1.2, 1.1, -0.5, 0.0, 0.0])       # theta5 = 0: wrist 1 and 3 aligned
    pose = forward(UR.dh, q)
    for b in inverse(UR.dh, pose, wrist_hint=0.4):
        assert np.abs(forward(UR.dh, b) - pose).max() < 1e-9
        if abs(math.sin(b[4])) < 1e-9:
            assert b[5] == pytest.approx(0.4)


def test_the_arm_takes_the_branch_nearest_its_joints_within_the_limits():
    rng = np.random.default_rng(3)
    for _ in range(100):
        x, y, z, yaw = rng.uniform(0.25, 0.6), rng.uniform(-0.4, 0.4), rng.uniform(0.02, 0.3), rng.uniform(-3, 3)
        current = UR.home + rng.normal(0.0, 0.3, 6)
        q = UR.joints_for(x, y, z, yaw, current)
        assert np.all(q >= UR.low) and np.all(q <= UR.high)
        assert np.abs(UR.tool(q) - tool_pose(x, y, z, yaw)).max() < 1e-9
        # no branch, at any whole turn of any joint within the limits, moves the joints less
        assert np.abs(q - current).max() <= _least_move(UR.branches(tool_pose(x, y, z, yaw), float(current[5])),
                                                        current) + 1e-9


def test_a_pose_no_branch_reaches_is_named():
    with pytest.raises(Unreachable, match="elbow cannot span"):
        UR.joints_for(1.5, 0.0, 0.2, 0.0)
    with pytest.raises(Unreachable, match="inside the shoulder offset"):
        UR.joints_for(0.0, 0.0, 0.3, 0.0)

    class Stiff(Arm):                   # an arm whose elbow may not bend: nothing fits
        name, dh, joints = "stiff", UR.dh, UR.joints[:2] + (Joint("elbow_joint", -1e-3, 1e-3),) + UR.joints[3:]
        flange_to_tool = UR.flange_to_tool
    with pytest.raises(Unreachable, match="outside the joint limits"):
        Stiff().joints_for(0.4, 0.1, 0.1, 0.0, UR.home)


def test_every_registered_robot_describes_what_a_client_checks_a_trajectory_with():
    assert {"gripper", "ur5e"} <= set(names())
    for name in names():
        d = describe(name)
        assert d["name"] == name and d["joints"] and d["kind"] in ("floating", "arm")
    d = describe("ur5e")
    assert [j["name"] for j in d["joints"]] == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                                "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    assert d["dh"] == {"d1": 0.1625, "a2": -0.425, "a3": -0.3922, "d4": 0.1333, "d5": 0.0997, "d6": 0.0996}
    assert all(j["max_velocity"] == pytest.approx(math.pi) for j in d["joints"])
    # from the description alone, a client's own forward kinematics gives the arm's tool pose
    base, tool = np.array(d["base"]), np.array(d["flange_to_tool"])
    assert np.abs(base @ forward(UR.dh, UR.home) @ tool - UR.tool(UR.home)).max() < 1e-12
    with pytest.raises(RobotError, match="known: gripper, ur5e"):
        robot("ur10")


def test_a_plugin_robot_is_registered_and_a_broken_one_is_named_not_raised(monkeypatch):
    from importlib.metadata import EntryPoint

    import sim_workers.robots.base as registry

    plugins = [EntryPoint("ur5e_again", "sim_workers.robots.ur5e:UR5e", registry.ENTRY_POINT_GROUP),
               EntryPoint("ghost", "no_such_robot_package:Ghost", registry.ENTRY_POINT_GROUP)]
    monkeypatch.setattr(registry, "entry_points", lambda group: plugins if group == registry.ENTRY_POINT_GROUP else [])
    monkeypatch.setattr(registry, "_SEEN", set())
    monkeypatch.setattr(registry, "_BROKEN", {})
    assert {"gripper", "ur5e"} <= set(registry.names())
    assert "ghost" in registry.broken() and "No module named" in registry.broken()["ghost"]
    with pytest.raises(RobotError, match="unknown robot 'ghost'"):
        registry.robot("ghost")


def test_tmoc_robots_lists_them_and_its_json_parses(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    assert "ur5e  (arm)" in out and "elbow_joint" in out and "[-3.14159, 3.14159]" in out
    assert main(["robots", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["robots"]["gripper"]["joints"][0]["low"] is None          # unbounded: null, not Infinity
    assert data["robots"]["ur5e"]["flange_to_tool"][2][3] == 0.15 and data["broken"] == {}


def _episode_rows(domain: str, size: float, n: int = 8) -> list[np.ndarray]:
    """Every executed trajectory (rows t, x, y, z, yaw, opening) of one episode at the truth."""
    from coordinator.distributed.fanout import ShardPool
    from coordinator.loop.reality import SimulatedReality
    from coordinator.loop.session import Session
    from coordinator.run_config import RunConfig

    cfg = RunConfig(domain=domain, n_blocks=n, particles=2, true_size=size, known_properties=True, episodes=1,
                    seed=0, max_steps=30, counterfactual_rows=0)     # the arm's reach, not T's prior
    pool = ShardPool(domain, {"n_blocks": n}, n_shards=0)
    s = Session(cfg, pool)
    reality = SimulatedReality(domain, {"n_blocks": n}, s.props_of(s.truth_row()))
    rows: list[np.ndarray] = []

    class Recorded:
        def start_episode(self, rng):
            return reality.start_episode(rng)

        def execute(self, trajectory, action):
            rows.append(np.asarray(trajectory))
            return reality.execute(trajectory, action)
    try:
        s.run_episode(Recorded(), np.random.default_rng(0))
    finally:
        pool.close()
        reality.close()
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("domain", ["container", "stack_and_push"])
def test_from_the_domain_s_base_the_arm_reaches_every_tool_point_of_its_episodes(domain):
    from coordinator.domains import load

    base = load(domain).physics.robot_base
    assert base is not None
    arm = UR.placed(base)
    for size in (0.033, 0.057):               # near the prior's ends: the lowest grasps, the tallest piles
        rows = np.concatenate(_episode_rows(domain, size))       # key poses, up to 0.5 m apart
        q = arm.joints_for(*rows[0, 1:5], arm.home)
        branch = np.sign(q[[2, 4]])
        for row in rows:
            q = arm.joints_for(*row[1:5], q)
            assert np.abs(arm.tool(q) - tool_pose(*row[1:5])).max() < 1e-9
            # one elbow and one wrist branch all episode: the arm never passes through the
            # elbow's or the wrist's singularity between two key poses
            assert (np.sign(q[[2, 4]]) == branch).all(), (domain, size, row, q)
