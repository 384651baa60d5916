"""Determinism: a particle-action's result depends on (configuration, sizes, trajectory) only.

Not on the world's past, the process, the number of worlds in a shard, how a batch is split
or which Ray actor runs it. Comparisons are bit-for-bit (``tobytes``), not approximate. In
both engines (issue 27): pybullet rebuilds its world per reset, MuJoCo resets its data (on
models cached per hypothesis, so a world with a past has them compiled already).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pybullet as pb
import pytest

from sim_workers.domains import load
from sim_workers.grounded_world import GroundedWorld
from sim_workers.engines.pybullet_world import PybulletWorld
from sim_workers.container.probes import loaded_configuration
from sim_workers.shard import Shard, decode_state, remote_shard

N = 8
from sim_workers.engines import ENGINES  # noqa: E402  (the registry's one list)


def _case(action: str):
    """(start configuration, trajectory, start_time) of one action, poses from Y at 0.045."""
    domain = load("container")
    truth = domain.true_properties()
    sizes = truth["block_sizes"]
    if action.startswith("push"):
        config = loaded_configuration(domain, sizes, 6, np.random.default_rng(3))
    else:
        config = domain.initial_configuration(truth)
    key = domain.action_pose(truth, config, action)
    traj = domain.action_trajectory(config, action, key)
    return config, traj, float(traj[3, 0])


PICKUP = "pickup(r,b3,init)"
PUSH = "push(r,c,init,goal)"
SIZES = np.array([[0.045] * N, [0.041] * N, np.linspace(0.032, 0.058, N), [0.050] * N,
                  [0.0455] * N, np.linspace(0.058, 0.032, N)])


def _run(world: GroundedWorld, action: str, sizes) -> np.ndarray:
    config, traj, t0 = _case(action)
    world.reset(config, {"block_sizes": sizes})
    return world.execute(traj, action, start_time=t0).configuration.to_array()


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype=np.float64).tobytes()


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("action", [PICKUP, PUSH])
def test_two_fresh_worlds_give_identical_bits(action, engine):
    domain = load("container", engine=engine)
    with GroundedWorld(domain) as a, GroundedWorld(domain) as b:
        ra, rb = _run(a, action, SIZES[2]), _run(b, action, SIZES[2])
    assert _bits(ra) == _bits(rb)
    # ... and the result is not trivially the start: the physics did something.
    start = _case(action)[0].to_array()
    assert np.abs(ra - start).max() > 0.01


def _with_a_past(world: GroundedWorld, action: str, sizes) -> np.ndarray:
    """Run other particles in `world` first, then `action` under `sizes`."""
    # Other sizes, other actions, a half-finished grasp, and the *same* sizes just before:
    # a world that skipped the rebuild when the sizes are unchanged is caught too.
    _run(world, PUSH, SIZES[1])
    _run(world, PICKUP, SIZES[2])
    config, traj, t0 = _case(PICKUP)
    world.reset(config, {"block_sizes": sizes})
    world.execute(traj[:6], PICKUP, start_time=t0, max_settle_s=0.0)      # stop mid-grasp
    _run(world, PUSH if action == PICKUP else PICKUP, sizes)
    _run(world, action, sizes)
    return _run(world, action, sizes)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("action", [PICKUP, PUSH])
def test_a_world_with_a_past_equals_a_fresh_world(action, engine):
    domain = load("container", engine=engine)
    with GroundedWorld(domain) as fresh:
        expected = _run(fresh, action, SIZES[0])
    with GroundedWorld(domain) as used:
        again = _with_a_past(used, action, SIZES[0])
    assert _bits(again) == _bits(expected)


class _RePoseOnly(PybulletWorld):
    """What reset() must not be: rebuild only when the sizes change, else re-pose the bodies
    (with restoreState of the just-built scene, which is what pybullet offers for this)."""

    def reset(self, config, props, *, place=True):
        props = self.domain.properties(props)
        if self.props is None or not np.array_equal(props["block_sizes"], self.props["block_sizes"]):
            pb.resetSimulation(physicsClientId=self.client)
            self._rebuild(props)
            self.props = props
            self._saved = pb.saveState(physicsClientId=self.client)
        else:
            pb.restoreState(self._saved, physicsClientId=self.client)
        placed = self.domain.place(config, props) if place else config
        self._apply(placed)
        return placed


@pytest.mark.parametrize("action", [PICKUP, PUSH])
def test_the_past_test_has_teeth(action):
    # Re-posing a built scene leaves contact caches and solver warm starts behind: the
    # results then depend on the world's past. This is why reset() rebuilds, and it shows
    # the test above would catch a reset() that cut that corner.
    domain = load("container")
    with GroundedWorld(domain) as fresh:
        expected = _run(fresh, action, SIZES[0])
    with _RePoseOnly(domain) as lazy:
        assert _bits(_run(lazy, action, SIZES[0])) == _bits(expected)   # its first build is fine
        assert _bits(_with_a_past(lazy, action, SIZES[0])) != _bits(expected)


_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    from sim_workers.domains import load
    from sim_workers.grounded_world import GroundedWorld
    import importlib.util
    spec = importlib.util.spec_from_file_location("_determinism", sys.argv[2])
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    _case, SIZES = helpers._case, helpers.SIZES
    out = {}
    with GroundedWorld(load("container", engine=sys.argv[3])) as w:
        for action in json.loads(sys.argv[1]):
            config, traj, t0 = _case(action)
            w.reset(config, {"block_sizes": SIZES[2]})
            arr = w.execute(traj, action, start_time=t0).configuration.to_array()
            out[action] = arr.tobytes().hex()
    print("RESULT " + json.dumps(out))
""")


