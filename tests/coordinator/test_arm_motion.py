"""Issue 41: a UR5e's joint trajectory for a step: the tool path followed to 1 mm, the joint
limits kept, every link clear of the believed scene, the same for a seed; what a
FollowJointTrajectory goal carries; a path the arm cannot take named, not crashed."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.loop.arm_motion import ArmPlanningError, TOLERANCE, plan_arm_step, start_joints
from coordinator.loop.reality import SimulatedReality
from coordinator.loop.session import Session
from coordinator.run_config import RunConfig
from planner.motion.joint_space import densify_joints
from sim_workers.robots.collision import links_checker


def _first_step(robot: str, domain: str = "container"):
    cfg = RunConfig(domain=domain, particles=4, true_size=0.045, episodes=1, seed=2, max_steps=5, robot=robot)
    s = Session(cfg)
    reality = SimulatedReality(domain, {"n_blocks": cfg.n_blocks}, s.props_of(s.truth_row()))
    try:
        s.start_episode(reality.start_episode(np.random.default_rng(0)))
    finally:
        reality.close()
    return s, s.next_step()


def _distance_to_path(p: np.ndarray, rows: np.ndarray) -> float:
    """The distance from point p to the polyline through the rows' (x, y, z)."""
    best = np.inf
    for a, b in zip(rows[:-1, 1:4], rows[1:, 1:4]):
        d = b - a
        f = 0.0 if not d.any() else float(np.clip((p - a) @ d / (d @ d), 0.0, 1.0))
        best = min(best, float(np.linalg.norm(a + f * d - p)))
    return best


@pytest.fixture(scope="module")
def steps():
    return _first_step("gripper"), _first_step("ur5e")


def test_the_arm_follows_the_tool_path_within_its_limits_and_clear_of_the_scene(steps):
    (_, gripper), (session, arm_step) = steps
    assert gripper.joint_trajectory is None and "joint_trajectory" not in gripper.to_dict()
    goal = arm_step.to_dict()["joint_trajectory"]
    arm = session.robot
    assert goal["joint_names"] == arm.joint_names
    q = np.array([p["positions"] for p in goal["points"]])
    v = np.array([p["velocities"] for p in goal["points"]])
    a = np.array([p["accelerations"] for p in goal["points"]])
    t = np.array([p["time_from_start"] for p in goal["points"]])
    assert len(q) == len(arm_step.trajectory) >= len(gripper.trajectory)
    assert np.all(np.diff(t) >= 0) and t[0] == 0.0
    assert np.all(q >= arm.low) and np.all(q <= arm.high)
    vmax = np.array([j.max_velocity for j in arm.joints])
    assert np.all(np.abs(v) <= 1.02 * vmax) and np.all(np.abs(a) <= 1.02 * arm.acceleration)
    # the tool: every point on the domain's path to 1 mm, and so is every joint-linear
    # piece's middle; the step's rows are the arm's own tool path
    for qi, row in zip(q, arm_step.trajectory):
        tool = arm.tool(qi)
        assert np.allclose(tool[:3, 3], row[1:4], atol=1e-9)
        assert _distance_to_path(tool[:3, 3], gripper.trajectory) <= TOLERANCE + 1e-9
    for qa, qb in zip(q[:-1], q[1:]):
        assert _distance_to_path(arm.tool(0.5 * (qa + qb))[:3, 3], gripper.trajectory) <= TOLERANCE + 1e-6
    # never faster than the domain timed the tool
    assert arm_step.trajectory[-1, 0] - arm_step.trajectory[0, 0] >= 0.99 * (gripper.trajectory[-1, 0]
                                                                               - gripper.trajectory[0, 0])
    # every link clear of the believed scene, densely along the path
    clear = links_checker(arm, session.domain.obstacles(session.observation.configuration,
                                                        session.clearance_sizes()))
    assert all(clear(qi) for qi in densify_joints(q, 0.01))


