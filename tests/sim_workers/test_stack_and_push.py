"""The stack-and-push domain's physics half: Y^-1 and Y on hand-built configurations (no
physics), then the probe's physics claims (seeded trials in grounded worlds).

The physics claims are the domain's calibration at true size 0.040 m, 16 trials, seed 0
(one child generator per trial, so the figures are exact and repeatable): a right-sized
pickup and a stack onto four work, a 25 % wrong belief breaks the grasp, a short tower
pushes, a tall one falls (with a graded height in between) and a tower of eight left
alone stands. One claim goes through the installed ``tmoc probe`` console script, as a
user runs it; the rest call ``sim_workers.probe.probe`` (the same code, in-process).
"""
from __future__ import annotations

import functools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sim_workers.blocks.hand import grip_depth
from sim_workers.configuration import Configuration, quat_from_yaw
from sim_workers.domains import load
from sim_workers.probe import probe, probe_loads
from sim_workers.stack_and_push import state_mapping as sm
from sim_workers.stack_and_push.probes import tower_atoms, tower_configuration
from sim_workers.stack_and_push.spec import StackAndPushSpec

SPEC = StackAndPushSpec()
N = SPEC.n_blocks
S = 0.040
UPRIGHT = [0.0, 0.0, 0.0, 1.0]
PUSH = "push(r,tower,start,goal)"


def base(s: float = S) -> Configuration:
    return sm.initial_configuration(SPEC, np.full(N, s))


def quat_about_x(angle: float) -> np.ndarray:
    return np.array([np.sin(angle / 2), 0.0, 0.0, np.cos(angle / 2)])


def tower(k: int, x: float = SPEC.start_x, s: float = S, offsets=None, yaws=None,
          config: Configuration | None = None) -> Configuration:
    """b1..bk stacked upright at (x, 0) (each shifted by offsets[i] in the plane and turned
    by yaws[i]), everything else as in `config` (default: the initial configuration)."""
    config = base(s) if config is None else config
    objects = config.objects.copy()
    for i in range(k):
        dx, dy = (0.0, 0.0) if offsets is None else offsets[i]
        objects[i] = [x + dx, dy, (i + 0.5) * s, *quat_from_yaw(0.0 if yaws is None else yaws[i])]
    return Configuration(config.robot, objects)


def atoms(tower_k: int = 0, **where) -> frozenset[str]:
    """b1..b{tower_k} in the `on` chain from the start site, the rest at init unless told,
    hand empty."""
    out = set(tower_atoms(tower_k)) | {"hand_empty(r)"}
    for i in range(tower_k + 1, N + 1):
        out.add(f"is_in(b{i},{where.get(f'b{i}', 'init')})")
    return frozenset(out)


# -- Y^-1 ------------------------------------------------------------------------------------
def test_initial_configuration_every_block_at_init_hand_empty_no_tower():
    state = sm.symbolic_state(SPEC, base())
    assert state == frozenset({"hand_empty(r)", *(f"is_in(b{i},init)" for i in range(1, N + 1))})
    assert not any(a.startswith("on(") for a in state)
    # The domain object reads the same, and it does not depend on the sizes it was laid out for.
    domain = load("stack_and_push")
    assert domain.symbolic_state(domain.initial_configuration({"block_sizes": np.full(N, 0.055)})) == state


def test_tower_of_three_on_the_start_site_is_an_on_chain():
    state = sm.symbolic_state(SPEC, tower(3))
    assert {"on(b1,start)", "on(b2,b1)", "on(b3,b2)"} <= state
    assert state == atoms(3)
    assert not any(a.startswith(("is_in(b1,", "is_in(b2,", "is_in(b3,")) for a in state)


def test_crooked_tower_keeps_its_order_by_height_not_by_name():
    # Built b3 at the bottom, then b1, then b2; a few mm off each other and turned a little.
    objects = base().objects.copy()
    for level, (i, dx, yaw) in enumerate([(2, 0.003, 0.05), (0, -0.004, -0.04), (1, 0.002, 0.1)]):
        objects[i] = [dx, 0.002 * level, (level + 0.5) * S, *quat_from_yaw(yaw)]
    state = sm.symbolic_state(SPEC, Configuration(base().robot, objects))
    assert {"on(b3,start)", "on(b1,b3)", "on(b2,b1)"} <= state
    assert not any(a.startswith("on(") and a not in ("on(b3,start)", "on(b1,b3)", "on(b2,b1)")
                   for a in state)