@pytest.mark.timeout(180)          # the fresh process may take its 120 s
@pytest.mark.parametrize("engine", ENGINES)
def test_a_fresh_process_gives_identical_bits(neutral_cwd, engine):
    actions = [PICKUP, PUSH]
    proc = subprocess.run([sys.executable, "-c", _SCRIPT, json.dumps(actions), __file__, engine],
                          capture_output=True, text=True, timeout=120, cwd=neutral_cwd)
    assert proc.returncode == 0, proc.stderr
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")][-1]
    theirs = json.loads(line[len("RESULT "):])
    with GroundedWorld(load("container", engine=engine)) as w:
        for action in actions:
            assert theirs[action] == _bits(_run(w, action, SIZES[2])).hex(), action


def _assert_same(a: dict, b: dict) -> None:
    assert set(a) == set(b)
    for k in a:
        if a[k].dtype == object:
            assert list(a[k]) == list(b[k]), k
        else:
            assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
            assert np.ascontiguousarray(a[k]).tobytes() == np.ascontiguousarray(b[k]).tobytes(), k


def _concat(parts: list[dict]) -> dict:
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


@pytest.mark.parametrize("engine", ENGINES)
def test_shard_size_and_batch_split_do_not_matter(engine):
    config, traj, t0 = _case(PICKUP)
    start = config.to_array()
    one = Shard("container", {"engine": engine}, n_worlds=1)
    three = Shard("container", {"engine": engine}, n_worlds=3)
    try:
        whole = one.simulate(start, SIZES, PICKUP, traj, t0)
        split = _concat([three.simulate(start, SIZES[:1], PICKUP, traj, t0),
                         three.simulate(start, SIZES[1:5], PICKUP, traj, t0),
                         three.simulate(start, SIZES[5:], PICKUP, traj, t0)])
        reversed_ = one.simulate(start, SIZES[::-1], PICKUP, traj, t0)
    finally:
        one.close()
        three.close()
    _assert_same(whole, split)
    _assert_same(whole, {k: v[::-1] for k, v in reversed_.items()})
    # The batch's particles did differ: wrong beliefs make different worlds (and outcomes).
    states = [decode_state(s) for s in whole["states"]]
    assert "is_holding(r,b3)" in states[0]
    assert len({_bits(row) for row in whole["configurations"]}) == len(SIZES)


