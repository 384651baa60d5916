"""The tray's column layout (issues 24 and 40): Y places every block inside the tray for
every L of the prior, in two columns when they fit side by side in the tray and in one
column otherwise; a tray that holds blocks keeps the layout it has under every hypothesis;
re-grounding and Y^-1 agree with it. Geometry without physics, then physical checks."""
from __future__ import annotations

import numpy as np
import pytest

from sim_workers.blocks.hand import grip_depth
from sim_workers.configuration import Configuration, quat_from_yaw, rotate_z
from sim_workers.container import columns
from sim_workers.container import state_mapping as sm
from sim_workers.container.spec import ContainerSpec
from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld, act

SPEC = ContainerSpec()
N = SPEC.n_blocks
# The largest size Y piles an empty tray in two columns with: half the tray beside half the
# slot gap (48.5 mm); the largest two columns hold at all: half the tray (50 mm).
TWO_COLUMN_MAX = SPEC.inner_half[0] - SPEC.slot_gap / 2
SIDE_BY_SIDE_MAX = SPEC.inner_half[0]
C, CYAW = (0.04, -0.03), 0.3          # a moved and turned tray: the layout is in its frame


def hypotheses() -> list[np.ndarray]:
    """Sizes across the prior: shared sizes from 30 to 60 mm, and per-block ones (one block
    20 % larger, as the "sizes" variation; mixed small and large)."""
    out = [np.full(N, s) for s in np.linspace(SPEC.prior_low, SPEC.prior_high, 13)]
    for s in (0.040, 0.045, 0.050):
        sizes = np.full(N, s)
        sizes[0] *= 1.2
        out.append(sizes)
    out.append(np.linspace(SPEC.prior_low, SPEC.prior_high, N))
    out.append(np.random.default_rng(4).uniform(SPEC.prior_low, SPEC.prior_high, N))
    return out


def at_rest(config: Configuration, i: int, key: np.ndarray, s: float) -> Configuration:
    """`config` with block i resting where a stack at `key` releases it (upright, at the
    tray's yaw, its bottom on the pile Y computed)."""
    objects = config.objects.copy()
    bottom = key[2] - (s - grip_depth(SPEC, s)) - SPEC.release_clearance
    objects[1 + i] = [key[0], key[1], bottom + s / 2, *quat_from_yaw(key[3])]
    return Configuration(config.robot, objects)


def stacked_by_y(sizes: np.ndarray, k: int) -> Configuration:
    """The first k blocks stacked one after another with Y's poses for `sizes`."""
    config = sm.initial_configuration(SPEC, sizes)
    objects = config.objects.copy()
    objects[0] = [*C, 0.0, *quat_from_yaw(CYAW)]
    config = Configuration(config.robot, objects)
    for i in range(k):
        key = sm.action_pose(SPEC, sizes, config, f"stack(r,b{i + 1},c)")
        config = at_rest(config, i, key, sizes[i])
    return config


def tray_boxes(config: Configuration, sizes: np.ndarray, k: int) -> np.ndarray:
    """(k, 2, 3) low and high corners of the first k blocks in the tray's frame."""
    boxes = []
    for i in range(k):
        p = config.objects[1 + i, :3]
        local = rotate_z(p[:2] - np.asarray(C), -CYAW)
        centre = np.array([local[0], local[1], p[2]])
        boxes.append([centre - sizes[i] / 2, centre + sizes[i] / 2])
    return np.array(boxes)


# -- the rule ------------------------------------------------------------------------------
@pytest.mark.parametrize("s, two", [(0.030, True), (0.045, True), (TWO_COLUMN_MAX - 1e-6, True),
                                    (TWO_COLUMN_MAX + 1e-6, False), (0.050, False), (0.054, False),
                                    (0.060, False)])
def test_two_columns_iff_every_block_fits_in_half_the_tray(s, two):
    assert columns.two_columns(SPEC, np.full(N, s)) is two
    # One block too large for half the tray puts the whole hypothesis in one column.
    mixed = np.full(N, 0.035)
    mixed[5] = s
    assert columns.two_columns(SPEC, mixed) is two


def test_the_rule_follows_the_tray_not_a_size():
    wide = ContainerSpec(inner_half=(0.065, 0.036))
    assert columns.two_columns(wide, np.full(N, 0.060))
    assert columns.tallest_pile(wide) == pytest.approx(0.060 * N / 2)
    assert columns.tallest_pile(SPEC) == pytest.approx(0.060 * N)      # 60 mm: one column


def test_the_vectorised_rule_is_one_per_hypothesis():
    rows = np.array([np.full(N, 0.040), np.full(N, 0.055), np.linspace(0.03, 0.06, N)])
    np.testing.assert_array_equal(columns.two_columns(SPEC, rows), [True, False, False])