@pytest.mark.parametrize("x, tower_k", [(SPEC.start_x, 0), (0.25, 2)], ids=["on-the-start-site", "beside-a-tower"])
def test_block_toppled_in_the_rail_is_in_rail_not_in_the_tower(x, tower_k):
    """A cube turned 45 degrees about x (resting on an edge, no face up) lying in the rail."""
    k = tower_k + 1                                       # the toppled block
    config = tower(tower_k)
    objects = config.objects.copy()
    objects[k - 1] = [x, 0.003, S / np.sqrt(2), *quat_about_x(np.pi / 4)]
    config = Configuration(config.robot, objects)
    assert not sm.upright(objects[k - 1, 3:])
    state = sm.symbolic_state(SPEC, config)
    assert f"is_in(b{k},rail)" in state
    assert not any(a.startswith(f"on(b{k},") or a.endswith(f",b{k})") for a in state)
    assert state == atoms(tower_k, **{f"b{k}": "rail"})
    # Upright at the same spot it would be the tower's base (or, beside it, still in the rail).
    objects[k - 1] = [x, 0.003, S / 2, *UPRIGHT]
    upright_state = sm.symbolic_state(SPEC, Configuration(config.robot, objects))
    assert (f"on(b{k},start)" in upright_state) == (tower_k == 0)


def _across_the_site(s: float = 0.060) -> Configuration:
    """b5 and b6 lying upright in the rail 33 mm ahead of and 45 mm behind the start site
    (where a failed push of eight 60 mm blocks left them), b3 waiting in the rail behind,
    the rest in their slots: no block is centred on the site, yet a 60 mm block released
    there overlaps both."""
    objects = base(s).objects.copy()
    for i, x in ((4, 0.033), (5, -0.045), (2, 0.18)):
        objects[i] = [x, 0.002, s / 2, *UPRIGHT]
    return Configuration(base(s).robot, objects)


def test_a_floor_block_a_stack_at_the_site_would_land_on_is_the_towers_base():
    config = _across_the_site()
    state = sm.symbolic_state(SPEC, config)
    assert "on(b5,start)" in state and "is_in(b6,rail)" in state and "is_in(b3,rail)" in state
    # Nearest the site, not lowest: b6 read 5 mm lower (perception) is still not the base.
    objects = config.objects.copy()
    objects[5, 2] -= 0.005
    assert "on(b5,start)" in sm.symbolic_state(SPEC, Configuration(config.robot, objects))
    # Y releases the next block over it, a block's height up: clear of b6 beside it.
    pose = sm.action_pose(SPEC, np.full(N, 0.060), config, "stack(r,b3,tower)")
    assert pose[0] == pytest.approx(0.033) and pose[2] > 0.060
    # Beyond every block of the prior the site is free again.
    objects[4, 0] = SPEC.start_x + SPEC.prior_high + 0.005
    objects[5, 0] = SPEC.start_x - SPEC.prior_high - 0.005
    far = sm.symbolic_state(SPEC, Configuration(config.robot, objects))
    assert not any(a.startswith("on(") for a in far) and "is_in(b5,rail)" in far


def test_the_tower_standing_in_the_window_is_the_tower_though_a_lone_block_is_nearer():
    """After a topple: b6, b3, b4 stand 35 mm behind the site, b5 lies alone 31 mm ahead."""
    s = 0.050
    objects = base(s).objects.copy()
    for i, (x, level) in {5: (-0.035, 0), 2: (-0.036, 1), 3: (-0.034, 2), 4: (0.031, 0)}.items():
        objects[i] = [x, 0.001, (level + 0.5) * s, *UPRIGHT]
    state = sm.symbolic_state(SPEC, Configuration(base(s).robot, objects))
    assert {"on(b6,start)", "on(b3,b6)", "on(b4,b3)", "is_in(b5,rail)"} <= state, sorted(state)


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_a_stack_beside_blocks_lying_across_the_site_lands_on_the_nearer(engine):
    """The failure loop this rule ended: before it, the stack was released at the site,
    landed across b5 and b6, failed, and was picked up and tried again until max_steps."""
    from sim_workers.grounded_world import GroundedWorld
    domain = load("stack_and_push", engine=engine)
    props = domain.properties({"block_sizes": np.full(N, 0.060)})
    config = _across_the_site()
    with GroundedWorld(domain) as world:
        for action in ("pickup(r,b3,rail)", "stack(r,b3,tower)"):
            world.reset(config, props)
            key = domain.action_pose(props, config, action)
            out = world.execute(domain.action_trajectory(config, action, key), action)
            config = out.configuration
        assert {"on(b5,start)", "on(b3,b5)"} <= out.state, sorted(out.state)


