"""Run a whole task: episodes of the TMOC loop on Ray, then result.json and curve.png."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from sim_workers.engines import check_engine
from sim_workers.reality_gap import SensorNoise

from ..distributed.fanout import ShardPool
from .observer import EpisodeCallback, RunObserver
from .reality import ContextFailure, SimulatedReality
from ..run_config import REALITY_STREAM, RunConfig, seed_stream
from .session import EpisodeInterrupted, Session
from ..distributed.shard_pools import ShardPools


def reality_for(config: RunConfig, session: Session) -> SimulatedReality:
    """The simulated real world holding the hidden truth, with the run's domain options."""
    # The truth is a row of L, built like a particle's (issue 39: one path; a size-only L
    # scaled the domain's default sizes by true_size / default, one ulp off at most truths).
    truth = session.domain.props_from_row(session.truth_row())
    failure = None if config.reality_fail is None else ContextFailure.parse(config.reality_fail)
    engine = {"engine": config.reality_engine} if config.reality_engine else {}
    return SimulatedReality(config.domain, {**domain_options(config), **engine}, truth, failure=failure,
                            context_fn=session.task.context_of, noise=sensor_noise(config))


def sensor_noise(config: RunConfig) -> SensorNoise:
    """The simulated reality's sensor and perception noise of a run (issue 37)."""
    return SensorNoise(scale=config.sensor_noise, bias=config.sensor_bias, tails=config.sensor_tails,
                       perception_m=config.perception_sigma)


def reality_stream(seed: int, resume: dict | None = None) -> np.random.Generator:
    """The simulated reality's generator (REALITY_STREAM), at a checkpoint's place when
    resuming: its bit generator's state and the number of child streams it had spawned
    (the reality spawns the execution jitter's and the sensors' streams every episode; a
    spawned child is numbered by that count, which the state does not hold). A checkpoint
    from before the count resumes at 0, as it did."""
    rng = seed_stream(seed, REALITY_STREAM)
    if resume:
        spawned = int(resume.get("reality_rng_spawned", 0))
        if spawned:
            ss = rng.bit_generator.seed_seq
            ss = np.random.SeedSequence(ss.entropy, spawn_key=ss.spawn_key, pool_size=ss.pool_size,
                                        n_children_spawned=spawned)
            rng = np.random.Generator(type(rng.bit_generator)(ss))
        rng.bit_generator.state = resume["reality_rng"]
    return rng


def domain_options(config: RunConfig) -> dict:
    """What every world of a run is built with: n_blocks and the run's domain options."""
    return {"n_blocks": config.n_blocks, **config.options}


class NodeTally:
    """Particle-actions per Ray node over a run; kept in the checkpoint, so that a resumed
    run goes on counting where the interrupted one stopped."""

    def __init__(self, nodes: list[dict] | None = None, reruns: int = 0) -> None:
        self.by_node = {n["node_id"]: {"hostname": n["hostname"],
                                       "particle_actions": int(n["particle_actions"])}
                        for n in nodes or []}
        self.reruns = reruns

    def add(self, out: dict) -> None:
        for node_id, d in out.get("nodes", {}).items():
            e = self.by_node.setdefault(node_id, {"hostname": d["hostname"], "particle_actions": 0})
            e["particle_actions"] += d["particle_actions"]
        self.reruns += int(out.get("reruns", 0))

    def report(self, shards: list[dict]) -> list[dict]:
        """One row per node that holds a shard or ran particles: node_id, hostname, shards
        (at the start of this run), particle_actions (over the whole task)."""
        per_node = {}
        for s in shards:
            row = per_node.setdefault(s["node_id"], {"node_id": s["node_id"], "hostname": s["hostname"],
                                                     "shards": 0, "particle_actions": 0})
            row["shards"] += 1
        for node_id, d in self.by_node.items():
            row = per_node.setdefault(node_id, {"node_id": node_id, "hostname": d["hostname"],
                                                "shards": 0, "particle_actions": 0})
            row["particle_actions"] = d["particle_actions"]
        return [per_node[k] for k in sorted(per_node)]


