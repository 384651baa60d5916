"""The session's transit to the pre-pose: collision-free among the observed obstacles."""
from __future__ import annotations

import numpy as np

from coordinator.reality import Observation
from coordinator.run_config import RunConfig
from coordinator.session import Session
from planner.motion import box_checker, interpolate_config
from sim_workers.configuration import Configuration
from sim_workers.probe import loaded_configuration


def _session_at(config: Configuration) -> Session:
    s = Session(RunConfig(agent="tmp_rl", particles=1, episodes=1))
    s.start_episode(Observation(config, s.domain.symbolic_state(config), s.domain.measurements(config)))
    return s


def _dense_ok(session: Session, config: Configuration, path: np.ndarray) -> bool:
    size = float(np.max(session.believed_sizes()))
    half, dz = session.domain.gripper_box(0.0)
    boxes = box_checker(session.domain.obstacles(config, size), gripper_half_extents=half)
    for a, b in zip(path[:-1], path[1:]):
        for t in np.linspace(0, 1, 50):
            q = interpolate_config(a, b, t) + np.array([0, 0, dz, 0])
            if not boxes(q):
                return False
    return True


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
    assert record["transit_fallback_notes"][0].endswith("(tried straight, up_across_down, rrtstar)")