def test_block_on_its_side_is_upright_again_and_held_block_is_not_in_the_tower():
    # A cube that rolled a quarter turn rests on another face: still a tower block.
    config = tower(2)
    objects = config.objects.copy()
    objects[1, 3:] = quat_about_x(np.pi / 2)
    assert sm.symbolic_state(SPEC, Configuration(config.robot, objects)) == atoms(2)
    # The gripper lifting b3 off the top of a tower of three: held, and the chain stops at b2.
    lifted = tower(3)
    robot = np.array([0.0, 0.0, 2.5 * S + (S / 2 - grip_depth(SPEC, S)), 0.0, S])
    objects = lifted.objects.copy()
    objects[2, 2] += 0.02
    robot[2] += 0.02
    state = sm.symbolic_state(SPEC, Configuration(robot, objects))
    assert state == (atoms(2) - {"is_in(b3,init)", "hand_empty(r)"}) | {"is_holding(r,b3)"}


def test_after_a_push_blocks_in_the_goal_area_are_delivered():
    domain = load("stack_and_push")
    offsets = [(0.002, -0.001), (-0.003, 0.002), (0.001, 0.004)]
    pushed = tower(3, x=SPEC.goal_centre_x, offsets=offsets, yaws=[0.04, -0.03, 0.1])
    objects = pushed.objects.copy()
    objects[3] = [0.30, 0.004, S / 2, *quat_from_yaw(0.2)]            # b4 fell off short of the goal
    objects[4] = [0.60, 0.10, S / 2, *UPRIGHT]                        # b5 off the rail beside the goal
    config = Configuration(pushed.robot, objects)
    # Off the start site the pushed tower is no tower: its blocks lie in the rail.
    assert sm.symbolic_state(SPEC, config) == atoms(
        0, b1="rail", b2="rail", b3="rail", b4="rail", b5="table")
    after = domain.after_action(config, PUSH)
    assert sm.symbolic_state(SPEC, after) == atoms(
        0, b1="goal", b2="goal", b3="goal", b4="rail", b5="table")
    for i in range(3):                                               # set down upright in its slot
        np.testing.assert_allclose(after.objects[i, :2], SPEC.delivered_slot(i))
        assert after.objects[i, 2] == pytest.approx(S / 2)
        np.testing.assert_allclose(after.objects[i, 3:], UPRIGHT)
    np.testing.assert_array_equal(after.objects[3:], config.objects[3:])
    np.testing.assert_array_equal(after.robot, config.robot)
    np.testing.assert_array_equal(config.objects, objects)           # the input is not modified
    # A delivered configuration re-grounds under any hypothesis without changing its atoms.
    placed = domain.place(after, {"block_sizes": np.full(N, 0.055)})
    assert sm.symbolic_state(SPEC, placed) == sm.symbolic_state(SPEC, after)
    assert placed.objects[0, 2] == pytest.approx(0.055 / 2)


def test_after_action_changes_nothing_elsewhere():
    domain = load("stack_and_push")
    at_goal = tower(3, x=SPEC.goal_centre_x)
    assert domain.after_action(at_goal, "stack(r,b4,tower)") is at_goal     # not a push
    assert domain.after_action(at_goal, "pickup(r,b4,init)") is at_goal
    at_start = tower(3)                                                    # a push that did not arrive
    assert domain.after_action(at_start, PUSH) is at_start


# -- Y ---------------------------------------------------------------------------------------
BELIEVED = np.array([0.030, 0.034, 0.038, 0.042, 0.046, 0.050, 0.054, 0.058])


