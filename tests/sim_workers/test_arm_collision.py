"""Issue 41: the UR5e's links as capsules, checked as sphere chains against the believed
scene's boxes and the table."""
from __future__ import annotations

import numpy as np

from sim_workers.robots import robot
from sim_workers.robots.collision import Capsule, first_contact, link_spheres, links_checker, sphere_chain

ARM = robot("ur5e").placed((0.3, 0.4, 0.0, -np.pi / 2))


def test_a_sphere_chain_covers_its_capsule():
    cap = Capsule("c", 0, (0.0, 0.0, 0.0), (0.3, 0.1, -0.2), 0.04)
    centres, r = sphere_chain(cap)
    rng = np.random.default_rng(0)
    a, b = np.array(cap.a), np.array(cap.b)
    for _ in range(2000):
        axis = a + rng.uniform() * (b - a)
        d = rng.normal(size=3)
        p = axis + d / np.linalg.norm(d) * cap.radius * rng.uniform() ** (1 / 3)    # inside the capsule
        assert np.linalg.norm(centres - p, axis=1).min() <= r + 1e-12
    assert r <= 1.04 * cap.radius                              # and the chain is barely wider


def test_home_is_clear_and_a_box_on_the_forearm_or_the_table_is_found():
    q = ARM.home
    assert links_checker(ARM, [])(q)
    p, _ = link_spheres(ARM, q)
    # a box around the forearm's middle: the links meet it, and say which
    names = [c.name for c in ARM.links]
    assert "forearm" in names
    from sim_workers.robots.collision import _Chains
    ch = _Chains(ARM.links)
    mid = p[[i for i, n in enumerate(ch.names) if n == "forearm"]].mean(axis=0)
    box = [(mid, np.full(3, 0.01))]
    assert not links_checker(ARM, box)(q)
    assert first_contact(ARM, box, q) == "the forearm meets obstacle 0"
    far = [(mid + np.array([0.0, 0.0, 0.5]), np.full(3, 0.01))]
    assert links_checker(ARM, far)(q) and first_contact(ARM, far, q) is None
    # the shoulder lifted down past the horizontal puts the upper arm through the table
    low = q.copy()
    low[1] = 0.6
    assert first_contact(ARM, [], low) is not None and "table" in first_contact(ARM, [], low)
    assert not links_checker(ARM, [])(low)
    # joints outside the limits are never valid
    out = q.copy()
    out[2] = 3.5
    assert not links_checker(ARM, [])(out)


def test_a_turned_box_is_checked_in_its_own_frame():
    q = ARM.home
    p, r = link_spheres(ARM, q)
    assert np.allclose(p[-1], ARM.tool(q)[:3, 3] + [0.0, 0.0, 0.15])     # the flange, above the tool
    c = p[-1] - np.array([0.0, 0.0, r[-1] + 0.02])           # 2 cm below the flange's sphere
    flat = [(c, np.array([0.1, 0.1, 0.005]))]
    assert links_checker(ARM, flat)(q)
    turned = [(c, np.array([0.1, 0.1, 0.005]), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]))]
    assert not links_checker(ARM, turned)(q)                  # stood on its edge, it reaches up 10 cm