def test_the_same_seed_gives_the_same_joint_trajectory(steps):
    (_, _), (_, arm_step) = steps
    _, again = _first_step("ur5e")
    assert again.joint_trajectory == arm_step.joint_trajectory
    assert np.array_equal(again.trajectory, arm_step.trajectory)


def test_a_box_in_the_arm_s_way_is_named_and_a_domain_without_a_base_is_refused(steps):
    (_, gripper), (session, _) = steps
    arm = session.robot
    config = session.observation.configuration
    start = start_joints(arm, config.robot, [])
    # a slab over the whole work area at the wrists' height: no way through
    slab = [(np.array([0.0, 0.0, 0.3]), np.array([1.5, 1.5, 0.01]))]
    with pytest.raises(ArmPlanningError, match="branch|meets|link"):
        plan_arm_step(arm, gripper.trajectory, slab, start=start, seed=0, transit_end=None)
    with pytest.raises(ValueError, match="robot: no robot 'ur6'"):
        RunConfig(robot="ur6")


def test_an_arm_pushes_with_the_open_front_finger_and_its_wrist_stays_behind():
    """Issue 41: with a closed gripper the wrist stands 33 mm inside a tower taller than
    10 cm; a run with an arm pushes with the open front finger turned a quarter round."""
    from coordinator.domains import load
    from sim_workers.stack_and_push import state_mapping

    assert RunConfig(domain="stack_and_push", robot="ur5e").options["push_open"] is True
    assert RunConfig(domain="container", robot="ur5e").options["push_open"] is True
    assert "push_open" not in RunConfig(domain="container").options
    assert RunConfig(domain="container", robot="ur5e", options={"push_open": False}).options["push_open"] is False
    closed = load("stack_and_push").physics.spec
    opened = load("stack_and_push", push_open=True).physics.spec
    config = _first_step("gripper", "stack_and_push")[0].observation.configuration
    sizes = np.full(closed.n_blocks, 0.045)
    a = state_mapping.action_pose(closed, sizes, config, "push(r,tower,start,goal)")
    b = state_mapping.action_pose(opened, sizes, config, "push(r,tower,start,goal)")
    assert a[3] == 0.0 and a[4] == 0.0 and np.isclose(b[3], np.pi / 2) and b[4] == opened.max_opening
    # the pushing face where it was: the front finger's outer face instead of the closed pair's
    assert np.isclose(b[0] + opened.push_reach, a[0] + closed.push_reach)
    # the UR5e's wrist (0.045 m round the tool's axis) is behind the open finger's face, not ahead
    assert opened.push_reach > 0.045 > closed.push_reach
    # the particle worlds' Y for every row is the same pose
    rows = state_mapping.action_poses(opened, np.tile(sizes, (3, 1)), config, "push(r,tower,start,goal)")
    assert np.allclose(rows, b)


@pytest.mark.slow
def test_the_ur5e_runs_a_container_episode_to_the_end():
    """Issue 41: a whole container episode with the arm, in the simulated UR5e reality:
    every step planned (no dead end), every trajectory within the joint limits, and the
    task done. (Four blocks: a first episode that pushes a full tray of eight spills it, and
    a block that lands against the arm's base is out of its reach, a dead end the
    benchmark counts: benchmarks/bench_arm_motion.py.)"""
    cfg = RunConfig(domain="container", particles=8, true_size=0.045, episodes=1, seed=0, robot="ur5e",
                    n_blocks=4)
    s = Session(cfg)
    reality = SimulatedReality("container", {"n_blocks": cfg.n_blocks}, s.props_of(s.truth_row()))
    goals = []
    real_execute = reality.execute

    def execute(trajectory, action, **kw):
        goals.append(s.pending.joint_trajectory)
        return real_execute(trajectory, action, **kw)
    reality.execute = execute
    try:
        ep = s.run_episode(reality, np.random.default_rng(0))
    finally:
        reality.close()
    assert s.stats.dead_end is None and s.task.is_goal(s.state), (s.stats.dead_end, ep["utility"])
    assert goals and all(g is not None for g in goals)
    arm = s.robot
    for g in goals:
        q = np.array([p["positions"] for p in g["points"]])
        assert np.all(q >= arm.low) and np.all(q <= arm.high)
        assert np.abs([p["velocities"] for p in g["points"]]).max() <= 1.02 * np.pi