@pytest.mark.parametrize("action", [PICKUP, PUSH])
def test_worlds_stepped_on_threads_give_the_serial_bits(action):
    """Issue 42: a shard's MuJoCo worlds step at once on threads (MuJoCo releases the GIL);
    each particle-action starts from a reset world, so the batch's bits are the serial
    shard's, whatever the thread count. pybullet's worlds do not step in threads (one)."""
    config, traj, t0 = _case(action)
    start = config.to_array()
    serial = Shard("container", {"engine": "mujoco"}, n_worlds=1)
    threaded = {k: Shard("container", {"engine": "mujoco"}, threads=k) for k in (2, 3)}
    try:
        want = serial.simulate(start, SIZES, action, traj, t0)
        for k, shard in threaded.items():
            assert shard.threads == k and len(shard.worlds) == k
            _assert_same(want, shard.simulate(start, SIZES, action, traj, t0))
            # twice: the threads' worlds now have a past
            _assert_same(want, shard.simulate(start, SIZES[::-1], action, traj, t0) and
                         shard.simulate(start, SIZES, action, traj, t0))
    finally:
        serial.close()
        for shard in threaded.values():
            shard.close()
    from sim_workers.engines import installed

    if installed("pybullet"):
        one = Shard("container", {"engine": "pybullet"}, threads=4)
        try:
            assert one.threads == 1
        finally:
            one.close()


@pytest.mark.slow
@pytest.mark.timeout(480)          # Ray's start, then ray.get waits of 180 + 180 + 60 s
@pytest.mark.parametrize("engine", ENGINES)
def test_two_ray_actors_match_the_in_process_shard(ray_cluster, engine):
    ray = ray_cluster
    config, traj, t0 = _case(PUSH)
    start = config.to_array()
    local = Shard("container", {"engine": engine}, n_worlds=2)
    try:
        expected = local.simulate(start, SIZES, PUSH, traj, t0)
    finally:
        local.close()
    # No CPU reservation: other tests' actors on the shared 2-CPU cluster cannot starve these.
    Actor = remote_shard(num_cpus=0)
    actors = [Actor.remote("container", {"engine": engine}, n) for n in (1, 2)]
    try:
        parts = ray.get([actors[0].simulate.remote(start, SIZES[:3], PUSH, traj, t0),
                         actors[1].simulate.remote(start, SIZES[3:], PUSH, traj, t0)], timeout=180)
        swapped = ray.get([actors[1].simulate.remote(start, SIZES[:3], PUSH, traj, t0),
                           actors[0].simulate.remote(start, SIZES[3:], PUSH, traj, t0)], timeout=180)
        nodes = ray.get([a.node.remote() for a in actors], timeout=60)
    finally:
        for a in actors:
            ray.kill(a)
    _assert_same(expected, _concat(parts))
    _assert_same(expected, _concat(swapped))
    assert len({n["pid"] for n in nodes}) == 2 and all(n["pid"] != os.getpid() for n in nodes)


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        resident_pages = int(f.read().split()[1])
    return resident_pages * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


@pytest.mark.slow
@pytest.mark.parametrize("engine", ENGINES)
def test_memory_stays_flat_over_many_resets(engine):
    domain = load("container", engine=engine)
    config, traj, t0 = _case(PICKUP)
    rng = np.random.default_rng(0)
    with GroundedWorld(domain) as w:
        for _ in range(200):                       # warm up allocator pools and caches
            w.reset(config, {"block_sizes": rng.uniform(0.03, 0.06, N)})
        w.execute(traj, PICKUP, start_time=t0)
        before = _rss_mb()
        for k in range(2000):                      # every reset a new size hypothesis
            w.reset(config, {"block_sizes": rng.uniform(0.03, 0.06, N)})
            if k % 500 == 0:
                w.execute(traj, PICKUP, start_time=t0)
        grown = _rss_mb() - before
    assert grown < 3.0, f"RSS grew {grown:.2f} MB over 2000 resets"
