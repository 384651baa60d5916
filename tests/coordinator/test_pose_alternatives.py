"""Y's alternatives judged by the particle worlds (issue 40's "Y's alternatives", issue 37's
large-end pickups): a cube's other grasp is offered when a neighbour is within the open
fingers' reach, simulated only when Y's pose may fail, and taken only when the worlds
predict it succeeds for more of the belief. Real pybullet worlds, no Ray."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.distributed.fanout import ShardPool
from coordinator.loop.real_pose import choose_pose
from coordinator.run_config import PRE_ISSUE_37_FILTER, RunConfig, stored_run_config
from sim_workers.blocks.hand import quarter_turn
from sim_workers.configuration import Configuration
from sim_workers.domains import load


def _counting(scores: dict[float, np.ndarray]):
    calls: list[float] = []

    def success(x: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        calls.append(float(x[3]))
        out = scores[float(x[3])]
        return out if rows is None else out[rows]
    return success, calls


def test_alternatives_are_simulated_only_while_the_pose_may_fail():
    w = np.full(4, 0.25)
    pose, alt = np.array([0.0, 0.0, 0.03, 0.1, 0.06]), np.array([0.0, 0.0, 0.03, 0.1 - np.pi / 2, 0.06])
    offered = lambda x: [alt]                                       # noqa: E731
    # Y's pose succeeds in every world: nothing can beat it, the alternative is not run.
    success, calls = _counting({0.1: np.ones(4), float(alt[3]): np.ones(4)})
    assert choose_pose([pose], success, w, offered) is pose and calls == [0.1]
    # It fails in some: the alternative is judged and taken when strictly better ...
    success, calls = _counting({0.1: np.array([1.0, 0.0, 0.0, 1.0]), float(alt[3]): np.ones(4)})
    assert choose_pose([pose], success, w, offered) is alt and len(calls) == 3
    # ... and not when only as good (the first of equals stays Y's) ...
    success, _ = _counting({0.1: np.array([1.0, 0.0, 0.0, 1.0]), float(alt[3]): np.array([0.0, 1.0, 1.0, 0.0])})
    assert choose_pose([pose], success, w, offered) is pose
    # ... and where it gains nothing in the worlds Y's pose may fail in, the rest is not run.
    success, calls = _counting({0.1: np.array([1.0, 0.0, 0.0, 1.0]), float(alt[3]): np.array([1.0, 0.0, 0.0, 1.0])})
    assert choose_pose([pose], success, w, offered) is pose and len(calls) == 2
    # Without alternatives one candidate is never simulated (the rule before).
    success, calls = _counting({0.1: np.zeros(4)})
    assert choose_pose([pose], success, w) is pose and calls == []


@pytest.mark.parametrize("domain", ["container", "stack_and_push"])
def test_the_other_grasp_is_offered_only_within_the_fingers_reach(domain):
    d = load(domain, n_blocks=8)
    config = d.initial_configuration({"block_sizes": np.full(8, 0.045)})
    action = "pickup(r,b2,init)"
    pitch = np.linalg.norm(np.diff(config.objects[-8:, :2], axis=0), axis=1).min()
    for size in (0.0579, 0.045, 0.034):
        pose = d.action_pose({"block_sizes": np.full(8, size)}, config, action)
        alts = d.pose_alternatives(config, action, pose, np.full((4, 1), size))
        # Within reach: the open fingers' outer faces plus a neighbour's half diagonal.
        reach = 0.5 * pose[4] + 2 * d.spec.finger_half[1] + np.sqrt(0.5) * size
        assert len(alts) == int(reach > pitch), (size, reach, pitch)
        for alt in alts:
            assert np.array_equal(np.delete(alt, 3), np.delete(pose, 3))
            assert abs(abs(alt[3] - pose[3]) - np.pi / 2) < 1e-12 and abs(alt[3]) <= np.pi / 2
        assert d.pose_alternatives(config, "push(r,c,init,goal)" if domain == "container" else action.replace(
            "pickup", "stack").replace("init", "start"), pose, np.full((4, 1), size)) == []
    assert quarter_turn(-0.2) == pytest.approx(np.pi / 2 - 0.2) and quarter_turn(0.3) == pytest.approx(0.3 - np.pi / 2)


def test_a_grasp_whose_finger_meets_the_neighbour_turns_a_quarter():
    """A 57.9 mm block with its neighbour 60 mm away along the closing axis (2 mm of table
    between them, as a block knocked from its slot lies): Y's grasp puts a finger on the
    neighbour and fails in some worlds of that size (measured: 2 of 4, not in order of
    size), the quarter-turned grasp closes across free table and holds in all of them, and
    the worlds' judgement takes it; in the world of the truth it holds the block."""
    d = load("container", n_blocks=8)
    size = 0.0579
    config = d.initial_configuration({"block_sizes": np.full(8, size)})
    objects = config.objects.copy()
    axis = np.array([0.0, 1.0])                      # Y's closing axis at yaw 0
    objects[2, :2] = objects[1, :2] + 0.060 * axis   # b2 beside b1 along it
    config = Configuration(config.robot, objects)
    action = "pickup(r,b1,init)"
    rows = np.array([[0.0565], [0.0572], [size], [0.0586]])
    pose = d.action_pose({"block_sizes": np.full(8, size)}, config, action)
    alts = d.pose_alternatives(config, action, pose, rows)
    assert len(alts) == 1
    pool = ShardPool("container", {"n_blocks": 8}, n_shards=0)

    def held(x: np.ndarray, sizes: np.ndarray, subset: np.ndarray | None = None) -> np.ndarray:
        sizes = sizes if subset is None else sizes[subset]
        traj = d.action_trajectory(config, action, x)
        res = pool.simulate(config.to_array(), np.ascontiguousarray(sizes), action, traj,
                            d.transit_end_time(config, action, x))
        return np.array(["is_holding(r,b1)" in s for s in res["states"]], dtype=np.float64)

    y_pose, turned = held(pose, rows), held(alts[0], rows)
    assert y_pose.sum() < len(rows) and turned.sum() == len(rows), (y_pose, turned)
    w = np.full(len(rows), 1 / len(rows))
    chosen = choose_pose([pose], lambda x, sub=None: held(x, rows, sub), w, lambda x: d.pose_alternatives(config, action, x, rows))
    assert np.array_equal(chosen, alts[0])
    assert held(chosen, np.array([[size]]))[0] == 1.0


def test_stored_configs_keep_y_alone():
    assert RunConfig().pose_alternatives is True
    assert stored_run_config({}).pose_alternatives is False
    assert PRE_ISSUE_37_FILTER["pose_alternatives"] is False
