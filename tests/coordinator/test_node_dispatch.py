"""One Ray call per node per action (issue 42): the node's dispatcher splits the slice over
the node's shards, and nothing in the results depends on it.

On the session's local Ray (one node, 2 CPUs: two shards behind one dispatcher), against
the in-process shard and the per-shard dispatch, bit for bit, in both engines; then the
failures a dispatcher must survive: Ray restarting it (it comes back without its shards
and is sent them again) and one of its shards ending for good (its rows re-run on the
node's other shard).
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import pytest

from coordinator.distributed.fanout import ShardPool
from coordinator.distributed.node_dispatcher import split_bounds
from sim_workers.container.probes import loaded_configuration
from sim_workers.domains import load
from sim_workers.engines import ENGINES

N_BLOCKS = 8
PUSH = "push(r,c,init,goal)"
SIZES = np.array([[0.045] * N_BLOCKS, [0.041] * N_BLOCKS, np.linspace(0.032, 0.058, N_BLOCKS),
                  [0.050] * N_BLOCKS, [0.0455] * N_BLOCKS, np.linspace(0.058, 0.032, N_BLOCKS),
                  [0.036] * N_BLOCKS])


def _push_case(engine: str):
    domain = load("container", engine=engine)
    sizes = domain.true_properties()["block_sizes"]
    config = loaded_configuration(domain, sizes, 5, np.random.default_rng(3))
    key = domain.action_pose(domain.true_properties(), config, PUSH)
    traj = domain.action_trajectory(config, PUSH, key)
    return config.to_array(), traj, float(traj[3, 0])


def _same(a: dict, b: dict) -> None:
    for k in ("configurations", "measurements", "steps"):
        assert np.ascontiguousarray(a[k]).tobytes() == np.ascontiguousarray(b[k]).tobytes(), k
    assert a["states"] == b["states"]


def _pool(engine: str, dispatch: str = "node") -> ShardPool:
    # A small CPU reservation: other tests' actors on the shared 2-CPU cluster keep room.
    return ShardPool("container", {"n_blocks": N_BLOCKS, "engine": engine}, num_cpus=0.1,
                     dispatch=dispatch)


def test_rows_are_split_contiguously_and_whole():
    for lo, hi, k in [(0, 7, 2), (3, 4, 5), (0, 1000, 16), (5, 5, 3)]:
        parts = split_bounds(lo, hi, k)
        assert [a for a, _ in parts[1:]] == [b for _, b in parts[:-1]]
        assert (parts[0][0], parts[-1][1]) == (lo, hi) if parts else lo == hi
        assert all(b > a for a, b in parts) and len(parts) <= k
        sizes = [b - a for a, b in parts]
        assert not sizes or max(sizes) - min(sizes) <= 1


def test_an_unknown_dispatch_is_refused_by_name():
    with pytest.raises(ValueError, match="dispatch: 'tree'"):
        ShardPool("container", n_shards=0, dispatch="tree")


@pytest.mark.slow
@pytest.mark.parametrize("engine", ENGINES)
def test_one_call_per_node_gives_the_bits_of_every_other_split(ray_cluster, engine):
    start, traj, t0 = _push_case(engine)
    local = ShardPool("container", {"n_blocks": N_BLOCKS, "engine": engine}, n_shards=0)
    try:
        expected = local.simulate(start, SIZES, PUSH, traj, t0)
    finally:
        local.close()
    pool = _pool(engine)
    try:
        by_node = pool.simulate(start, SIZES, PUSH, traj, t0)
        # One node, two shards: one call from the driver, two from the dispatcher.
        assert pool.timings["ray_calls"] == 1 and pool.timings["node_calls"] == 2
        assert len(pool.actors) == 2
        pool.dispatch = "shard"
        by_shard = pool.simulate(start, SIZES, PUSH, traj, t0)
        assert pool.timings["ray_calls"] == 1 + 2
    finally:
        pool.close()
    _same(expected, by_node)
    _same(expected, by_shard)
    assert sum(v["particle_actions"] for v in by_node["nodes"].values()) == len(SIZES)
    # The batch's particles did differ: the comparison is not of seven copies of one row.
    assert len({row.tobytes() for row in by_node["configurations"]}) > 3


@contextmanager
def _pushing_pool():
    """A pybullet pool on the session's cluster and a call that pushes the SIZES batch."""
    start, traj, t0 = _push_case("pybullet")
    pool = _pool("pybullet")
    try:
        yield pool, lambda: pool.simulate(start, SIZES, PUSH, traj, t0)
    finally:
        pool.close()


@pytest.mark.slow
def test_a_restarted_dispatcher_is_sent_its_shards_again(ray_cluster):
    ray = ray_cluster
    with _pushing_pool() as (pool, push):
        first = push()
        (node,) = pool._nodes.values()
        before = ray.get(node.actor.ping.remote(), timeout=60)
        ray.kill(node.actor, no_restart=False)           # its process dies; Ray restarts it
        again = push()
        after = ray.get(node.actor.ping.remote(), timeout=60)
        assert after["pid"] != before["pid"] and pool.timings["plans_resent"] == 1
        assert (after["epoch"], after["shards"]) == (node.epoch, 2)
        assert again["reruns"] == 0
    _same(first, again)


@pytest.mark.slow
def test_a_shard_lost_for_good_has_its_rows_rerun_on_the_node(ray_cluster):
    ray = ray_cluster
    with _pushing_pool() as (pool, push):
        first = push()
        ray.kill(pool.actors[0], no_restart=True)
        again = push()
        assert again["reruns"] == 1
        (node,) = pool._nodes.values()
        assert ray.get(node.actor.ping.remote(), timeout=60)["shards"] == 1
        # the pool forgets it at once (not at the next re-plan): one shard, a new plan held
        # by the dispatcher, and the next action runs with no re-run
        assert pool.n_shards == 1 and len(node.shards) == 1
        assert ray.get(node.actor.ping.remote(), timeout=60)["epoch"] == node.epoch
        third = push()
        assert third["reruns"] == 0
    _same(first, again)
    _same(first, third)


@pytest.mark.slow
def test_one_threaded_shard_per_node_gives_the_same_bits(ray_cluster):
    """A MuJoCo node as one shard stepping its worlds on threads (issue 42, item 2): on
    the 2-CPU cluster, threads=2 plans one shard holding both CPUs' worth of reservation."""
    start, traj, t0 = _push_case("mujoco")
    local = ShardPool("container", {"n_blocks": N_BLOCKS, "engine": "mujoco"}, n_shards=0)
    pool = ShardPool("container", {"n_blocks": N_BLOCKS, "engine": "mujoco"}, num_cpus=0.1, threads=2)
    try:
        expected = local.simulate(start, SIZES, PUSH, traj, t0)
        got = pool.simulate(start, SIZES, PUSH, traj, t0)
        assert len(pool.actors) == 1 and pool.timings["node_calls"] == 1
        assert [n["worlds"] for n in pool.nodes()] == [2]
    finally:
        local.close()
        pool.close()
    _same(expected, got)