def test_stack_release_height_grows_by_the_believed_sizes_of_the_tower_below():
    offsets = [(0.002 * (i % 3) - 0.002, 0.001 * i) for i in range(N)]
    yaws = [0.03 * (-1) ** i for i in range(N)]
    zs = []
    for k in range(6):
        config = tower(k, offsets=offsets, yaws=yaws)
        assert sm.symbolic_state(SPEC, config) == atoms(k)
        pose = sm.action_pose(SPEC, BELIEVED, config, "stack(r,b8,tower)")
        if k:                       # over the observed tower, faces aligned with its top block
            # Close enough to the top block that the released block reads on(b8, top).
            assert np.linalg.norm(pose[:2] - config.objects[k - 1, :2]) < sm.ON_DXY
            assert pose[3] == pytest.approx(yaws[k - 1])
        else:                       # an empty site: the start site itself
            np.testing.assert_allclose(pose[:2], SPEC.start_xy())
            assert pose[3] == 0.0
        assert pose[2] == pytest.approx(BELIEVED[:k].sum() + SPEC.release_clearance
                                        + BELIEVED[7] - grip_depth(SPEC, BELIEVED[7]))
        assert pose[4] == pytest.approx(min(SPEC.max_opening, sm.RELEASE_RATIO * BELIEVED[7]))  # a turned block frees
        zs.append(pose[2])
    # Delta z over the empty site = the sum of the believed sizes of the tower below.
    np.testing.assert_allclose(np.array(zs) - zs[0], np.cumsum([0.0, *BELIEVED[:5]]))
    assert np.all(np.diff(zs) > 0)


def test_a_stack_lets_go_of_a_block_turned_in_the_fingers():
    """The release opens past the believed block's diagonal (a cube turned in the fingers
    spans up to sqrt(2) sides between them), at every size of the prior, in the scalar and
    the batched Y alike; the grasp's 1.15 sides left a turned 40 mm block wedged."""
    sizes = np.linspace(SPEC.prior_low, SPEC.prior_high, 7)
    config = tower(2)
    rows = np.repeat(sizes[:, None], N, axis=1)
    batched = sm.action_poses(SPEC, rows, config, "stack(r,b8,tower)")
    for s, row in zip(sizes, batched):
        pose = sm.action_pose(SPEC, np.full(N, s), config, "stack(r,b8,tower)")
        assert pose[4] == row[4]
        assert min(np.sqrt(2) * s + 0.002, SPEC.max_opening) <= pose[4] <= SPEC.max_opening, (s, pose[4])


def test_stack_height_depends_only_on_the_tower_and_the_held_block():
    config = tower(4)
    small = sm.action_pose(SPEC, np.full(N, 0.040), config, "stack(r,b8,tower)")
    large = sm.action_pose(SPEC, np.full(N, 0.050), config, "stack(r,b8,tower)")
    # Four blocks below, plus two thirds of the held block (its grip deepens with it).
    assert large[2] - small[2] == pytest.approx(4 * 0.010 + 0.010 * 2 / 3)
    # Blocks neither in the tower nor held (b5..b7, in the supply row) do not move it.
    other = np.full(N, 0.040)
    other[4:7] = 0.060
    np.testing.assert_array_equal(sm.action_pose(SPEC, other, config, "stack(r,b8,tower)"), small)
    # The true sizes of the configuration do not matter either: only where the blocks are.
    assert sm.action_pose(SPEC, np.full(N, 0.040), tower(4, s=0.050), "stack(r,b8,tower)")[2] \
        == pytest.approx(small[2])


@pytest.mark.parametrize("place", ["init", "rail"])
def test_pickup_pose_scales_with_the_believed_size(place):
    config = base()
    objects = config.objects.copy()
    if place == "rail":
        objects[2] = [0.32, -0.004, S / 2, *quat_from_yaw(1.0)]   # folded: 1.0 - pi/2
    else:
        objects[2, :2] += [0.004, -0.003]
        objects[2, 3:] = quat_from_yaw(0.1)
    config = Configuration(config.robot, objects)
    assert f"is_in(b3,{place})" in sm.symbolic_state(SPEC, config)
    poses = []
    for s in (0.030, 0.040, 0.050):
        sizes = np.full(N, 0.045)
        sizes[2] = s                                       # only b3's belief matters
        pose = sm.action_pose(SPEC, sizes, config, f"pickup(r,b3,{place})")
        np.testing.assert_allclose(pose[:2], objects[2, :2])
        assert pose[2] == pytest.approx(s - grip_depth(SPEC, s))
        assert pose[3] == pytest.approx(1.0 - np.pi / 2 if place == "rail" else 0.1)
        # 1.15 sides at least, widened by the grasp clearance where the row leaves room
        assert SPEC.open_ratio * s - 1e-12 <= pose[4] <= s + 2 * SPEC.grasp_clearance + 1e-12
        poses.append(pose)
    poses = np.array(poses)
    np.testing.assert_allclose(np.diff(poses[:, 2]), [0.010 * 2 / 3] * 2)   # tips at 2/3 of the side
    # 1 mm more opening per mm of belief (s + 2c; the 1.15 sides' 1.15 mm without the clearance)
    np.testing.assert_allclose(np.diff(poses[:, 4]), [0.010] * 2)
    np.testing.assert_allclose(np.diff(poses[:, [0, 1, 3]], axis=0), 0.0)


