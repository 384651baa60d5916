"""The session's transit to the pre-pose: collision-free among the observed obstacles."""
from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from sim_workers.blocks.hand import grip_depth
from coordinator.loop.reality import Observation
from coordinator.run_config import RunConfig
from coordinator.loop.session import Session
from coordinator.loop.transit import plan_pre_pose_transit, transit_checker
from planner.motion import box_checker, interpolate_config
from sim_workers.configuration import Configuration, quat_from_yaw
from sim_workers.grounded_world import GroundedWorld
from sim_workers.container.probes import loaded_configuration
from sim_workers.stack_and_push.probes import tower_configuration


def _session_at(config: Configuration) -> Session:
    s = Session(RunConfig(agent="tmp_rl", particles=1, episodes=1))
    s.start_episode(Observation(config, s.domain.symbolic_state(config), s.domain.measurements(config)))
    return s


def _dense_ok(session: Session, config: Configuration, path: np.ndarray) -> bool:
    """The loop's own check (empty hand, fingers at their widest) at 50 states a segment."""
    free = transit_checker(session.domain, config, session.believed_sizes(), 0.0)
    return all(free(interpolate_config(a, b, t)) for a, b in zip(path[:-1], path[1:])
               for t in np.linspace(0, 1, 50))


def test_transit_behind_a_full_pile_goes_over_it_not_through_it():
    domain = _session_at(Configuration(np.zeros(5), np.zeros((9, 7)) + [0, 0, 0, 0, 0, 0, 1])).domain
    sizes = np.full(8, 0.045)
    config = loaded_configuration(domain, sizes, 8, np.random.default_rng(0))
    config = Configuration(np.array([0.024, 0.0, 0.28, 0.0, 0.05]), config.objects)
    session = _session_at(config)
    pre = domain.pre_pose(config, "push(r,c,init,goal)",
                          domain.action_pose({"block_sizes": sizes}, config, "push(r,c,init,goal)"))
    path = session._transit(config, pre)
    assert path is not None, session.stats.transit_fallbacks
    np.testing.assert_allclose(path[0], config.robot[:4])
    np.testing.assert_allclose(path[-1], pre[:4])
    assert _dense_ok(session, config, path)
    # The scenario is a real obstacle: the straight segment would cut through the pile.
    assert not _dense_ok(session, config, np.array([config.robot[:4], pre[:4]]))
    assert len(path) > 2


def test_transit_in_free_space_is_the_straight_segment():
    domain = _session_at(Configuration(np.zeros(5), np.zeros((9, 7)) + [0, 0, 0, 0, 0, 0, 1])).domain
    truth = domain.true_properties()
    config = domain.initial_configuration(truth)
    session = _session_at(config)
    action = "pickup(r,b4,init)"
    pre = domain.pre_pose(config, action, domain.action_pose(truth, config, action))
    path = session._transit(config, pre)
    assert len(path) == 2 and _dense_ok(session, config, path)


def test_a_transit_that_fails_is_counted_in_the_episode_record():
    """Every strategy failing (here: a pre-pose inside the pile) leaves the action to the
    default transit, and the episode record says so: `transit_fallbacks` and the notes."""
    domain = _session_at(Configuration(np.zeros(5), np.zeros((9, 7)) + [0, 0, 0, 0, 0, 0, 1])).domain
    config = domain.initial_configuration(domain.true_properties())
    session = _session_at(config)
    inside = np.array([*config.objects[1][:3], 0.0, 0.05])        # the first block's centre
    draws = session.rng.bit_generator.state
    assert session._transit(config, inside) is None
    assert session.rng.bit_generator.state != draws               # RRT* was seeded, as before
    record = session.stats.record(0, session.posterior(), None)
    assert record["transit_fallbacks"] == 1
    assert "in collision" in record["transit_fallback_notes"][0]
    assert record["transit_fallback_notes"][0].endswith("(tried straight, up_across_down, over_the_top, rrtstar)")


# -- the checked transit is free in the scene itself ------------------------------------------

def _known_session(domain: str, size: float, config: Configuration) -> Session:
    """A session whose belief is the truth (every block `size`), at `config`."""
    s = Session(RunConfig(domain=domain, particles=1, episodes=1, true_size=size, known_properties=True))
    s.start_episode(Observation(config, s.domain.symbolic_state(config), s.domain.measurements(config)))
    return s


