"""Y and Y^-1 of the container domain on hand-built configurations (no physics)."""
from __future__ import annotations

import numpy as np
import pytest

from sim_workers.blocks.hand import grip_depth
from sim_workers.configuration import Configuration, quat_from_yaw, rotate_z
from sim_workers.container.spec import ContainerSpec
from sim_workers.container import state_mapping as sm
from sim_workers.domains import load

SPEC = ContainerSpec()
NARROW = ContainerSpec(grasp_clearance=0.0)
S = 0.045
N = SPEC.n_blocks
UPRIGHT = [0.0, 0.0, 0.0, 1.0]


def base(sizes=None) -> Configuration:
    return sm.initial_configuration(SPEC, np.full(N, S) if sizes is None else np.asarray(sizes))


def with_objects(config: Configuration, robot=None, **blocks) -> Configuration:
    """Copy of `config` with some objects moved: c=(x, y, z[, yaw]), b3=(x, y, z[, yaw])."""
    objects = config.objects.copy()
    for name, pose in blocks.items():
        row = 0 if name == "c" else int(name[1:])
        yaw = pose[3] if len(pose) > 3 else 0.0
        objects[row] = [*pose[:3], *quat_from_yaw(yaw)]
    return Configuration(config.robot if robot is None else np.asarray(robot, dtype=float), objects)


def in_container(k: int, col: int, level: int = 0, c=(0.0, 0.0), cyaw: float = 0.0, s: float = S):
    """World pose (x, y, z, yaw) of a block resting in the container's column `col`."""
    lx = (1 if col else -1) * (s / 2 + SPEC.slot_gap / 2)
    xy = np.asarray(c) + rotate_z(np.array([lx, 0.0]), cyaw)
    return (xy[0], xy[1], SPEC.floor_top + level * s + s / 2, cyaw)


def held_pose(robot) -> tuple:
    """Where a block of size S hangs between the fingers of a gripper at `robot`."""
    return (robot[0], robot[1], robot[2] - (S / 2 - grip_depth(SPEC, S)), robot[3])


def atoms(**where) -> frozenset[str]:
    """The expected state: every block at init unless told, c at init, hand empty unless held."""
    out = {f"is_in(c,{where.pop('c', 'init')})"}
    held = False
    for i in range(1, N + 1):
        loc = where.get(f"b{i}", "init")
        if loc == "held":
            out.add(f"is_holding(r,b{i})")
            held = True
        elif loc == "container":
            out.add(f"at_container(b{i},c)")
        else:
            out.add(f"is_in(b{i},{loc})")
    if not held:
        out.add("hand_empty(r)")
    return frozenset(out)


# -- Y^-1 ----------------------------------------------------------------------------------
def test_initial_configuration_is_all_at_init_hand_empty():
    state = sm.symbolic_state(SPEC, base())
    assert state == atoms()
    assert state == frozenset({"is_in(c,init)", "hand_empty(r)", *(f"is_in(b{i},init)" for i in range(1, 9))})


def test_mixed_scene_every_label():
    robot = [0.10, 0.30, 0.20, 0.3, S]                     # lifted, fingers closed on S
    config = with_objects(
        base(), robot=robot,
        b2=(-0.35, 0.30, S / 2),                            # on the table, elsewhere
        b3=in_container(3, 0),                              # in the container, left
        b4=in_container(4, 1),                              # in the container, right
        b5=held_pose(robot),                                # between the fingers, lifted
        b6=(SPEC.delivered_x, 0.0, S / 2),                  # delivered
        b7=(SPEC.init_slot(6)[0] + 0.005, SPEC.init_slot(6)[1] - 0.004, S / 2, 0.1),  # jittered
        b8=(SPEC.init_slot(7)[0] + 0.03, SPEC.init_slot(7)[1], S / 2),   # 3 cm off its slot
    )
    assert sm.symbolic_state(SPEC, config) == atoms(
        b2="table", b3="container", b4="container", b5="held", b6="goal", b8="table")