def test_pose_classes_are_the_stack_layout_per_row():
    domain = load("container")
    config = sm.initial_configuration(SPEC, np.full(N, 0.045))
    shared = np.array([[0.040], [0.048], [0.049], [0.060]])
    np.testing.assert_array_equal(domain.pose_classes(shared, config, "stack(r,b2,c)"), [1, 1, 0, 0])
    per_block = np.array([np.full(N, 0.040), np.r_[0.054, np.full(N - 1, 0.040)]])
    np.testing.assert_array_equal(domain.pose_classes(per_block, config, "stack(r,b2,c)"), [1, 0])
    for action in ("pickup(r,b2,init)", "push(r,c,init,goal)"):     # no discrete choice
        np.testing.assert_array_equal(domain.pose_classes(shared, config, action), [0, 0, 0, 0])


# -- Y: a feasible placement for every L -----------------------------------------------------
@pytest.mark.parametrize("h", range(len(hypotheses())))
def test_every_stacked_block_lies_inside_the_tray_and_apart(h):
    sizes = hypotheses()[h]
    two = columns.two_columns(SPEC, sizes)
    ix, iy = SPEC.inner_half
    for k in range(1, N + 1):
        config = stacked_by_y(sizes, k)
        boxes = tray_boxes(config, sizes, k)
        assert np.all(boxes[:, 0, :2] >= [-ix - 1e-12, -iy - 1e-12]), (k, boxes)
        assert np.all(boxes[:, 1, :2] <= [ix + 1e-12, iy + 1e-12]), (k, boxes)
        assert np.all(boxes[:, 0, 2] >= SPEC.floor_top - 1e-12)
        for a in range(k):
            for b in range(a):
                overlap = np.minimum(boxes[a, 1], boxes[b, 1]) - np.maximum(boxes[a, 0], boxes[b, 0])
                assert np.any(overlap <= 1e-12), (k, a, b)      # touching, never inside
        assert sm.symbolic_state(SPEC, config) >= {f"at_container(b{i + 1},c)" for i in range(k)}
    # Where the pile went: one column on the centre line, or both halves in use.
    centres = (boxes[:, 0, 0] + boxes[:, 1, 0]) / 2
    if two:                                             # each block off the centre line
        assert np.all(np.abs(centres) >= sizes / 2 - 1e-12) and (centres < 0).any() and (centres > 0).any()
    else:
        np.testing.assert_allclose(centres, 0.0, atol=1e-12)


@pytest.mark.parametrize("s", [0.049, 0.054, 0.060])
def test_large_blocks_pile_in_one_column_on_the_centre_line(s):
    sizes = np.full(N, s)
    config = stacked_by_y(sizes, 3)
    key = sm.action_pose(SPEC, sizes, config, "stack(r,b4,c)")
    np.testing.assert_allclose(key[:2], C, atol=1e-15)
    assert key[2] == pytest.approx(SPEC.floor_top + 3 * s + SPEC.release_clearance + s - grip_depth(SPEC, s))
    # The vectorised Y makes the same choice, row by row, beside two-column hypotheses.
    rows = np.array([sizes, np.full(N, 0.040), sizes])
    batch = sm.action_poses(SPEC, rows, config, "stack(r,b4,c)")
    np.testing.assert_array_equal(batch[0], key)
    np.testing.assert_array_equal(batch[2], key)
    np.testing.assert_array_equal(batch[1], sm.action_pose(SPEC, rows[1], config, "stack(r,b4,c)"))


@pytest.mark.parametrize("s", [0.030, 0.045, 0.048])
def test_small_blocks_still_pile_in_two_columns(s):
    sizes = np.full(N, s)
    lx = s / 2 + SPEC.slot_gap / 2
    for k, (side, level) in enumerate([(-1, 0), (1, 0), (-1, 1), (1, 1)]):
        key = sm.action_pose(SPEC, sizes, stacked_by_y(sizes, k), f"stack(r,b{k + 1},c)")
        local = rotate_z(key[:2] - np.asarray(C), -CYAW)
        np.testing.assert_allclose(local, [side * lx, 0.0], atol=1e-15)
        below = SPEC.floor_top + level * s                  # the column's top under the block
        assert key[2] == pytest.approx(below + SPEC.release_clearance + s - grip_depth(SPEC, s))


@pytest.mark.parametrize("s", [0.049, 0.0493, SIDE_BY_SIDE_MAX])
def test_a_two_column_pile_gets_blocks_over_48_5_mm_against_the_walls(s):
    """A hypothesis over 48.5 mm adds to the two-column pile the robot built (at a belief
    of 45 mm) against the walls, in the lower column: the pile there is, inside the tray."""
    sizes = np.full(N, s)
    for k, side in enumerate([-1, 1, -1, 1]):
        pile = stacked_by_y(np.full(N, 0.045), k)
        key = sm.action_pose(SPEC, sizes, pile, f"stack(r,b{k + 1},c)")
        local = rotate_z(key[:2] - np.asarray(C), -CYAW)
        expected = [side * (SPEC.inner_half[0] - s / 2), 0.0] if k else [0.0, 0.0]  # empty: the rule
        np.testing.assert_allclose(local, expected, atol=1e-15)


