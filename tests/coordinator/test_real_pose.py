"""The real pose of a TMOC session: the belief's mode averaged over one pose class."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.particle_filter.belief import Belief
from coordinator.loop.reality import Observation
from coordinator.run_config import RunConfig
from coordinator.loop.session import Session
from sim_workers.configuration import Configuration

# Two hypotheses under 48.5 mm (two columns) and two above (one column), close enough in L
# for one mode (bandwidth 3 mm); the one-column side carries more weight.
SIZES = np.array([[0.047], [0.048], [0.050], [0.051]])
WEIGHTS = np.array([0.1, 0.2, 0.3, 0.4])


def _session() -> tuple[Session, Configuration]:
    s = Session(RunConfig(agent="tmoc", particles=4, episodes=1))
    s.belief = Belief(SIZES.copy(), np.log(WEIGHTS), s.belief.low, s.belief.high)
    config = s.domain.initial_configuration({"block_sizes": np.full(s.n_blocks, 0.049)})
    s.start_episode(Observation(config, s.domain.symbolic_state(config), s.domain.measurements(config)))
    return s, config


def test_a_stack_straddling_the_layout_switch_uses_one_layout():
    s, config = _session()
    real, poses = s._real_pose(config, "stack(r,b1,c)")
    one_column = s.domain.pose_classes(SIZES, config, "stack(r,b1,c)") == 0
    assert one_column.tolist() == [False, False, True, True]
    # The tray's centre line (one column), heights averaged over the one-column side only.
    w = WEIGHTS[one_column] / WEIGHTS[one_column].sum()
    np.testing.assert_allclose(real[:3], w @ poses[one_column, :3], rtol=0, atol=1e-12)
    assert real[0] == pytest.approx(config.objects[0, 0], abs=1e-12)
    # The mean over all four would have put the block between the columns.
    assert abs(WEIGHTS @ poses[:, 0] - config.objects[0, 0]) > 0.005


def test_a_pickup_averages_the_whole_mode():
    s, config = _session()
    real, poses = s._real_pose(config, "pickup(r,b1,init)")
    np.testing.assert_allclose(real[[0, 1, 2, 4]], (WEIGHTS @ poses)[[0, 1, 2, 4]], rtol=0, atol=1e-12)


def test_a_pose_the_arm_cannot_reach_is_not_offered():
    """Issue 41: with an arm, a candidate pose no branch of the UR5e's inverse reaches is
    predicted to fail in every world (and costs no simulation), so it never beats one the
    arm reaches, even where the worlds would say it succeeds everywhere."""
    from coordinator.loop.real_pose import arm_reaches, choose_pose, reach_gated

    s = Session(RunConfig(agent="tmoc", particles=4, episodes=1, robot="ur5e"))
    config = s.domain.initial_configuration({"block_sizes": np.full(s.n_blocks, 0.045)})
    s.start_episode(Observation(config, s.domain.symbolic_state(config), s.domain.measurements(config)))
    action = "pickup(r,b1,init)"
    near = s.domain.action_pose({"block_sizes": np.full(s.n_blocks, 0.045)}, config, action)
    far = near.copy()
    far[0] += 2.0                                   # 2 m on: beyond the UR5e's 0.85 m reach
    reaches = arm_reaches(s, config, action)
    assert reaches(near) and not reaches(far)
    simulated = []

    def success(x, rows=None):                      # the worlds' verdict: the far pose is perfect
        simulated.append(x)
        return np.full(4, 1.0 if x[0] > near[0] + 1.0 else 0.5)

    w = np.full(4, 0.25)
    assert choose_pose([far, near], success, w)[0] == far[0]                 # without the gate
    simulated.clear()
    assert choose_pose([far, near], reach_gated(success, reaches, 4), w)[0] == near[0]
    assert len(simulated) == 1 and simulated[0][0] == near[0]               # the far one was not run
    # the floating gripper reaches everywhere: no gate
    g = Session(RunConfig(agent="tmoc", particles=4, episodes=1))
    assert arm_reaches(g, config, action) is None and reach_gated(success, None, 4) is success