def test_container_at_goal_with_its_load_rotated():
    c, cyaw = (0.58, 0.02), 0.25
    config = with_objects(base(), c=(*c, 0.0, cyaw), b1=in_container(1, 0, 0, c, cyaw),
                          b2=in_container(2, 1, 0, c, cyaw), b3=in_container(3, 0, 1, c, cyaw))
    assert sm.symbolic_state(SPEC, config) == atoms(
        c="goal", b1="container", b2="container", b3="container")


@pytest.mark.parametrize("x, where", [(0.29, "init"), (0.31, "goal"), (-0.05, "init"), (0.7, "goal")])
def test_container_location_is_the_nearer_one(x, where):
    assert sm.symbolic_state(SPEC, with_objects(base(), c=(x, 0.0, 0.0))) == atoms(c=where)


def test_block_beside_the_container_is_on_the_table():
    # Outside the walls (inner half 0.05 + 4 mm tolerance) at floor height: not loaded.
    config = with_objects(base(), b1=(0.0, SPEC.outer_half[1] + S / 2 + 0.001, S / 2),
                          b2=(SPEC.outer_half[0] + S / 2 + 0.001, 0.0, S / 2))
    assert sm.symbolic_state(SPEC, config) == atoms(b1="table", b2="table")


def test_not_held_when_fingers_wide_open_or_block_not_lifted():
    slot = SPEC.init_slot(3)
    open_robot = [slot[0], slot[1], 0.20, 0.0, SPEC.max_opening - 0.005]
    config = with_objects(base(), robot=open_robot, b4=held_pose(open_robot))
    assert sm.symbolic_state(SPEC, config) == atoms()     # b4 within 2 cm of its slot: init
    # Fingers closed on the block but still at the table: a grasp, not yet a pickup.
    low = [slot[0], slot[1], S - grip_depth(SPEC, S), 0.0, S]
    assert sm.symbolic_state(SPEC, with_objects(base(), robot=low)) == atoms()


def test_two_blocks_between_the_fingers_the_nearest_is_held():
    robot = [0.10, 0.30, 0.20, 0.0, S]
    near = held_pose(robot)
    far = (near[0] + 0.010, near[1] + 0.030, near[2] - 0.02)  # inside the hand's box, further
    # Whichever index it has, the nearer block is the held one.
    for held, other in (("b2", "b1"), ("b1", "b2")):
        config = with_objects(base(), robot=robot, **{held: near, other: far})
        assert sm.symbolic_state(SPEC, config) == atoms(**{held: "held", other: "table"})


def test_domain_symbolic_state_is_the_same_function():
    domain = load("container")
    config = with_objects(base(), b3=in_container(3, 0))
    assert domain.symbolic_state(config) == sm.symbolic_state(SPEC, config)


# -- Y -------------------------------------------------------------------------------------
@pytest.mark.parametrize("yaw, folded", [(0.0, 0.0), (0.5, 0.5), (1.2, 1.2 - np.pi / 2), (-0.9, -0.9 + np.pi / 2)])
def test_pickup_pose_scales_with_the_believed_size(yaw, folded):
    # At 1.15 sides (no clearance), where the opening is the block's alone; the clearance's
    # room rule (the neighbours' believed reach) is tested in test_grasp_clearance.py.
    slot = SPEC.init_slot(2)
    config = with_objects(base(), b3=(slot[0] + 0.004, slot[1] - 0.003, S / 2, yaw))
    poses = []
    for s in (0.030, 0.045, 0.060):
        sizes = np.full(N, 0.05)
        sizes[2] = s                                       # only b3's belief matters
        pose = sm.action_pose(NARROW, sizes, config, "pickup(r,b3,init)")
        np.testing.assert_allclose(pose[:2], config.objects[3, :2])
        assert pose[2] == pytest.approx(s - grip_depth(NARROW, s))
        assert pose[3] == pytest.approx(folded)
        assert pose[4] == pytest.approx(NARROW.open_ratio * s)
        poses.append(pose)
    poses = np.array(poses)
    # Linear in s: 15 mm more size, 10 mm higher (the fingertips at two thirds of the
    # believed side: the grip deepens with it) and 1.15 x 15 mm wider.
    np.testing.assert_allclose(np.diff(poses[:, 2]), [0.010, 0.010])
    np.testing.assert_allclose(np.diff(poses[:, 4]), [NARROW.open_ratio * 0.015] * 2)
    # The other blocks' beliefs do not move b3's grasp.
    other = np.full(N, 0.03)
    other[2] = 0.045
    np.testing.assert_array_equal(sm.action_pose(NARROW, other, config, "pickup(r,b3,init)"), poses[1])