@pytest.mark.parametrize("k", range(N + 1))
def test_push_pose_is_finite_behind_the_tower(k):
    domain = load("stack_and_push")
    rng = np.random.default_rng(k)
    if k:
        config = tower_configuration(domain, np.full(N, S), k, rng)
        assert tower_atoms(k) <= sm.symbolic_state(SPEC, config)
    else:
        config = base()
    for believed in (np.full(N, 0.030), np.full(N, 0.060), BELIEVED):
        pose = sm.action_pose(SPEC, believed, config, PUSH)
        assert pose.shape == (5,) and np.all(np.isfinite(pose))
        assert pose[2] == SPEC.push_tip_z and pose[3] == 0.0 and pose[4] == 0.0
        if k:
            chain = range(k)
            rear = min(config.objects[j, 0] - sm._rear_half(believed[j], config.objects[j, 3:]) for j in chain)
            assert pose[0] == pytest.approx(rear - SPEC.finger_half[0] - SPEC.push_gap)
            assert pose[1] == pytest.approx(config.objects[0, 1])
            # The stroke carries the tower's base to the goal centre.
            end = sm.push_end_x(SPEC, config, PUSH, pose)
            assert end - pose[0] == pytest.approx(SPEC.goal_centre_x - config.objects[0, 0])
        else:
            assert pose[0] < SPEC.start_x and pose[1] == 0.0
        traj = domain.action_trajectory(config, PUSH, pose)
        assert np.all(np.isfinite(traj)) and np.all(np.diff(traj[:, 0]) >= 0)
        assert domain.transit_end_time(config, PUSH, pose) < traj[-1, 0]


def test_tower_configuration_is_the_tower_it_says():
    domain = load("stack_and_push")
    rng = np.random.default_rng(3)
    for k in range(1, N + 1):
        config = tower_configuration(domain, np.full(N, S), k, rng)
        assert sm.symbolic_state(SPEC, config) == atoms(k)
        np.testing.assert_allclose(config.objects[:k, 2], (np.arange(k) + 0.5) * S)


# -- physics: the probe's claims (true size 0.040 m, 16 trials, seed 0) -------------------------
TRUE = 0.040
TRIALS = 16
SEED = 0


@functools.cache
def rate(action: str, load_k: int = 4, believed: float = TRUE) -> float:
    """Success rate of `action` from sim_workers.probe.probe (cached: one run per input)."""
    result = probe(action, TRUE, believed, load_k=load_k, trials=TRIALS, seed=SEED, domain="stack_and_push")
    assert result.trials == TRIALS
    return result.success_rate