# -- re-grounding and Y^-1 -----------------------------------------------------------------
@pytest.mark.parametrize("h", range(len(hypotheses())))
def test_place_for_sizes_keeps_a_pile_y_built(h):
    sizes = hypotheses()[h]
    for k in (1, 3, N):
        config = stacked_by_y(sizes, k)
        placed = sm.place_for_sizes(SPEC, config, sizes)
        np.testing.assert_allclose(placed.objects[1:k + 1], config.objects[1:k + 1], atol=1e-12)


# (seen, hypothesis, columns the hypothesis re-grounds the pile in): the pile's own layout,
# where the hypothesis' blocks can lie that way; two columns of 55 mm blocks cannot. (Seen
# at 0.049 Y piles one column, which a 35 mm hypothesis keeps.)
@pytest.mark.parametrize("seen, hypothesis, two", [(0.045, 0.049, True), (0.045, 0.0495, True),
                                                   (0.055, 0.045, False), (0.058, 0.032, False),
                                                   (0.045, 0.055, False), (0.049, 0.035, False)])
def test_place_for_sizes_keeps_the_piles_layout(seen, hypothesis, two):
    observed = stacked_by_y(np.full(N, seen), 5)
    sizes = np.full(N, hypothesis)
    assert columns.tray_layout(SPEC, observed, sizes, list(range(5))) is two
    placed = sm.place_for_sizes(SPEC, observed, sizes)
    boxes = tray_boxes(placed, sizes, 5)
    ix, iy = SPEC.inner_half
    assert np.all(np.abs(boxes[:, :, :2]) <= [ix + 1e-12, iy + 1e-12])
    assert sm.symbolic_state(SPEC, placed) == sm.symbolic_state(SPEC, observed)
    tops = sorted(boxes[:, 1, 2])
    if two:                                             # three and two high, side by side
        assert tops[-1] == pytest.approx(SPEC.floor_top + 3 * hypothesis)
        centres = (boxes[:, 0, 0] + boxes[:, 1, 0]) / 2
        assert (centres < -hypothesis / 2 + 1e-12).sum() == 3 and (centres > hypothesis / 2 - 1e-12).sum() == 2
    else:                                               # one column: five blocks high
        assert tops[-1] == pytest.approx(SPEC.floor_top + 5 * hypothesis)


def test_y_adds_to_the_pile_there_is_under_every_hypothesis():
    """The next block goes onto the pile the tray has: a one-column pile of 52 mm blocks
    gets the block on its top under a 45 mm hypothesis too (not beside it, into the other
    blocks), and a two-column pile of 45 mm blocks gets it in its lower column under a
    49.5 mm hypothesis (not on a tower the pile is not). The vectorised Y agrees."""
    one = stacked_by_y(np.full(N, 0.052), 3)
    two = stacked_by_y(np.full(N, 0.045), 3)
    rows = np.array([np.full(N, 0.045), np.full(N, 0.0495), np.full(N, 0.052)])
    for config, centre in ((one, True), (two, False)):
        batch = sm.action_poses(SPEC, rows, config, "stack(r,b4,c)")
        for r, sizes in enumerate(rows):
            key = sm.action_pose(SPEC, sizes, config, "stack(r,b4,c)")
            np.testing.assert_array_equal(batch[r], key)
            local = rotate_z(key[:2] - np.asarray(C), -CYAW)
            s = sizes[0]
            if centre:
                np.testing.assert_allclose(local, 0.0, atol=1e-15)
                below = SPEC.floor_top + 3 * s
            elif s <= SIDE_BY_SIDE_MAX:                 # the right column, one block high
                assert local[0] > s / 2 - 1e-12
                below = SPEC.floor_top + s
            else:                                       # 52 mm cannot lie side by side
                np.testing.assert_allclose(local, 0.0, atol=1e-15)
                below = SPEC.floor_top + 3 * s
            assert key[2] == pytest.approx(below + SPEC.release_clearance + s - grip_depth(SPEC, s))


def test_y_inverse_reads_a_one_column_pile_of_large_blocks_as_loaded():
    sizes = np.full(N, SPEC.prior_high)
    config = stacked_by_y(sizes, N)                     # 8 x 60 mm: 0.48 m high
    assert config.objects[N, 2] > SPEC.prior_high * N / 2 + 0.05   # above a two-column cap
    assert sm.symbolic_state(SPEC, config) >= {f"at_container(b{i + 1},c)" for i in range(N)}
    # A block well above the tallest pile is still not in the container.
    objects = config.objects.copy()
    objects[N, 2] = SPEC.floor_top + columns.tallest_pile(SPEC) + 0.05
    assert "at_container(b8,c)" not in sm.symbolic_state(SPEC, Configuration(config.robot, objects))