def test_a_step_s_joint_space_searches_stop_at_its_budget(steps, monkeypatch):
    """One step cannot hold a session's thread past STEP_BUDGET_S: with no budget left the
    joint-space search is refused by name (here the move to the step's first pose)."""
    import coordinator.loop.arm_motion as arm_motion

    (_, gripper), (session, _) = steps
    arm = session.robot
    start = start_joints(arm, session.observation.configuration.robot, [])
    monkeypatch.setattr(arm_motion, "STEP_BUDGET_S", 0.0)
    far = start.copy()
    far[0] += 1.0                       # the arm stands a joint turn away from the step's first pose
    with pytest.raises(ArmPlanningError, match="planning budget of 0 s is spent"):
        plan_arm_step(arm, gripper.trajectory, [], start=far, seed=0, transit_end=None)


def test_the_arm_moves_in_the_particle_worlds_and_the_simulated_arm_reports_the_joints_it_reached():
    """Issue 41, item 4: every real step's particle worlds get the arm's joints (its links
    move there), the simulated UR5e tracks the step's joints and reports where it stands,
    and the next step's joint trajectory starts from that report."""
    from coordinator.distributed.fanout import ShardPool
    from sim_workers.robots.motion import ArmMotion

    cfg = RunConfig(domain="stack_and_push", particles=6, true_size=0.045, episodes=1, seed=1, max_steps=4,
                    robot="ur5e", n_blocks=4, counterfactual_rows=0)   # the arm's worlds, not T's prior
    pool = ShardPool(cfg.domain, {"n_blocks": cfg.n_blocks, **cfg.options}, n_shards=0)
    s = Session(cfg, shard_pool=pool)
    reality = SimulatedReality(cfg.domain, {"n_blocks": cfg.n_blocks, **cfg.options}, s.props_of(s.truth_row()))
    arms, reports, goals = [], [], []
    simulate, execute = pool.simulate, reality.execute

    def simulate_seen(*a, **kw):
        arms.append(kw.get("arm"))
        return simulate(*a, **kw)

    def execute_seen(trajectory, action, **kw):
        goals.append(s.pending.joint_trajectory)
        obs = execute(trajectory, action, **kw)
        reports.append((kw.get("arm"), obs))
        return obs

    pool.simulate, reality.execute = simulate_seen, execute_seen
    try:
        s.run_episode(reality, np.random.default_rng(1))
    finally:
        reality.close()
        pool.close()
    assert len(reports) >= 2 and all(isinstance(a, ArmMotion) for a, _ in reports)
    # each real step's replay carries the step's joints (the choice of the real pose among
    # candidates, before the arm is planned, runs the tool rows alone)
    replayed = [a for a in arms if a is not None]
    assert all(any(a is m for a in replayed) for m, _ in reports)
    arm = s.robot
    for motion, obs in reports:
        q = obs.joint_positions
        assert q is not None and len(q) == 6
        # the simulated arm stood on the step's last point to well under a millimetre
        assert np.linalg.norm(arm.tool(q)[:3, 3] - arm.tool(motion.joints[-1])[:3, 3]) < 1e-4
        assert not np.array_equal(q, motion.joints[-1])            # but it tracked, not copied
    for (_, obs), goal in zip(reports[:-1], goals[1:]):
        assert np.allclose(goal["points"][0]["positions"], obs.joint_positions, atol=1e-9)


