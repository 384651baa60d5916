"""Stack-and-push's push success by tower height across the prior (issue 24): towers built
by the agent's own actions (the ``built_push`` probe, T*'s), pushed by the real arm with
and without its per-push timing jitter (``push_time_jitter``). Prints one row per size
and the heights whose success lies strictly between 20 and 80 %: a graded trade-off
between fewer trips and a safe push at every size, or not.

    python benchmarks/bench_push_curve.py                       # 5 sizes x towers 4..8, 10 trials
    python benchmarks/bench_push_curve.py --sizes 32,58 --trials 20 --jitter 0.3
"""
from __future__ import annotations

import argparse
import time

from sim_workers.probe import probe

GRADED = (0.2, 0.8)


def curve(size_mm: float, heights: list[int], trials: int, jitter: float, seed: int) -> list[float]:
    """Push success per tower height at one true size (Y at the truth)."""
    return [probe("built_push", size_mm / 1000, load_k=k, trials=trials, seed=seed, domain="stack_and_push",
                  options={"push_time_jitter": jitter}).successes / trials for k in heights]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="32,38,45,52,58", help="true sizes in mm, comma-separated")
    ap.add_argument("--heights", default="4,5,6,7,8")
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--jitter", type=float, default=None, help="default: the domain's (0.3)")
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    sizes = [float(s) for s in args.sizes.split(",")]
    heights = [int(h) for h in args.heights.split(",")]
    from sim_workers.domains import load
    from sim_workers.reality_gap import action_jitter

    jitter = action_jitter(load("stack_and_push"), "push") if args.jitter is None else args.jitter
    print(f"| jitter | size (mm) | {' | '.join(f'tower {h}' for h in heights)} | graded heights | s |")
    print("|---|---|" + "---|" * len(heights) + "---|---|")
    graded_sizes = {}
    for j in (0.0, jitter):
        graded_sizes[j] = 0
        for s in sizes:
            t0 = time.perf_counter()
            rates = curve(s, heights, args.trials, j, args.seed)
            graded = [h for h, p in zip(heights, rates) if GRADED[0] < p < GRADED[1]]
            graded_sizes[j] += bool(graded)
            print(f"| {j:g} | {s:g} | {' | '.join(f'{p:.2f}' for p in rates)} | "
                  f"{', '.join(map(str, graded)) or '-'} | {time.perf_counter() - t0:.0f} |", flush=True)
    print(f"\nsizes with a graded height (strictly {GRADED[0]:g}..{GRADED[1]:g}): "
          f"nominal {graded_sizes[0.0]}/{len(sizes)}, jitter {jitter:g} {graded_sizes[jitter]}/{len(sizes)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
