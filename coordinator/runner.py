"""Run a whole task: episodes of the TMOC loop on Ray, then result.json and curve.png."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from .fanout import ShardPool, init_ray
from .reality import SimulatedReality
from .run_config import RunConfig
from .session import Session


def reality_for(config: RunConfig, session: Session) -> SimulatedReality:
    truth = session.domain.true_properties(config.sizes_variation)
    truth["block_sizes"] = truth["block_sizes"] * (config.true_size / session.domain.spec.true_size)
    return SimulatedReality(config.domain, {"n_blocks": config.n_blocks}, truth)


def run(config: RunConfig, *, ray_address: str | None = None,
        on_episode: Callable[[dict, Session, dict], None] | None = None,
        resume: dict | None = None, should_stop: Callable[[], bool] | None = None,
        pool: ShardPool | None = None, kill_shard_at: int | None = None) -> dict:
    """Run the episodes of `config`; returns the result record (see `tmoc run`).

    on_episode(record, session, checkpoint) is called after every episode with a
    checkpoint from which ``run(config, resume=checkpoint)`` continues exactly where this
    run is (same results as an uninterrupted run). `should_stop` is polled between
    episodes. `pool` lets a long-lived service share one shard pool between tasks.
    `kill_shard_at` (tests only): kill shard 0 right before that episode, to check that Ray
    restarts it and the run ends with identical results.
    """
    t0 = time.perf_counter()
    own_pool = pool is None
    session = Session.from_checkpoint(resume["session"]) if resume else Session(config)
    if session.agent.learn_belief:
        if pool is None:
            init_ray(ray_address)
            pool = ShardPool(config.domain, {"n_blocks": config.n_blocks}, config.shards)
        session.pool = pool
    else:
        pool, own_pool = None, False
    reality = reality_for(config, session)
    # Reality's draws come from their own stream: the agent's decisions never shift them.
    reality_rng = np.random.default_rng(np.random.SeedSequence(config.seed).spawn(2)[1])
    if resume:
        reality_rng.bit_generator.state = resume["reality_rng"]
    nodes: list[dict] = []
    try:
        nodes = pool.nodes() if pool is not None else []
        for e in range(session.episode, config.episodes):
            if should_stop is not None and should_stop():
                break
            if kill_shard_at is not None and e == kill_shard_at and pool is not None and pool.actors:
                import ray
                ray.kill(pool.actors[0], no_restart=False)
            record = session.run_episode(reality, reality_rng)
            if on_episode is not None:
                on_episode(record, session, {"session": session.to_checkpoint(),
                                             "reality_rng": reality_rng.bit_generator.state})
    finally:
        reality.close()
        ray_s = pool.timings["ray_s"] if pool is not None else 0.0
        if own_pool and pool is not None:
            pool.close()
    return result_record(config, session, nodes, time.perf_counter() - t0, ray_s)


def result_record(config: RunConfig, session: Session, nodes: list[dict], wall_s: float,
                  ray_s: float) -> dict:
    episodes = session.episodes
    utilities = [e["utility"] for e in episodes]
    post = session.posterior()
    T = session.transition
    return {
        "config": config.model_dump(),
        "episodes": episodes,
        "summary": {
            "mean_utility": float(np.mean(utilities)) if utilities else None,
            "final_size_mean": post["size_mean"],
            "final_size_std": post["size_std"],
            "true_size": config.true_size,
            "transition": T.to_planner(),
        },
        "runtime": {
            "shards": len(nodes),
            "nodes": sorted({n["node_id"] for n in nodes}),
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
    """Utility per episode, and the posterior block size with its spread."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eps = result["episodes"]
    x = [e["episode"] for e in eps]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    ax1.plot(x, [e["utility"] for e in eps], marker="o")
    ax1.set_xlabel("episode"); ax1.set_ylabel("utility"); ax1.set_title(f"{result['config']['agent']}: utility")
    m = np.array([e["posterior"]["size_mean"] for e in eps]) * 1000
    s = np.array([e["posterior"]["size_std"] for e in eps]) * 1000
    ax2.plot(x, m, marker="o", label="posterior mean")
    ax2.fill_between(x, m - s, m + s, alpha=0.3, label="±1 std")
    ax2.axhline(result["config"]["true_size"] * 1000, color="k", ls="--", label="true size")
    ax2.set_xlabel("episode"); ax2.set_ylabel("block size (mm)"); ax2.set_title("belief over L"); ax2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