def test_an_action_the_arm_cannot_do_is_a_failure_t_learns_not_a_silent_end():
    """Issue 41: a block that came to rest beside the UR5e's base, 0.11 m from its axis (the
    wrist centre would have to be inside the shoulder's 0.133 m offset): T gets a failed
    pickup in that context, the episode pays a failed action, and with nothing else to plan
    from there the episode ends naming why. (A tower of eight 34 mm blocks the arm could not
    push was this test's case until the arm learned to change branch above the scene.)"""
    from coordinator.loop.reality import Observation
    from sim_workers.configuration import Configuration
    from sim_workers.container.probes import loaded_configuration

    s = Session(RunConfig(domain="container", n_blocks=4, particles=4, true_size=0.045, episodes=1, seed=0,
                          robot="ur5e"))
    d = s.domain
    loaded = loaded_configuration(d, np.full(4, 0.045), 3, np.random.default_rng(0))     # b1-b3 in the tray
    objects = loaded.objects.copy()
    objects[4] = [d.robot_base[0] + 0.11, d.robot_base[1], 0.0225, 0.0, 0.0, 0.0, 1.0]
    config = Configuration(loaded.robot, objects)
    s.start_episode(Observation(config, d.symbolic_state(config), d.measurements(config)))
    before = s.transition.to_planner()["pickup"]
    assert s.next_step() is None
    notes = s.stats.arm_refusals
    assert len(notes) == 1 and notes[0].startswith("the arm cannot pickup(r,b4,table): unreachable pose")
    assert "shoulder offset" in notes[0] and s.stats.dead_end == notes[0]
    assert s.experience.counts()["real"] == {("pickup", 0): (0.0, 1.0)}
    assert s.transition.to_planner()["pickup"] < before
    assert s.stats.actions == 1 and s.stats.failures == {"pickup": 1}


def _push_of_a_tower(size: float, height: int):
    """(session, configuration, key pose, tool rows, transit end) of the push of a tower of
    `height` blocks of `size` (jittered as stacked, seed 0), the gripper above it as a stack
    left it, in a run with the UR5e."""
    from coordinator.loop.reality import Observation
    from sim_workers.configuration import Configuration
    from sim_workers.stack_and_push.probes import tower_configuration

    # (robot: the push of a run with an arm: the open front finger, RunConfig's push_open)
    s = Session(RunConfig(domain="stack_and_push", particles=1, episodes=1, true_size=size, known_properties=True,
                          robot="ur5e"))
    d = s.domain
    objects = tower_configuration(d, np.full(8, size), height, np.random.default_rng(0)).objects
    top = objects[height - 1]
    config = Configuration(np.array([top[0], top[1], top[2] + 1.5 * size + d.spec.carry_margin, 0.0, 0.05]), objects)
    s.start_episode(Observation(config, d.symbolic_state(config), d.measurements(config)))
    action = "push(r,tower,start,goal)"
    x, _ = s._real_pose(config, action)
    transit = s._transit(config, d.pre_pose(config, action, x))
    rows = d.action_trajectory(config, action, x, transit)
    t_pre = d.transit_end_time(config, action, x, transit)
    return s, config, x, rows, t_pre


