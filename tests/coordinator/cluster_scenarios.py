"""The multi-node scenarios of tests/coordinator/test_cluster.py, in a process of their own.

A process connects to one Ray cluster, and the test session already has its local
``ray.init(num_cpus=2)``; so `test_cluster.py` runs this file with ``sys.executable``. It
builds a ``ray.cluster_utils.Cluster`` on this machine (a head node and, later, a worker
node, 1 CPU each), runs the scenarios below with one tiny task (4 particles, 1 episode,
at most 4 actions, seed 7) and prints one JSON line (the last line of stdout):

  single   the task on the head alone (the single-node reference)
  api      `tmoc serve --ray-address <cluster>`: task 1 on the head alone, then a worker
           node joins, then task 2 (same spec): its pool must grow onto the new node
  two      the task with the runner's own pool on both nodes
  failure  the same, the worker node removed while the second action's batches are in
           flight (its shard's slice must be re-run on the head)
  gpu      a node with one logical GPU joins; a pool of the batch engine (mujoco_warp)
           puts its one shard on it and its particles' outcomes are CPU MuJoCo's
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]     # for test helpers only: the packages come installed
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

# (the paper's loop: these scenarios are about nodes and dispatch, not T's prior)
SPEC = {"agent": "tmoc", "particles": 4, "episodes": 1, "max_steps": 4, "seed": 7, "counterfactual_rows": 0}


def _load_helper(path: Path):
    """A test helper module by file path (the checkout is not on sys.path, on purpose)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"_helper_{path.parent.name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def strip(result: dict) -> dict:
    """What must not depend on placement: result.json without runtime and wall clocks."""
    r = json.loads(json.dumps(result))
    r.pop("runtime", None)
    for e in r.get("episodes", []):
        for k in ("wall_s", "physics_s", "planning_s", "counterfactual_s"):
            e.pop(k, None)
    return r