def _dense(path: np.ndarray, step: float = 0.005) -> list[np.ndarray]:
    """The path's states at most `step` apart."""
    return [interpolate_config(a, b, t) for a, b in zip(path[:-1], path[1:])
            for t in np.linspace(0, 1, int(np.ceil(np.linalg.norm(b[:3] - a[:3]) / step)) + 1)]


def _scene_bodies(domain, h) -> dict[int, str]:
    """Body id -> name of everything a gripper could hit: table, rail or tray, objects."""
    names = {b: n for n, b in zip(domain.object_names, h.objects)}
    names[h.table] = "table"
    for other in ("rail", "container"):
        if hasattr(h, other):
            names[getattr(h, other)] = other
    return names


def _touches_scene(domain, config: Configuration, sizes: np.ndarray, path: np.ndarray,
                   held: int | None = None, opening: float | None = None) -> list[tuple[int, str]]:
    """(state, body) pairs where the gripper, fingers `opening` apart (default: their
    widest, as the check's box), or the object it holds (`held`, a row of the objects,
    carried rigidly) touches the scene built with the true `sizes`, along the path every
    5 mm: what a robot moving along it would hit."""
    opening = domain.spec.max_opening if opening is None else opening
    with GroundedWorld(domain) as world:
        world.reset(config, {"block_sizes": sizes}, place=False)
        h, c = world.handles, world.client
        names = _scene_bodies(domain, h)
        movers = [(h.gripper, np.array([0.0, 0.0, h.palm_offset]))]
        if held is not None:
            names.pop(h.objects[held])
            movers.append((h.objects[held], config.objects[held, :3] - config.robot[:3]))
        for j in h.fingers:
            pb.resetJointState(h.gripper, j, opening / 2 + h.finger_inner, physicsClientId=c)
        hits = []
        for k, q in enumerate(_dense(path)):
            for body, offset in movers:
                pb.resetBasePositionAndOrientation(body, list(q[:3] + offset), quat_from_yaw(q[3]),
                                                   physicsClientId=c)
            pb.performCollisionDetection(physicsClientId=c)
            hits += [(k, name) for mover, _ in movers for body, name in names.items()
                     if pb.getClosestPoints(mover, body, 0.0, physicsClientId=c)]
        return hits


def _tower_session(size: float, seed: int) -> tuple[Session, Configuration]:
    """Every block of `size` in a (jittered, turned) tower, the gripper above it as a
    stack leaves it: what the push of a full tower starts from."""
    base = _known_session("stack_and_push", size, Configuration(np.zeros(5), np.tile([0, 0, 0, 0, 0, 0, 1.0], (8, 1))))
    domain, sizes = base.domain, np.full(8, size)
    config = tower_configuration(domain, sizes, 8, np.random.default_rng(seed))
    top = config.objects[-1]
    robot = np.array([top[0], top[1], top[2] + size / 2 + size + domain.spec.carry_margin, 0.0, 0.05])
    config = Configuration(robot, config.objects)
    return _known_session("stack_and_push", size, config), config


@pytest.mark.parametrize("size", [0.030, 0.045, 0.060])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_push_of_a_tower_of_eight_has_a_checked_transit_free_in_the_scene(size, seed):
    """The push's pre-pose is a few mm behind the tower's rear faces, alongside a tower up
    to 480 mm tall: the obstacle model (each block's box at its observed yaw) must leave
    that room, and the path it passes must touch nothing in the real scene."""
    session, config = _tower_session(size, seed)
    action = "push(r,tower,start,goal)"
    assert {f"on(b{i + 1},{'start' if i == 0 else f'b{i}'})" for i in range(8)} <= session.state
    x, _ = session._real_pose(config, action)
    pre = session.domain.pre_pose(config, action, x)
    path = session._transit(config, pre)
    assert path is not None, session.stats.transit_fallbacks
    np.testing.assert_array_equal(path[-1], pre[:4])
    assert _touches_scene(session.domain, config, np.full(8, size), path) == []
    # The approach from the pre-pose down behind the tower (fingers closed) touches nothing.
    approach = np.array([pre[:4], x[:4]])
    assert _touches_scene(session.domain, config, np.full(8, size), approach, opening=pre[4]) == []


