"""The chute (docs/examples/tmoc-chute-domain, a domain that is not a block world): TMOC
against TMP-RL over truths spanning the prior of the pucks' friction, and how well TMOC's
posterior finds the truth.

    pip install -e docs/examples/tmoc-chute-domain
    python benchmarks/bench_chute.py                   # 5 truths x 2 seeds x 6 episodes, ~12 min on 2 cores
    python benchmarks/bench_chute.py --truths 0.2,0.6 --seeds 1 --episodes 4

Every run is `tmoc run --domain chute --truth friction=MU` (N <= 16 particles for TMOC);
prints per truth the mean utility of each agent, their difference, and TMOC's final
posterior (mean +- std, |error| in stds), then the totals.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np


def run(agent: str, mu: float, seed: int, episodes: int, particles: int, out: Path) -> dict:
    cmd = [sys.executable, "-m", "coordinator.cli", "run", "--domain", "chute", "--agent", agent,
           "--truth", f"friction={mu:g}", "--episodes", str(episodes), "--particles", str(particles),
           "--seed", str(seed), "--no-progress", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return json.loads((out / "result.json").read_text())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--truths", default="0.21,0.33,0.45,0.57,0.69", help="friction truths (the prior is [0.15, 0.75])")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--episodes", type=int, default=6)
    ap.add_argument("--particles", type=int, default=16)
    args = ap.parse_args(argv)
    truths = [float(t) for t in args.truths.split(",")]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for mu in truths:
            for seed in range(args.seeds):
                res = {a: run(a, mu, seed, args.episodes, args.particles, Path(tmp) / f"{a}-{mu}-{seed}")
                       for a in ("tmoc", "tmp_rl")}
                post = res["tmoc"]["summary"]["posterior"]["friction"]
                rows.append({"mu": mu, "seed": seed,
                             "tmoc": [e["utility"] for e in res["tmoc"]["episodes"]],
                             "tmp_rl": [e["utility"] for e in res["tmp_rl"]["episodes"]],
                             "mean": post["mean"], "std": post["std"]})
                r = rows[-1]
                print(f"friction {mu:.2f} seed {seed}: TMOC {np.mean(r['tmoc']):7.1f} {r['tmoc']}  "
                      f"TMP-RL {np.mean(r['tmp_rl']):7.1f} {r['tmp_rl']}  posterior {r['mean']:.3f} +- {r['std']:.3f}",
                      flush=True)
    tmoc = np.mean([np.mean(r["tmoc"]) for r in rows])
    tmp = np.mean([np.mean(r["tmp_rl"]) for r in rows])
    err = np.array([abs(r["mean"] - r["mu"]) for r in rows])
    z = np.array([abs(r["mean"] - r["mu"]) / max(r["std"], 1e-12) for r in rows])
    wins = sum(np.mean(r["tmoc"]) > np.mean(r["tmp_rl"]) for r in rows)
    ties = sum(np.mean(r["tmoc"]) == np.mean(r["tmp_rl"]) for r in rows)
    print(f"\nmean utility per episode: TMOC {tmoc:.1f}, TMP-RL {tmp:.1f}, difference {tmoc - tmp:+.1f} "
          f"(TMOC ahead in {wins}, tied in {ties} of {len(rows)} runs)")
    print(f"first episode: TMOC {np.mean([r['tmoc'][0] for r in rows]):.1f}, TMP-RL "
          f"{np.mean([r['tmp_rl'][0] for r in rows]):.1f}")
    print(f"posterior |error|: mean {err.mean():.3f}, max {err.max():.3f} (friction); within 2 std "
          f"in {int((z <= 2).sum())} of {len(rows)}; max {z.max():.1f} std")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