def wait_cpus(ray, n: float, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while ray.available_resources().get("CPU", 0) < n:
        if time.monotonic() > deadline:
            raise RuntimeError(f"CPUs not freed: {ray.available_resources()}")
        time.sleep(0.2)


def api_scenario(cluster, address: str, tmp: Path) -> dict:
    import httpx

    api_helpers = _load_helper(REPO / "tests" / "api" / "conftest.py")
    Server, wait_for = api_helpers.Server, api_helpers.wait_for

    server = Server(tmp / "cluster.sqlite", "--ray-address", address).start(timeout=120)
    out = {}
    try:
        with server.client(timeout=60) as client:
            def finished(task_id):
                def done():
                    v = client.get(f"/v1/tasks/{task_id}").json()
                    return v if v["status"] in ("succeeded", "failed", "cancelled") else None
                return wait_for(done, timeout=240, every=0.3, what=f"task {task_id}")

            t1 = client.post("/v1/tasks", json=SPEC).json()["id"]
            out["task1"] = finished(t1)
            t0 = time.perf_counter()
            out["worker"] = cluster.add_node(num_cpus=1).node_id
            cluster.wait_for_nodes()
            out["join_s"] = time.perf_counter() - t0
            t2 = client.post("/v1/tasks", json=SPEC).json()["id"]
            out["task2"] = finished(t2)
            out["episodes2"] = client.get(f"/v1/tasks/{t2}/episodes").json()
    except httpx.HTTPError as exc:  # pragma: no cover - shown by the test
        raise RuntimeError(f"{exc}\n{server.log()}") from None
    finally:
        server.stop()
    return out


def gpu_scenario(cluster, ShardPool) -> dict:
    """A node with one (logical) GPU joins: a batch-engine pool puts its one shard there,
    reserving the GPU (on this machine without a CUDA driver Warp steps on the CPU)."""
    import numpy as np
    import ray

    from sim_workers.domains import load
    from sim_workers.shard import Shard, decode_state

    node = cluster.add_node(num_cpus=1, num_gpus=1)
    cluster.wait_for_nodes()
    physics = load("container")
    truth = physics.true_properties()
    config = physics.initial_configuration(truth)
    action = "pickup(r,b3,init)"
    traj = physics.action_trajectory(config, action, physics.action_pose(truth, config, action))
    sizes = np.repeat(np.array([[0.034], [0.045], [0.056]]), 8, axis=1)
    options = {"n_blocks": 8, "engine": "mujoco_warp"}
    pool = ShardPool("container", options)
    try:
        out = pool.simulate(config.to_array(), sizes, action, traj, start_time=float(traj[3, 0]))
        gpus_left = ray.available_resources().get("GPU", 0.0)
        shards = len(pool.actors)
    finally:
        pool.close()
    cpu = Shard("container", {"n_blocks": 8, "engine": "mujoco"})
    try:
        want = cpu.simulate(config.to_array(), sizes, action, traj, start_time=float(traj[3, 0]))
    finally:
        cpu.close()
    return {"node": node.node_id, "shards": shards, "nodes": out["nodes"], "gpus_free_while_running": gpus_left,
            "same_states": [a == decode_state(b) for a, b in zip(out["states"], want["states"])]}


def main() -> int:
    import tempfile

    import ray
    from ray.cluster_utils import Cluster

    import coordinator.loop.runner as runner
    import coordinator.distributed.shard_pools as shard_pools
    from coordinator.distributed.fanout import ShardPool
    from coordinator.run_config import RunConfig

    cfg = RunConfig(**SPEC)
    timings = {}
    t = time.perf_counter()
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        ray.init(address=cluster.address, logging_level="ERROR", log_to_driver=False)
        head = ray.get_runtime_context().get_node_id()
        timings["cluster_s"] = time.perf_counter() - t

        t = time.perf_counter()
        single = runner.run(cfg)
        timings["single_s"] = time.perf_counter() - t

        t = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            api = api_scenario(cluster, cluster.address, Path(tmp))
        timings["api_s"] = time.perf_counter() - t
        worker = next(n for n in cluster.worker_nodes if n.node_id == api["worker"])
        wait_cpus(ray, 2)                      # the server's shards are gone with it

        t = time.perf_counter()
        two = runner.run(cfg)
        timings["two_s"] = time.perf_counter() - t
        wait_cpus(ray, 2)

        # The worker node leaves while the second action's batches are in flight: the
        # first ray.wait of that call removes it (remove_node waits for its processes to die).
        removed = {}
        real_wait = ray.wait

        class NodeLossPool(ShardPool):
            def simulate(self, *args, **kwargs):
                removed["armed"] = self.timings["calls"] == 1
                return super().simulate(*args, **kwargs)

        def wait(*args, **kwargs):
            if removed.pop("armed", False):
                t_rm = time.perf_counter()
                cluster.remove_node(worker)
                removed["remove_s"] = time.perf_counter() - t_rm
                removed["at"] = time.perf_counter()
            return real_wait(*args, **kwargs)

        ray.wait = wait
        # The runner's own pool is built by coordinator.distributed.shard_pools.ShardPools.
        shard_pools.ShardPool = NodeLossPool
        t = time.perf_counter()
        try:
            failure = runner.run(cfg)
        finally:
            ray.wait = real_wait
            shard_pools.ShardPool = ShardPool
        timings["failure_s"] = time.perf_counter() - t
        timings["remove_s"] = removed.get("remove_s")
        alive = [n["NodeID"] for n in ray.nodes() if n["Alive"]]

        t = time.perf_counter()
        gpu = gpu_scenario(cluster, ShardPool)
        timings["gpu_s"] = time.perf_counter() - t
    finally:
        ray.shutdown()
        cluster.shutdown()
    print(json.dumps({
        "head": head, "worker": api["worker"], "alive_after": alive, "timings": timings,
        "single": {"result": strip(single), "runtime": single["runtime"]},
        "two": {"result": strip(two), "runtime": two["runtime"]},
        "failure": {"result": strip(failure), "runtime": failure["runtime"],
                    "removed": "at" in removed},
        "api": api, "gpu": gpu,
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())