def test_a_block_is_an_obstacle_as_it_lies():
    """A block's box is the cube itself at its observed pose: turned by 45 degrees it
    leaves free the corners of its bounds (the old any-yaw box, s/sqrt(2) each way, and
    an axis-aligned one did not)."""
    from sim_workers.obstacles import cube_box

    turned = cube_box(np.array([0.1, 0.2, 0.03, *quat_from_yaw(np.pi / 4)]), 0.06)
    np.testing.assert_allclose(turned[0], [0.1, 0.2, 0.03])
    np.testing.assert_allclose(turned[1], [0.03, 0.03, 0.03])
    corner = np.array([0.1 + 0.036, 0.2 + 0.036, 0.03, 0.0])     # inside the bounds, off the cube
    assert box_checker([turned], gripper_radius=0.005)(corner)
    assert not box_checker([turned], gripper_radius=0.005)(np.array([0.13, 0.2, 0.03, 0.0]))


def test_the_gripper_is_checked_as_palm_fingers_and_held_block():
    """The boxes the check moves: the palm, the fingers as far apart as they are, and a
    held 58 mm block, 29 mm out on both sides of the 24 mm fingers, hanging 48 mm below
    the fingertips (Y grips it a third of its side, 19.3 mm, below its top) and no wider than itself along them."""
    domain = _session_at(Configuration(np.zeros(5), np.zeros((9, 7)) + [0, 0, 0, 0, 0, 0, 1])).domain
    palm, fingers = domain.gripper_boxes(0.0)
    assert fingers[0][1] == pytest.approx(domain.spec.max_opening / 2 + 2 * domain.spec.finger_half[1] + 0.001)
    assert palm[1] - palm[0][2] <= fingers[1] + fingers[0][2]       # no gap between palm and fingers
    _, closed, block = domain.gripper_boxes(0.058, opening=0.058)
    assert closed[0][1] == pytest.approx(0.029 + 2 * domain.spec.finger_half[1] + 0.001)
    assert block[0][:2] == pytest.approx([0.03, 0.03])
    assert block[0][2] - block[1] == pytest.approx(0.058 - grip_depth(domain.spec, 0.058) + 0.001)   # its bottom


# -- a fallback's action is replayed from the trajectory's start ------------------------------

class _RecordingPool:
    """A shard pool that records where each particle-action was told to start and
    predicts nothing (every particle: no change)."""

    def __init__(self, measurements: int) -> None:
        self.starts: list[np.ndarray] = []
        self.measurements = measurements

    def simulate(self, start, sizes, action, trajectory, start_time=0.0) -> dict:
        n = len(sizes)
        self.starts.append(np.broadcast_to(np.asarray(start_time, dtype=np.float64), (n,)).copy())
        return {"states": [frozenset()] * n, "steps": np.ones(n, dtype=np.int64),
                "measurements": np.zeros((n, self.measurements)), "configurations": np.tile(start, (n, 1))}


def _observe_unchanged(session: Session) -> dict:
    """The real world says the pending action changed nothing (a failure)."""
    obs = session.observation
    return session.observe(Observation(obs.configuration, obs.state, obs.measurements))


@pytest.mark.parametrize("likelihood", ["replay", "paper"])
def test_a_fallback_is_replayed_by_the_particle_worlds_from_the_trajectory_start(monkeypatch, likelihood):
    """An unchecked transit may touch something, so the particle worlds simulate the whole
    trajectory the robot executed (start time 0), not from the pre-pose, and the note says
    so; an action with a checked transit still starts them at the pre-pose."""
    import coordinator.loop.session as session_module
    from coordinator.loop.episode import REPLAYED
    from planner.motion import Transit

    # The recording pool replays actions only: no counterfactual snapshot to ask it for.
    s = Session(RunConfig(particles=4, episodes=1, seed=0, likelihood=likelihood, particle_budget="fixed",
                          counterfactual_rows=0))
    config = s.domain.initial_configuration(s.domain.true_properties())
    first = Observation(config, s.domain.symbolic_state(config), s.domain.measurements(config))
    s.shard_pool = _RecordingPool(len(first.measurements))
    s.start_episode(first)
    checked = session_module.plan_pre_pose_transit
    monkeypatch.setattr(session_module, "plan_pre_pose_transit",
                        lambda *a, **k: Transit(None, "none", "goal (...) is in collision (forced)"))
    step = s.next_step()
    assert step.unchecked_transit and step.transit_end == 0.0
    # The robot moves along the default path: the trajectory the worlds replay.
    np.testing.assert_array_equal(step.trajectory, s.domain.action_trajectory(config, step.action, step.pose))
    assert "ess" in _observe_unchanged(s)
    np.testing.assert_array_equal(s.shard_pool.starts[-1], 0.0)
    assert s.stats.transit_fallbacks == ["goal (...) is in collision (forced)" + REPLAYED]

    monkeypatch.setattr(session_module, "plan_pre_pose_transit", checked)
    step = s.next_step()
    assert not step.unchecked_transit and step.transit_end > 0.0
    _observe_unchanged(s)
    assert np.all(s.shard_pool.starts[-1] > 0.0)
    if likelihood == "replay":
        np.testing.assert_array_equal(s.shard_pool.starts[-1], step.transit_end)
    assert len(s.stats.transit_fallbacks) == 1