def test_a_wrist_over_the_tower_changes_branch_above_the_scene_in_a_straight_move(monkeypatch):
    """Issue 41: after stacking a tower of eight 32 mm blocks, the UR5e's wrist branch puts its
    wrist over the tower when the tool comes down behind it to push: every link of that
    branch is checked and refused. The arm changes branch above the scene (up, across,
    down: three straight joint moves, no search) and pushes. (In the learning benchmark's
    run this comes from, RRT* alone spent the step's 10 s on reconfigurations near the
    tower and the push was refused; here no search is allowed.)"""
    from coordinator.loop.arm_motion import SAFE_CLEARANCE, contact_time
    from coordinator.loop.transit import transit_checker
    from sim_workers.robots.base import tool_pose
    from sim_workers.robots.kinematics import nearest

    size = 0.0321
    s, config, x, rows, t_pre = _push_of_a_tower(size, 8)
    sizes = np.full(8, size)
    obstacles = s.domain.obstacles(config, sizes)
    arm = s.robot
    # the branch the arm stood on in the benchmark's run: wrist 2 at -pi/2, shoulder pan 2.4
    start = nearest(arm.branches(tool_pose(*config.robot[:4]), 0.0), np.array([2.37, -1.73, 1.67, -1.52, -1.57, 2.39]),
                    arm.low, arm.high)
    kw = dict(start=start, seed=0, transit_end=t_pre,
              tool_valid=transit_checker(s.domain, config, sizes, 0.0, float(rows[:, 5].max())),
              contact_from=contact_time(rows, x, t_pre))
    def no_search(*a, **k):
        raise AssertionError("a search where three straight moves do")
    monkeypatch.setattr("coordinator.loop.arm_motion.plan_joint_rrtstar", no_search)
    plan = plan_arm_step(arm, rows, obstacles, **kw)
    assert plan.replanned > 0
    tops = max(float(c[2] + h[2]) for c, h, _ in obstacles)
    assert plan.rows[:, 3].max() >= tops + SAFE_CLEARANCE - 1e-6          # it went over the top
    assert np.sign(np.sin(plan.end[4])) != np.sign(np.sin(start[4]))     # on the other wrist branch
    after = plan.source_t >= t_pre - 1e-9
    assert max(_distance_to_path(p, rows[rows[:, 0] >= t_pre - 1e-9]) for p in plan.rows[after, 1:4]) < TOLERANCE + 1e-6
    clear = links_checker(arm, obstacles)
    t_contact = plan.time_of(kw["contact_from"])
    for q in densify_joints(plan.path.q[plan.path.t + plan.rows[0, 0] <= t_contact - 1e-9], 0.01):
        assert clear(q)


def test_the_gripper_in_a_joint_space_transit_is_checked_at_the_believed_sizes(monkeypatch):
    """Issue 41: the links clear the belief's 97.5 % quantile; the gripper is checked as the
    domain's own transit checks it, at the believed sizes. The push's transit ends 4 mm behind
    the tower's believed rear face: at the quantile (a prior still wide) the tower would
    already touch the fingers there, and every joint-space move to it was refused ("goal is in
    collision": a tower of 4 the UR5e could not push in bench_arm_motion's episodes)."""
    from coordinator.loop import session as session_module
    from coordinator.loop.reality import Observation
    from sim_workers.configuration import Configuration
    from sim_workers.stack_and_push.probes import tower_configuration

    s = Session(RunConfig(domain="stack_and_push", n_blocks=4, particles=16, episodes=1, true_size=0.045, seed=0,
                          robot="ur5e"))
    d = s.domain
    objects = tower_configuration(d, np.full(4, 0.045), 4, np.random.default_rng(0)).objects
    config = Configuration(np.array([objects[-1][0], objects[-1][1], objects[-1][2] + 0.1175, 0.0, 0.05]), objects)
    s.start_episode(Observation(config, d.symbolic_state(config), d.measurements(config)))
    # A belief with a long upper tail (in bench_arm_motion's refused push the believed size
    # was 45.2 mm and its 97.5 % quantile 58.3 mm); here 20 mm above the believed size, past
    # the largest particle that Y's push pose keeps clear of.
    monkeypatch.setattr(s, "clearance_sizes", lambda: s.believed_sizes() + 0.02)
    seen = {}
    real = session_module.plan_arm_step

    def capture(arm, rows, obstacles, **kw):
        seen.update(kw, rows=rows)
        return real(arm, rows, obstacles, **kw)
    monkeypatch.setattr(session_module, "plan_arm_step", capture)
    step = s.next_step()
    assert step is not None and step.action == "push(r,tower,start,goal)", s.stats.arm_refusals
    rows = seen["rows"]
    end = rows[np.flatnonzero(rows[:, 0] <= seen["transit_end"] + 1e-9)[-1]]
    assert seen["tool_valid"](end[1:5])