# -- physics -------------------------------------------------------------------------------
def test_two_large_blocks_stack_into_one_column_in_pybullet():
    s = 0.056                                           # above 48.5 mm: one column
    domain = load("container")
    truth = {"block_sizes": np.full(N, s)}
    with GroundedWorld(domain) as world:
        config = world.reset(domain.initial_configuration(truth), truth)
        for b in ("b1", "b2"):
            out = act(world, domain, config, truth, f"pickup(r,{b},init)")
            assert f"is_holding(r,{b})" in out.state
            out = act(world, domain, out.configuration, truth, f"stack(r,{b},c)")
            config = out.configuration
    assert {"at_container(b1,c)", "at_container(b2,c)", "hand_empty(r)"} <= out.state
    c, b1, b2 = config.objects[:3]
    # b2 rests on b1, both near the tray's centre line, upright and inside the walls.
    assert abs(b1[0] - c[0]) < 0.005 and abs(b2[0] - c[0]) < 0.005
    assert b1[2] == pytest.approx(SPEC.floor_top + s / 2, abs=0.002)
    assert b2[2] == pytest.approx(SPEC.floor_top + 3 * s / 2, abs=0.002)


def test_a_world_over_48_5_mm_replays_the_robots_two_column_pile_as_reality_does():
    """Reality's blocks are 49.3 mm; the robot believes 48 mm and piles four in two columns.
    The truth's own world re-grounds that pile in two columns (each block against its wall)
    and its push carries them to goal, as reality's does; under the one-column rule it was
    a tower of offset blocks that the push toppled, so the belief left the truth (issue 40).
    A 52 mm world cannot hold two columns: it still predicts the failure."""
    s, k = 0.0493, 4
    domain = load("container")
    truth, belief = {"block_sizes": np.full(N, s)}, {"block_sizes": np.full(N, 0.048)}
    with GroundedWorld(domain) as world:
        config = world.reset(domain.initial_configuration(truth), truth)
        for i in range(k):
            out = act(world, domain, config, belief, f"pickup(r,b{i + 1},init)")
            out = act(world, domain, out.configuration, belief, f"stack(r,b{i + 1},c)")
            config = out.configuration
        assert {f"at_container(b{i + 1},c)" for i in range(k)} <= out.state
        real = act(world, domain, config, belief, "push(r,c,init,goal)")
    delivered = {f"is_in(b{i + 1},goal)" for i in range(k)}
    assert delivered <= real.state
    for hypothesis, travels in ((s, True), (0.052, False)):
        sizes = np.full(N, hypothesis)
        with GroundedWorld(domain) as world:
            placed = world.reset(config, {"block_sizes": sizes})
            tops = placed.objects[1:k + 1, 2] + hypothesis / 2
            assert tops.max() == pytest.approx(SPEC.floor_top + (2 if travels else k) * hypothesis)
            out = act(world, domain, placed, belief, "push(r,c,init,goal)")
        assert (delivered <= out.state) is travels


def test_a_counterfactual_push_loads_the_pile_the_belief_builds():
    """The push probe loads the tray as Y at the believed size piles it (the pile the robot
    would push), in the true blocks: 49.3 mm blocks under a 48 mm belief in two columns
    against the walls, under their own size (T*'s probes) in one; 40 mm blocks under a
    52 mm belief in one."""
    domain = load("container")
    from sim_workers.container.probes import loaded_configuration

    def centres(true, believed):
        sizes = np.full(N, true)
        config = loaded_configuration(domain, sizes, 4, np.random.default_rng(0),
                                      None if believed is None else np.full(N, believed))
        c = config.objects[0, :2]
        return config.objects[1:5, 0] - c[0], config.objects[1:5, 2]

    x, z = centres(0.0493, 0.048)         # side by side, within 0.7 mm of the walls (jitter)
    assert np.all(np.abs(x) >= 0.0493 / 2 - 1e-12) and np.all(np.abs(x) <= SPEC.inner_half[0] - 0.0493 / 2 + 1e-12)
    assert x[0] * x[1] < 0 and x[2] * x[3] < 0
    assert z.max() == pytest.approx(SPEC.floor_top + 1.5 * 0.0493)
    for true, believed in ((0.0493, None), (0.040, 0.052)):
        x, z = centres(true, believed)
        assert np.all(np.abs(x) < true / 4)
        assert z.max() == pytest.approx(SPEC.floor_top + 3.5 * true)