def test_a_transit_through_a_tower_topples_it_only_when_the_particle_world_replays_it():
    """Why a fallback is replayed: the default path across at the carry height runs
    through a tower of five; a particle world started at the pre-pose never sees that."""
    from sim_workers.shard import Shard, decode_state

    # The 1.15 sides' opening (grasp_clearance 0): the wider default's open fingers pass
    # either side of this tower's top block on this path, and nothing topples.
    shard = Shard("stack_and_push", {"grasp_clearance": 0.0})
    domain, sizes = shard.domain, np.full(8, 0.045)
    config = tower_configuration(domain, sizes, 5, np.random.default_rng(0))
    config = Configuration(np.array([-0.25, 0.10, 0.15, 0.0, 0.085]), config.objects)
    action = "pickup(r,b6,init)"
    key = domain.action_pose({"block_sizes": sizes}, config, action)
    trajectory = domain.action_trajectory(config, action, key)      # the unchecked default path
    t_pre = domain.transit_end_time(config, action, key)
    tower = {"on(b1,start)", "on(b2,b1)", "on(b3,b2)", "on(b4,b3)", "on(b5,b4)"}
    assert tower <= domain.symbolic_state(config)
    row = np.array([[0.045]])                                        # one particle: the truth
    replayed, skipped = (decode_state(shard.simulate(config.to_array(), row, action, trajectory, t0)["states"][0])
                         for t0 in (0.0, t_pre))
    shard.close()
    assert tower <= skipped and "is_holding(r,b6)" in skipped
    assert not tower <= replayed


def _container_pile(size: float, columns: tuple[int, ...], held: int) -> Configuration:
    """Blocks of `size` piled in the tray, `columns[k]` blocks in a column at local x
    (k = 0: one column on the centre line; 0, 1: the two columns side by side), each
    turned a little; block `held` (0-based) in the closed hand at the carry height above
    its start slot; the rest in their start row."""
    domain = _session_at(Configuration(np.zeros(5), np.zeros((9, 7)) + [0, 0, 0, 0, 0, 0, 1])).domain
    spec, sizes = domain.spec, np.full(8, size)
    config = domain.initial_configuration({"block_sizes": sizes})
    objects = config.objects.copy()
    rng = np.random.default_rng(0)
    xs = [0.0] if len(columns) == 1 else [-(size + spec.slot_gap) / 2, (size + spec.slot_gap) / 2]
    i = 0
    for x, count in zip(xs, columns):
        for level in range(count):
            objects[1 + i, :3] = [x + rng.normal(0, 0.001), rng.normal(0, 0.001),
                                  spec.floor_top + (level + 0.5) * size]
            objects[1 + i, 3:] = quat_from_yaw(rng.uniform(-0.05, 0.05))
            i += 1
    slot = spec.init_slot(held)
    robot = np.array([slot[0], slot[1], spec.carry_height, 0.0, size])
    objects[1 + held] = [slot[0], slot[1], spec.carry_height + grip_depth(spec, size) - size / 2, 0, 0, 0, 1]
    return Configuration(robot, objects)


def _stack_key_over_column(domain, config: Configuration, size: float, x: float) -> np.ndarray:
    """The release pose over the column at local x: Y's rule (believed column height,
    clearance, fingertips grip_depth below the block's top), for a column Y may choose."""
    spec, c = domain.spec, config.objects[0]
    column = [o for o in config.objects[1:] if abs(o[0] - c[0] - x) < size / 2 and o[2] < 0.3 and o[2] > 0]
    z = spec.floor_top + len(column) * size + spec.release_clearance + size - grip_depth(spec, size)
    return np.array([c[0] + x, c[1], z, 0.0, spec.open_ratio * size])