class _Tallied:
    """The pool as the session sees it: every simulate() is counted per node."""

    def __init__(self, pool: ShardPool, tally: NodeTally) -> None:
        self.pool, self.tally = pool, tally

    def simulate(self, *args, **kwargs) -> dict:
        out = self.pool.simulate(*args, **kwargs)
        self.tally.add(out)
        return out

    def probe_rows(self, *args, **kwargs) -> dict:
        return self.pool.probe_rows(*args, **kwargs)


def run(config: RunConfig, *, ray_address: str | None = None,
        on_episode: Callable[[dict, Session, dict], None] | None = None,
        resume: dict | None = None, should_stop: Callable[[], bool] | None = None,
        pool: ShardPool | None = None, kill_shard_at: int | None = None,
        frames=None, observers: Sequence[RunObserver] = ()) -> dict:
    """Run the episodes of `config`; returns the result record (see `tmoc run`).

    `observers` (``coordinator.loop.observer.RunObserver``) watch the run: each step, each
    episode, closed when it ends. on_episode(record, session, checkpoint) is one of them
    (an ``EpisodeCallback``, called after the others), after every episode with a
    checkpoint from which ``run(config, resume=checkpoint)`` continues exactly where this
    run is (same results as an uninterrupted run). `should_stop` is polled between
    episodes. `pool` lets a long-lived service share one shard pool between tasks.
    `kill_shard_at` (tests only): kill shard 0 right before that episode, to check that Ray
    restarts it and the run ends with identical results.

    `frames` (a ``coordinator.integrations.frames.FrameSink``): scene pictures of the run go there (the
    end of every episode, every failed action), drawn by a ``FrameRecorder`` observer, first
    of them; they change nothing in the results.

    ``runtime.nodes`` of the result lists the Ray nodes that ran particles (node_id,
    hostname, shards, particle_actions); the checkpoint carries them as ``nodes``.
    """
    t0 = time.perf_counter()
    own_pools = None                 # this run's own Ray and pool when none is lent
    session = Session.from_checkpoint(resume["session"]) if resume else Session(config)
    tally = NodeTally(resume.get("nodes") if resume else None,
                      resume.get("reruns", 0) if resume else 0)
    if session.agent.learn_belief:
        if pool is None:
            own_pools = ShardPools(ray_address, config.shards, max_pools=1, own_ray_thread=False)
            pool = own_pools.acquire(config.scene)
        session.shard_pool = _Tallied(pool, tally)
    else:
        pool = None
    reality = reality_for(config, session)
    if frames is not None:
        from ..integrations.frames import FrameRecorder

        session.watch(FrameRecorder(config.domain, domain_options(config), reality.truth, frames))
    # Reality's draws come from their own stream: the agent's decisions never shift them.
    reality_rng = reality_stream(config.seed, resume)
    nodes: list[dict] = []
    for observer in observers:
        session.watch(observer)
    if on_episode is not None:
        session.watch(EpisodeCallback(on_episode, lambda: {
            "reality_rng": reality_rng.bit_generator.state,
            "reality_rng_spawned": reality_rng.bit_generator.seed_seq.n_children_spawned,
            "nodes": tally.report(nodes), "reruns": tally.reruns}))
    ray_s0 = pool.timings["ray_s"] if pool is not None else 0.0
    try:
        nodes = pool.nodes() if pool is not None else []
        for e in range(session.episode, config.episodes):
            if should_stop is not None and should_stop():
                break
            if kill_shard_at is not None and e == kill_shard_at and pool is not None and pool.actors:
                import ray
                ray.kill(pool.actors[0], no_restart=False)
            try:
                # Polled before every action too: a cancel takes effect within one action
                # (issue 25: 108.7 s at 16 blocks), the partial episode dropped.
                session.run_episode(reality, reality_rng, should_stop)
            except EpisodeInterrupted:
                break
    finally:
        reality.close()
        for observer in session.observers:
            observer.close()
        ray_s = pool.timings["ray_s"] - ray_s0 if pool is not None else 0.0
        if own_pools is not None:
            own_pools.close()
    return result_record(config, session, nodes, time.perf_counter() - t0, ray_s, tally)