def tmoc() -> list[str]:
    """The installed console script `tmoc`, as a user runs it."""
    script = Path(sys.executable).with_name("tmoc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "coordinator.cli"]


def cli_probe(cwd, action: str, load_k: int = 4, believed: float | None = None) -> dict:
    """`tmoc probe --domain stack_and_push ... --json` in a subprocess; its JSON object."""
    argv = tmoc() + ["probe", "--domain", "stack_and_push", "--action", action,
                     "--true-size", str(TRUE), "--load", str(load_k), "--trials", str(TRIALS),
                     "--seed", str(SEED), "--json"]
    if believed is not None:
        argv += ["--believed-size", str(believed)]
    proc = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=300, check=False,
                          env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    assert len(lines) == 1, proc.stdout
    return json.loads(lines[0])


@pytest.mark.slow
@pytest.mark.timeout(360)          # the CLI subprocess may take its 300 s
def test_push_of_two_succeeds_through_the_cli(neutral_cwd):
    data = cli_probe(neutral_cwd, "push", load_k=2)
    assert data["domain"] == "stack_and_push" and data["action"] == "push" and data["load"] == 2
    assert data["trials"] == TRIALS and data["seed"] == SEED and data["true_size"] == TRUE
    assert data["success_rate"] >= 0.85, data
    # The console script and the library are the same seeded trials.
    assert data["success_rate"] == rate("push", 2)


def test_pickup_with_the_right_size_succeeds():
    assert rate("pickup", believed=TRUE) >= 0.9


def test_pickup_with_a_25_percent_wrong_belief_fails_only_without_the_clearance():
    # Too small: at the 1.15 sides of before (grasp_clearance 0) the fingers open to
    # 34.5 mm over a 40 mm block and land on its top; the default 6 mm of clearance opens
    # them to 42 mm, which holds it (the grasp width read then tells the belief).
    tight = probe("pickup", TRUE, 0.030, trials=TRIALS, seed=SEED, domain="stack_and_push",
                  options={"grasp_clearance": 0.0})
    assert tight.success_rate <= 0.5
    assert rate("pickup", believed=0.030) >= 0.9


def test_pickup_with_a_25_percent_large_belief_still_grasps():
    # The grip deepens with the believed size (a third of it): fingertips at 33 mm on a
    # 40 mm block; the grasp width, not a miss, tells the belief it was wrong.
    assert rate("pickup", believed=0.050) >= 0.9


@pytest.mark.slow
def test_stack_onto_a_tower_of_four_succeeds():
    assert rate("stack", 4) >= 0.9


@pytest.mark.slow
def test_a_tall_tower_pushes_worse_than_a_short_one():
    assert rate("push", 8) <= rate("push", 2) - 0.25


@pytest.mark.slow
def test_some_middle_height_is_graded():
    rates = {k: rate("push", k) for k in range(3, 8)}
    assert any(0.2 <= r <= 0.8 for r in rates.values()), rates


@pytest.mark.slow
def test_a_tower_of_eight_left_alone_stands():
    assert rate("stand", 8) == 1.0


@pytest.mark.slow
def test_probe_accepts_every_load_t_star_asks_for():
    """T* (tmoc experiment) probes a stack onto the empty start site (load 0); probe() once
    refused every load outside 1..n, the container's range."""
    domain = load("stack_and_push")
    for action, k in domain.t_star_probe_jobs(N):
        assert k in probe_loads(domain, action), (action, k)
    assert list(probe_loads(domain, "stack")) == list(range(N))
    assert rate("stack", 0) >= 0.9                      # one block onto the start site
    with pytest.raises(ValueError, match=r"load: 8 is outside \[0, 7\]"):
        probe("stack", TRUE, load_k=N, trials=1, domain="stack_and_push")
    with pytest.raises(ValueError, match=r"load: 0 is outside \[1, 8\]"):
        probe("push", TRUE, load_k=0, trials=1, domain="stack_and_push")


# -- vectorised Y: what the coordinator calls once per action for all N particles ------------
def _vector_cases():
    yield {}, 1
    yield {"unknown_density": True}, 2
    yield {"unknown_density": True}, 2 * N          # one value per block per property
    yield {"force_from_mass": True}, N


@pytest.mark.parametrize("options,width", list(_vector_cases()))
def test_action_poses_equal_per_row_action_pose_bit_for_bit(options, width):
    """Every action on scenes with towers of 0, 3 and all N blocks (turned, offset), with a
    size (and density) per particle: the batch is the per-row Y to the bit, efforts included."""
    rng = np.random.default_rng(11)
    domain = load("stack_and_push", **options)
    L = domain.L
    n_props = len(L.names)
    per = width // n_props
    low = np.repeat(np.asarray(L.low), per)
    high = np.repeat(np.asarray(L.high), per)
    rows = rng.uniform(low, high, size=(48, width))
    yaws = rng.uniform(-0.6, 0.6, N)
    offsets = rng.uniform(-0.004, 0.004, (N, 2))
    for k in (0, 3, N):
        config = tower(k, offsets=offsets, yaws=yaws)
        actions = [PUSH] + [f"pickup(r,b{i},init)" for i in range(k + 1, N + 1)][:2] \
            + [f"stack(r,b{i},tower)" for i in range(k + 1, N + 1)][:2]
        for action in actions:
            batch = domain.action_poses(rows, config, action)
            single = np.array([domain.action_pose(domain.props_from_row(r) if n_props > 1 or width > 1
                                                  else {"block_sizes": np.full(N, r[0])}, config, action)
                               for r in rows])
            assert batch.shape == single.shape == (48, 6 if domain.force_from_mass else 5)
            np.testing.assert_array_equal(batch, single, err_msg=f"{action} with {k} stacked")


def test_action_poses_refuses_a_row_out_of_range_by_name():
    domain = load("stack_and_push", unknown_density=True)
    rows = np.tile([0.045, 1000.0], (4, 1))
    rows[2, 1] = 1e6
    with pytest.raises(ValueError, match="density"):
        domain.action_poses(rows, base(), "pickup(r,b1,init)")
    rows[2] = [5.0, 1000.0]
    with pytest.raises(ValueError, match="block_sizes"):
        domain.action_poses(rows, base(), "pickup(r,b1,init)")
    with pytest.raises(ValueError, match="L: rows of 3 values"):
        domain.action_poses(np.zeros((2, 3)), base(), "pickup(r,b1,init)")


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_a_block_left_on_another_is_grasped_at_its_believed_bottom(engine):
    """b3 left lying on b5 in the rail, away from the site (a failed stack's leftover): Y
    grasps it where it is, not at the floor's height, where the fingers only knock it off
    (planned again every time, until the episode's `max_steps`)."""
    from sim_workers.grounded_world import GroundedWorld
    s = 0.050
    objects = base(s).objects.copy()
    objects[4] = [0.20, 0.0, s / 2, *UPRIGHT]
    objects[2] = [0.201, 0.001, 1.5 * s, *UPRIGHT]
    config = Configuration(base(s).robot, objects)
    state = sm.symbolic_state(SPEC, config)
    assert {"is_in(b3,rail)", "is_in(b5,rail)"} <= state and not any(a.startswith("on(") for a in state)
    action = "pickup(r,b3,rail)"
    pose = sm.action_pose(SPEC, np.full(N, s), config, action)
    assert pose[2] == pytest.approx(s + sm.action_pose(SPEC, np.full(N, s), base(s), "pickup(r,b3,init)")[2])
    domain = load("stack_and_push", engine=engine)
    props = domain.properties({"block_sizes": np.full(N, s)})
    with GroundedWorld(domain) as world:
        world.reset(config, props)
        out = world.execute(domain.action_trajectory(config, action, domain.action_pose(props, config, action)), action)
    assert "is_holding(r,b3)" in out.state and "is_in(b5,rail)" in out.state, sorted(out.state)
    # Small blocks too (a 30 mm block's centre on another is 45 mm up, below the height
    # under which a block counts as lying on the floor elsewhere in Y^-1).
    small = objects.copy()
    small[4, 2], small[2, 2] = 0.015, 0.045
    pose30 = sm.action_pose(SPEC, np.full(N, 0.030), Configuration(config.robot, small), action)
    assert pose30[2] == pytest.approx(0.030 + 0.030 - grip_depth(SPEC, 0.030))
    # ... and the worlds keep it there (re-grounded onto the floor it would sit inside b5).
    placed = sm.place_for_sizes(SPEC, Configuration(config.robot, small), np.full(N, 0.030))
    np.testing.assert_array_equal(placed.objects[2, :3], small[2, :3])
    # Two blocks side by side on the floor, 60 and 30 mm (centres 15 mm apart in height,
    # and 2 mm of perception noise): neither lies on the other.
    side = objects.copy()
    side[4], side[2] = [0.20, 0.0, 0.030, *UPRIGHT], [0.245, 0.0, 0.017, *UPRIGHT]
    assert not sm.rests_on_a_block(SPEC, side, 4) and not sm.rests_on_a_block(SPEC, side, 2)
    # A block seen in the air with nothing under it (caught on the outside of the fingers)
    # is grasped at the floor's height: a grasp aimed where it is seen only carries it along.
    objects[4] = [0.40, 0.0, s / 2, *UPRIGHT]
    caught = Configuration(config.robot, objects)
    assert not sm.rests_on_a_block(SPEC, objects, 2)
    np.testing.assert_array_equal(sm.action_pose(SPEC, np.full(N, s), caught, action)[2],
                                  sm.action_pose(SPEC, np.full(N, s), base(s), "pickup(r,b3,init)")[2])
