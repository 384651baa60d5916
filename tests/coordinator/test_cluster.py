"""Particles across machines (issue 6): a real multi-node Ray cluster on this machine.

``ray.cluster_utils.Cluster`` starts a head and a worker node of 1 CPU each (separate
raylets, the way separate machines are). A process joins one Ray cluster only, and this
test session has its own local Ray, so the scenarios run in a subprocess
(tests/coordinator/cluster_scenarios.py) that prints its findings as JSON; every test
below checks one property of that single run.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from coordinator.distributed.fanout import plan_shards

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]

# The scenarios' subprocess may take its 420 s inside the first test's setup.
pytestmark = [pytest.mark.slow, pytest.mark.cluster, pytest.mark.timeout(600)]


@pytest.fixture(scope="module")
def scenarios(neutral_cwd):
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", PYTHONUNBUFFERED="1")
    env.pop("RAY_ADDRESS", None)
    proc = subprocess.run([sys.executable, str(HERE / "cluster_scenarios.py")], cwd=neutral_cwd, env=env,
                          capture_output=True, text=True, timeout=420)
    assert proc.returncode == 0, f"{proc.stdout[-4000:]}\n{proc.stderr[-6000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _by_node(runtime: dict) -> dict:
    return {n["node_id"]: n for n in runtime["nodes"]}


def test_plan_gives_one_shard_per_cpu_and_deals_a_fixed_count_over_nodes():
    nodes = [{"node_id": "a", "cpus": 2}, {"node_id": "b", "cpus": 1}, {"node_id": "c", "cpus": 0}]
    assert plan_shards(nodes) == ["a", "b", "a"]
    assert plan_shards(nodes, 2) == ["a", "b"]
    assert plan_shards(nodes, 5) == ["a", "b", "a", "a", "b"]
    assert plan_shards([{"node_id": "h", "cpus": 0}]) == []


def test_single_node_reference_runs_on_the_head_alone(scenarios):
    rt = scenarios["single"]["runtime"]
    assert [n["node_id"] for n in rt["nodes"]] == [scenarios["head"]]
    assert rt["shards"] == 1 and rt["nodes"][0]["particle_actions"] == rt["particle_actions"] > 0


def test_shards_land_on_both_nodes_with_the_same_result(scenarios):
    rt = scenarios["two"]["runtime"]
    nodes = _by_node(rt)
    assert set(nodes) == {scenarios["head"], scenarios["worker"]}
    assert rt["shards"] == 2 and all(n["shards"] == 1 for n in nodes.values())
    # 4 particles, 2 per shard, on every action; Y's alternatives are judged in the rows
    # where Y's pose may fail only (an odd count splits 2 + 1), so the halves are close.
    assert sum(n["particle_actions"] for n in nodes.values()) == rt["particle_actions"]
    assert all(0.4 * rt["particle_actions"] <= n["particle_actions"] <= 0.6 * rt["particle_actions"]
               for n in nodes.values()), nodes
    assert all(n["hostname"] for n in nodes.values()) and rt["reruns"] == 0
    assert scenarios["two"]["result"] == scenarios["single"]["result"]


def test_losing_the_worker_node_mid_run_reruns_its_batch_with_an_identical_result(scenarios):
    f = scenarios["failure"]
    assert f["removed"] and scenarios["alive_after"] == [scenarios["head"]]
    rt = f["runtime"]
    nodes = _by_node(rt)
    assert rt["reruns"] >= 1
    # The worker answered the first action only; the head ran the rest, its re-run included.
    assert nodes[scenarios["worker"]]["particle_actions"] == 2
    assert nodes[scenarios["head"]]["particle_actions"] == rt["particle_actions"] - 2
    assert rt["particle_actions"] == scenarios["single"]["runtime"]["particle_actions"]
    assert f["result"] == scenarios["single"]["result"]


def test_service_pool_grows_onto_a_node_that_joined_between_tasks(scenarios):
    api, single = scenarios["api"], scenarios["single"]
    t1, t2 = api["task1"], api["task2"]
    assert t1["status"] == t2["status"] == "succeeded", (t1.get("error"), t2.get("error"))
    # The task status reports which nodes ran the particles (also in result.runtime).
    assert [n["node_id"] for n in t1["nodes"]] == [scenarios["head"]]
    nodes = {n["node_id"]: n for n in t2["nodes"]}
    assert set(nodes) == {scenarios["head"], scenarios["worker"]}
    assert all(n["shards"] == 1 and n["particle_actions"] > 0 for n in nodes.values())
    assert t2["nodes"] == t2["result"]["runtime"]["nodes"]
    # Same spec, same seed: the same episodes and summary as the single-node run.
    for e in api["episodes2"]:
        for k in ("wall_s", "physics_s", "planning_s", "counterfactual_s"):
            e.pop(k, None)
    assert api["episodes2"] == single["result"]["episodes"]
    assert t2["result"]["summary"] == single["result"]["summary"]


def test_a_batch_engine_pool_puts_one_shard_per_gpu(scenarios):
    """Issue 42: with the batch engine (MuJoCo Warp) a pool plans one shard per GPU of the
    cluster, not per CPU: the node with the (logical) GPU holds it and runs the particles,
    whose outcomes are CPU MuJoCo's."""
    g = scenarios["gpu"]
    assert g["shards"] == 1 and list(g["nodes"]) == [g["node"]]
    assert g["nodes"][g["node"]]["particle_actions"] == 3
    assert g["gpus_free_while_running"] == 0.0           # the shard holds the GPU
    assert all(g["same_states"]), g["same_states"]