@pytest.mark.parametrize("size, columns", [(0.048, (3, 2)), (0.054, (4,)), (0.060, (4,))])
def test_container_pre_poses_over_a_pile_of_large_blocks_have_checked_transits(size, columns):
    """A held block's stack over a pile of large blocks (two columns side by side, as
    large as fit, or one column of blocks too large for two) and the push of the loaded
    tray: each transit is checked (no fallback) and touches nothing in the scene, the held
    block included."""
    held = sum(columns)
    config = _container_pile(size, columns, held)
    session = _known_session("container", size, config)
    domain = session.domain
    assert f"is_holding(r,b{held + 1})" in session.state
    assert sum(a.startswith("at_container(") for a in session.state) == held
    action = f"stack(r,b{held + 1},c)"
    key = (domain.action_pose({"block_sizes": np.full(8, size)}, config, action) if len(columns) == 2
           else _stack_key_over_column(domain, config, size, 0.0))
    pre = domain.pre_pose(config, action, key)
    path = session._transit(config, pre)
    assert path is not None, session.stats.transit_fallbacks
    assert _touches_scene(domain, config, np.full(8, size), path, held=1 + held, opening=size) == []

    # The push of the loaded tray, the hand empty above the pile after the last stack.
    objects = config.objects.copy()
    objects[1 + held] = [*domain.spec.init_slot(held), size / 2, 0, 0, 0, 1]
    top = max(o[2] for o in objects[1:]) + size / 2
    empty = Configuration(np.array([key[0], key[1], top + domain.spec.STACK_LEAVE_CLEARANCE, 0.0, 0.07]), objects)
    session = _known_session("container", size, empty)
    action = "push(r,c,init,goal)"
    x, _ = session._real_pose(empty, action)
    pre = domain.pre_pose(empty, action, x)
    path = session._transit(empty, pre)
    assert path is not None, session.stats.transit_fallbacks
    assert _touches_scene(domain, empty, np.full(8, size), path) == []


def test_a_held_block_goes_over_a_taller_column_when_the_carry_height_is_too_low():
    """Four blocks in one column, one in the other: the stack's pre-pose over the low
    column is 170 mm up, the carry height 200 mm, so a held block carried across at the
    carry height meets the tall column's top (186 mm). The scene's own candidate goes up
    until the block clears it, across and down: checked, and free in the scene."""
    size, held = 0.045, 5
    config = _container_pile(size, (4, 1), held)
    session = _known_session("container", size, config)
    domain = session.domain
    action = f"stack(r,b{held + 1},c)"
    key = domain.action_pose({"block_sizes": np.full(8, size)}, config, action)
    assert key[0] > config.objects[0, 0]                         # the low column, on the right
    pre = domain.pre_pose(config, action, key)
    plan = plan_pre_pose_transit(domain, config, pre, session.believed_sizes(), size, seed=lambda: 0)
    assert plan.strategy == "over_the_top", plan
    assert plan.path[1, 2] > 0.186 + size - grip_depth(domain.spec, size)
    assert _touches_scene(domain, config, np.full(8, size), plan.path, held=1 + held, opening=size) == []


def test_a_dead_end_state_ends_the_episode_with_its_reason():
    # A block caught in the fingers with the container at goal: no plan reaches the goal
    # (stacking needs the container at init, pushing it back an empty hand). The episode
    # ends there, recorded, instead of failing the run or the robot's session.
    from sim_workers.domains import load as load_world

    s = Session(RunConfig(n_blocks=2, agent="tmoc", particles=4))
    config = load_world("container", n_blocks=2).initial_configuration({"block_sizes": np.full(2, 0.04)})
    stuck = frozenset({"is_in(c,goal)", "is_holding(r,b1)", "is_in(b2,init)"})
    s.start_episode(Observation(config, stuck, np.zeros(0)))
    assert s.next_step() is None and s.episode_done()
    record = s._finish_episode()
    assert "goal unreachable" in record["dead_end"] and record["actions"] == 0
    s.start_episode(Observation(config, frozenset({"is_in(c,init)", "hand_empty(r)", "is_in(b1,init)",
                                                   "is_in(b2,init)"}), np.zeros(0)))
    assert s.next_step() is not None and s.stats.dead_end is None