def test_pickup_pose_never_below_the_table():
    sizes = np.full(N, 0.01)
    assert sm.action_pose(SPEC, sizes, base(sizes), "pickup(r,b1,init)")[2] == pytest.approx(0.003)


def _loaded(k: int, s: float = S, c=(0.0, 0.0), cyaw: float = 0.0) -> Configuration:
    """The first k blocks in the container: b1 left, b2 right, b3 left on b1, ..."""
    blocks = {f"b{i + 1}": in_container(i, i % 2, i // 2, c, cyaw, s) for i in range(k)}
    return with_objects(base(np.full(N, s)), c=(*c, 0.0, cyaw), **blocks)


def test_stack_release_height_grows_with_the_pile():
    sizes = np.full(N, S)
    zs = []
    for k in range(6):
        config = _loaded(k)
        assert sm.symbolic_state(SPEC, config) >= {f"at_container(b{i + 1},c)" for i in range(k)}
        pose = sm.action_pose(SPEC, sizes, config, "stack(r,b8,c)")
        col = k % 2                                       # the lower column, ties left
        x_expected = (1 if col else -1) * (S / 2 + SPEC.slot_gap / 2)
        assert pose[0] == pytest.approx(x_expected) and pose[1] == pytest.approx(0.0)
        assert pose[2] == pytest.approx(SPEC.floor_top + (k // 2) * S + SPEC.release_clearance
                                        + S - grip_depth(SPEC, S))
        assert pose[4] == pytest.approx(SPEC.open_ratio * S)
        zs.append(pose[2])
    assert np.all(np.diff(zs) >= 0) and zs[4] - zs[0] == pytest.approx(2 * S)


def test_stack_height_comes_from_the_believed_sizes_of_the_pile():
    config = _loaded(4)
    small = sm.action_pose(SPEC, np.full(N, 0.040), config, "stack(r,b8,c)")
    large = sm.action_pose(SPEC, np.full(N, 0.048), config, "stack(r,b8,c)")   # still two columns
    # Two blocks below in the column, plus two thirds of the held block (its grip deepens
    # with it).
    assert large[2] - small[2] == pytest.approx(2 * 0.008 + 0.008 * 2 / 3)


def test_stack_pose_follows_a_moved_and_turned_container():
    c, cyaw = (0.6, 0.05), 0.3
    pose = sm.action_pose(SPEC, np.full(N, S), _loaded(1, c=c, cyaw=cyaw), "stack(r,b8,c)")
    xy = np.asarray(c) + rotate_z(np.array([S / 2 + SPEC.slot_gap / 2, 0.0]), cyaw)
    np.testing.assert_allclose(pose[:2], xy)
    assert pose[3] == pytest.approx(cyaw)


@pytest.mark.parametrize("action, direction", [("push(r,c,init,goal)", 1), ("push(r,c,goal,init)", -1)])
def test_push_pose_is_independent_of_sizes(action, direction):
    c = (0.0, 0.0) if direction > 0 else SPEC.container_goal
    config = _loaded(4, c=c)
    poses = [sm.action_pose(SPEC, np.full(N, s), config, action) for s in (0.03, 0.045, 0.06)]
    mixed = np.linspace(0.03, 0.06, N)
    poses.append(sm.action_pose(SPEC, mixed, config, action))
    for p in poses[1:]:
        np.testing.assert_array_equal(p, poses[0])
    behind = c[0] - direction * (SPEC.outer_half[0] + SPEC.finger_half[0] + 0.012)
    np.testing.assert_allclose(poses[0], [behind, c[1], SPEC.push_tip_z, 0.0, SPEC.push_opening])
    end = sm.push_end_x(SPEC, config, action, poses[0])
    target = SPEC.location_xy(action.split(",")[3][:-1])
    assert end - poses[0][0] == pytest.approx(target[0] - c[0])


# -- re-grounding under a hypothesis ------------------------------------------------------
def test_place_for_sizes_piles_container_blocks_by_hypothesised_sizes():
    observed = with_objects(
        base(),
        # b2 was seen *below* b1 in the left column: order comes from observed heights.
        b1=(-0.020, 0.004, 0.090, 0.1), b2=(-0.030, -0.002, 0.030), b3=(0.025, 0.0, 0.040),
        b4=(-0.35, 0.30, 0.10, 0.2))                     # on the table, seen at a wrong height
    sizes = np.array([0.030, 0.048, 0.040, 0.035, 0.045, 0.045, 0.045, 0.045])   # two columns
    placed = sm.place_for_sizes(SPEC, observed, sizes)
    f = SPEC.floor_top
    o = placed.objects
    assert o[2, 2] == pytest.approx(f + 0.048 / 2)                  # b2 first in its column
    assert o[1, 2] == pytest.approx(f + 0.048 + 0.030 / 2)          # b1 on top of b2
    assert o[3, 2] == pytest.approx(f + 0.040 / 2)                  # b3 alone on the right
    assert o[4, 2] == pytest.approx(0.035 / 2)                      # table block rests on it
    for i in range(5, 9):
        assert o[i, 2] == pytest.approx(sizes[i - 1] / 2)
    # Planar poses kept (clipped inside the walls); container blocks take the container's yaw.
    assert o[1, 0] < 0 and o[2, 0] < 0 and o[3, 0] > 0
    np.testing.assert_allclose(o[4, :2], observed.objects[4, :2])
    np.testing.assert_allclose(o[1:4, 3:], np.tile(UPRIGHT, (3, 1)), atol=1e-12)
    for i in range(1, 4):                                            # inside the walls
        assert abs(o[i, 0]) + sizes[i - 1] / 2 <= SPEC.inner_half[0] + 1e-12
    assert sm.symbolic_state(SPEC, placed) == sm.symbolic_state(SPEC, observed)


# b3 rests on b1 in the left column (two columns), or on b1 and b2 (one column: 52 mm and
# up do not fit in half the tray).
@pytest.mark.parametrize("s, below_b3", [(0.030, 1), (0.040, 1), (0.052, 2), (0.060, 2)])
def test_place_for_sizes_keeps_the_symbolic_state(s, below_b3):
    robot = [0.10, 0.30, 0.20, 0.0, S]
    observed = with_objects(_loaded(3), robot=robot, b5=held_pose(robot),
                            b6=(SPEC.delivered_x, 0.1, 0.03), b7=(-0.35, 0.0, S / 2))
    placed = sm.place_for_sizes(SPEC, observed, np.full(N, s))
    assert sm.symbolic_state(SPEC, placed) == sm.symbolic_state(SPEC, observed) == atoms(
        b1="container", b2="container", b3="container", b5="held", b6="goal", b7="table")
    assert placed.robot[4] == pytest.approx(s)                       # fingers on its width
    np.testing.assert_array_equal(placed.objects[5, :3], observed.objects[5, :3])
    np.testing.assert_allclose(placed.objects[6, :3], [*SPEC.delivered_slot(5), s / 2])
    assert placed.objects[3, 2] == pytest.approx(SPEC.floor_top + below_b3 * s + s / 2)


def test_domain_place_validates_and_regrounds():
    domain = load("container")
    config = _loaded(2)
    placed = domain.place(config, {"block_sizes": np.full(N, 0.05)})
    assert placed.objects[1, 2] == pytest.approx(SPEC.floor_top + 0.025)


# -- after an action -----------------------------------------------------------------------
def test_after_push_to_goal_the_helper_unloads():
    domain = load("container")
    config = _loaded(3, c=SPEC.container_goal)
    after = domain.after_action(config, "push(r,c,init,goal)")
    assert sm.symbolic_state(SPEC, config) == atoms(c="goal", b1="container", b2="container", b3="container")
    assert sm.symbolic_state(SPEC, after) == atoms(c="goal", b1="goal", b2="goal", b3="goal")
    for i in range(3):
        np.testing.assert_allclose(after.objects[1 + i, :2], SPEC.delivered_slot(i))
        np.testing.assert_allclose(after.objects[1 + i, 3:], UPRIGHT)
    np.testing.assert_array_equal(after.objects[4:], config.objects[4:])
    np.testing.assert_array_equal(after.objects[0], config.objects[0])


def test_after_action_changes_nothing_elsewhere():
    domain = load("container")
    at_init = _loaded(3)
    assert domain.after_action(at_init, "push(r,c,goal,init)") is at_init   # not at goal
    at_goal = _loaded(3, c=SPEC.container_goal)
    assert domain.after_action(at_goal, "stack(r,b3,c)") is at_goal        # not a push
    assert domain.after_action(at_goal, "pickup(r,b4,init)") is at_goal


# -- bad actions ---------------------------------------------------------------------------
@pytest.mark.parametrize("action", ["lift(r,b1)", "pickup r b1 init", "pickup(r,b1", "", "push((r))"])
def test_unparsable_actions_are_named_in_the_error(action):
    with pytest.raises(ValueError) as err:
        sm.action_pose(SPEC, np.full(N, S), base(), action)
    assert "action" in str(err.value) and repr(action) in str(err.value)


@pytest.mark.parametrize("action, named", [("pickup(r,b9,init)", "'b9'"), ("stack(r,x1,c)", "'x1'"),
                                           ("pickup(r,b0,init)", "'b0'")])
def test_unknown_blocks_are_named(action, named):
    with pytest.raises(ValueError, match=named):
        sm.action_pose(SPEC, np.full(N, S), base(), action)


def test_check_action_names_the_bad_argument():
    domain = load("container")
    domain.check_action("pickup(r,b1,table)")
    domain.check_action("push(r,c,goal,init)")
    with pytest.raises(ValueError, match="'goal'"):
        domain.check_action("pickup(r,b1,goal)")
    with pytest.raises(ValueError, match="mars"):
        domain.check_action("push(r,c,init,mars)")
    with pytest.raises(ValueError, match="'b12'"):
        domain.check_action("stack(r,b12,c)")
    with pytest.raises(ValueError, match="teleport"):
        domain.check_action("teleport(r,b1)")


# -- vectorised Y: what the coordinator calls once per action for all N particles ------------
def _vector_scenes():
    yield base(), ["pickup(r,b1,init)", "pickup(r,b4,init)"]
    loaded = _loaded(2, c=(0.05, -0.02), cyaw=0.4)
    yield loaded, [f"stack(r,b{k},c)" for k in range(3, N + 1)] + \
        ["push(r,c,init,goal)", "push(r,c,goal,init)"]


def test_action_poses_equal_per_row_action_pose_bit_for_bit():
    rng = np.random.default_rng(7)
    domain = load("container")
    for config, actions in _vector_scenes():
        rows = rng.uniform(0.025, 0.065, size=(64, N))
        for action in actions:
            batch = domain.action_poses(rows, config, action)
            single = np.array([domain.action_pose({"block_sizes": r}, config, action) for r in rows])
            assert batch.shape == (64, 5)
            np.testing.assert_array_equal(batch, single, err_msg=action)
    # a shared size (one column of L) broadcasts to every block
    shared = rng.uniform(0.03, 0.06, size=(8, 1))
    config = base()
    np.testing.assert_array_equal(
        domain.action_poses(shared, config, "pickup(r,b2,init)"),
        [domain.action_pose({"block_sizes": np.full(N, r[0])}, config, "pickup(r,b2,init)") for r in shared])


def test_action_poses_refuses_a_size_out_of_range_by_name():
    domain = load("container")
    rows = np.full((3, N), 0.05)
    rows[1, 2] = 5.0
    with pytest.raises(ValueError, match="block_sizes"):
        domain.action_poses(rows, base(), "pickup(r,b3,init)")