def result_record(config: RunConfig, session: Session, nodes: list[dict], wall_s: float,
                  ray_s: float, tally: NodeTally | None = None) -> dict:
    episodes = session.episodes
    utilities = [e["utility"] for e in episodes]
    post = session.posterior()
    T = session.transition
    # The hidden truth in full, by L's names (defaults included): `truth: {}` said nothing
    # of what the run's reality held when it was the default (issue 39).
    truth = {str(n): float(v) for n, v in zip(session.L.names, session.L.truth_row(config.truth_values(), 1, False))}
    dumped = config.model_dump()
    dumped["truth"] = {**truth, **dumped["truth"]}
    return {
        "config": dumped,
        "episodes": episodes,
        "summary": {
            "mean_utility": float(np.mean(utilities)) if utilities else None,
            # (None for a domain whose L has no size: its figures are under "posterior")
            "final_size_mean": post.get("size_mean"),
            "final_size_std": post.get("size_std"),
            "true_size": config.true_size if "size_mean" in post else None,
            "truth": {**truth, **config.truth_values()},
            "posterior": post["properties"],
            "transition": T.to_planner(),
            # actions that moved without a checked transit (episode records say why)
            "transit_fallbacks": int(sum(e.get("transit_fallbacks", 0) for e in episodes)),
        },
        "runtime": {
            # the engines that ran (the config's, or the default where it left them unset)
            "engines": {"particles": check_engine(config.engine),
                        "reality": check_engine(config.reality_engine, "reality_engine")},
            "shards": len(nodes),
            "nodes": (tally or NodeTally()).report(nodes),
            "reruns": tally.reruns if tally is not None else 0,
            "particle_actions": session.particle_actions,
            "particle_steps": session.particle_steps,
            "wall_s": wall_s,
            "ray_wait_s": ray_s,
            "physics_s": float(sum(e["physics_s"] for e in episodes)),
            "planning_s": float(sum(e["planning_s"] for e in episodes)),
        },
    }


def write_result(result: dict, out_dir: Path) -> tuple[Path, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "result.json"
    path.write_text(json.dumps(result, indent=2, sort_keys=True))
    png = out_dir / "curve.png"
    plot_curve(result, png)
    return path, png


def plot_curve(result: dict, path: Path) -> None:
    """Utility per episode, then one panel per property of L: its posterior mean, its
    spread and the truth (size in mm; other properties in their own units)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps = result["episodes"]
    x = [e["episode"] for e in eps]
    names = list(eps[-1]["posterior"].get("properties", {"size": {}})) if eps else ["size"]
    truth = (result.get("summary") or {}).get("truth") or {
        **(result["config"].get("truth") or {}), "size": result["config"]["true_size"]}
    fig, axes = plt.subplots(1, 1 + len(names), figsize=(5 * (1 + len(names)), 3.8))
    ax1 = axes[0]
    ax1.plot(x, [e["utility"] for e in eps], marker="o")
    ax1.set_xlabel("episode")
    ax1.set_ylabel("utility")
    ax1.set_title(f"{result['config']['agent']}: utility")
    for ax, name in zip(axes[1:], names):
        if name == "size":
            scale, label = 1000.0, "block size (mm)"
            m = np.array([e["posterior"]["size_mean"] for e in eps]) * scale
            s = np.array([e["posterior"]["size_std"] for e in eps]) * scale
        else:
            props = [e["posterior"]["properties"][name] for e in eps]
            scale, label = 1.0, f"{name} ({props[0]['unit']})"
            m = np.array([p["mean"] for p in props])
            s = np.array([p["std"] for p in props])
        ax.plot(x, m, marker="o", label="posterior mean")
        ax.fill_between(x, m - s, m + s, alpha=0.3, label="±1 std")
        if name in truth:
            ax.axhline(truth[name] * scale, color="k", ls="--", label=f"true {name}")
        ax.set_xlabel("episode")
        ax.set_ylabel(label)
        ax.set_title(f"belief over L: {name}")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
