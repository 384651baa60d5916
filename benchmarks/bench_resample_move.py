"""The resample-move after a sharp step (`move_after_resample`, docs/LOOP.md), with and without.

    python benchmarks/bench_resample_move.py [--part synthetic|slide|both] [--seeds N]

synthetic: a channel 10x as sensitive to L as the container's opening (2 mm pins L to
0.2 mm; 16 particles ~2 mm apart), four readings with the sensor's noise, truths across the
prior, one run per seed; per number of sweeps (and without the move): runs within 2x the
exact posterior's std, median std / exact, mean z^2 and coverage at +-2 std, and the wall
time of the filter's updates. Seconds; no physics.

slide: the smallest example domain (docs/examples/tmoc-slide-domain, from the checkout) at
16 particles, 2 episodes, truths 0.2, 0.3, 0.45 and 0.55 x `--seeds` seeds, with and without
the move: runs that learned (std < 0.03), max |z|, mean z^2, coverage, episode 2 at the
optimum, runs that never improved, and the time of each arm (ratio printed). Minutes.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from coordinator.loop.session import Session
from coordinator.particle_filter import resample_move as rm
from coordinator.particle_filter import filter as pf
from coordinator.particle_filter.resample_move import RealStep
from coordinator.run_config import RunConfig

SIGMA, GAIN, N = 0.002, 10.0, 16
SLIDE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "tmoc-slide-domain"


def _sharp_world(start, rows, action, trajectory, start_time) -> dict:
    rows = np.asarray(rows)
    meas = np.full((len(rows), 17), np.nan)
    meas[:, 0] = GAIN * (rows[:, 0] - 0.030)
    return {"states": [frozenset({"ok"})] * len(rows), "measurements": meas, "steps": np.ones(len(rows))}


def _synthetic_run(seed: int, move: bool, readings: int = 4) -> tuple[float, float]:
    s = Session(RunConfig(particles=N, seed=seed, particle_budget="fixed", move_after_resample=move))
    rng = np.random.default_rng(seed + 200)
    truth = 0.033 + 0.024 * rng.random()
    ok = frozenset({"ok"})
    for _ in range(readings):
        obs = np.full(17, np.nan)
        obs[0] = GAIN * (truth - 0.030) + rng.normal(0, SIGMA)
        pred = _sharp_world(None, s.belief.particles, "pickup(r,b1,init)", None, 0.0)
        sym = np.full(s.belief.n, math.log1p(-s.config.error_rate))
        step = RealStep(np.zeros(1), "pickup(r,b1,init)", np.zeros((2, 6)), 0.0, ok, ok, obs)
        s.filter.update(step, sym, pred["measurements"], s.rng, _sharp_world, s._symbolic_loglik)
    mean, std = float(s.belief.mean()[0]), float(s.belief.std()[0])
    return (mean - truth) / std, std / (SIGMA / GAIN / math.sqrt(readings))


def synthetic(seeds: int) -> None:
    print(f"synthetic sharp channel, {seeds} runs of 4 readings, {N} particles")
    print("sweeps | within 2x exact | median std/exact | mean z^2 | covered +-2 | seconds")
    original = rm.resample_move
    try:
        for sweeps in (None, 1, 2, 4, 8, 16):
            pf.resample_move = lambda *a, _s=sweeps, **k: original(*a, **{**k, "max_sweeps": _s or 0})
            t0 = time.perf_counter()
            runs = [_synthetic_run(seed, move=sweeps is not None) for seed in range(seeds)]
            dt = time.perf_counter() - t0
            z, sharp = np.array([r[0] for r in runs]), np.array([r[1] for r in runs])
            print(f"{'none' if sweeps is None else sweeps:>6} | {int(np.sum(sharp <= 2)):>3} / {seeds} | "
                  f"{np.median(sharp):16.2f} | {np.mean(z ** 2):8.2f} | {int(np.sum(abs(z) <= 2)):>3} / {seeds} | {dt:.2f}")
    finally:
        pf.resample_move = original


def slide(seeds: int) -> None:
    sys.path.insert(0, str(SLIDE))
    from tmoc_slide_domain import DOMAIN

    import sim_workers.domains as registry
    from coordinator.distributed.fanout import ShardPool
    from coordinator.loop.runner import run

    real = registry.plugin_entries
    registry.plugin_entries = lambda: {**real(), "slide": {**DOMAIN, "distribution": "tmoc-slide-domain"}}
    pool = ShardPool("slide", {"n_blocks": 2}, n_shards=0)
    times = {}
    try:
        for move in (False, True):
            rows, t0 = [], time.perf_counter()
            for truth in (0.2, 0.3, 0.45, 0.55):
                for seed in range(1, seeds + 1):
                    cfg = RunConfig(domain="slide", truth={"friction": truth}, particles=N, episodes=2, seed=seed,
                                    particle_budget="fixed", n_objects=2, move_after_resample=move)
                    r = run(cfg, pool=pool)
                    post = r["summary"]["posterior"]["friction"]
                    utils = [e["utility"] for e in r["episodes"]]
                    rows.append(((post["mean"] - truth) / post["std"], post["std"], utils))
            times[move] = time.perf_counter() - t0
            z = np.array([r[0] for r in rows])
            learned = np.array([r[1] < 0.03 for r in rows])
            optimum = sum(r[2][-1] == 80.0 for r in rows)
            never = sum(r[2][-1] <= r[2][0] and r[2][0] < 80.0 for r in rows)
            print(f"slide, move_after_resample={move}: learned {int(learned.sum())}/{len(rows)}, "
                  f"max |z| (learned) {np.max(np.abs(z[learned])):.2f}, mean z^2 (learned) {np.mean(z[learned] ** 2):.2f}, "
                  f"covered +-2 {int(np.sum(np.abs(z) <= 2))}/{len(rows)}, episode 2 at 80: {optimum}/{len(rows)}, "
                  f"never improved: {never}, {times[move]:.0f} s")
    finally:
        pool.close()
    print(f"time with / without the move: {times[True] / times[False]:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=("synthetic", "slide", "both"), default="both")
    ap.add_argument("--seeds", type=int, default=None, help="synthetic: 24; slide: 4 per truth")
    args = ap.parse_args()
    if args.seeds is not None and args.seeds < 1:
        ap.error("--seeds: at least 1")
    if args.part in ("synthetic", "both"):
        synthetic(args.seeds or 24)
    if args.part in ("slide", "both"):
        slide(args.seeds or 4)


if __name__ == "__main__":
    main()
