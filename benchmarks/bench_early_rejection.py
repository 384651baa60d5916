"""The move's early rejection (docs/LOOP.md, "Early rejection"): whole runs with the move's
proposals screened step by step against the likelihood's bound (the default) and with every
proposal replayed over the whole window, on the same seeds.

    python benchmarks/bench_early_rejection.py [--cases container,chute,slide] [--episodes N]

Per case: particle-actions and wall time each way and their ratios, and whether the two
runs are the same run (utilities, posterior, particle rows: they must be, bit for bit; the
script exits 1 if not). The chute and the slide come from the checkout's examples
(`pip install -e docs/examples/tmoc-chute-domain`, `... tmoc-slide-domain`); a case whose
domain is not installed is skipped with a line saying so. Minutes on 2 cores.
"""
from __future__ import annotations

import argparse
import json
import time

from coordinator.domains import names
from coordinator.loop.runner import run
from coordinator.particle_filter import filter as pf
from coordinator.particle_filter import resample_move as rm
from coordinator.run_config import RunConfig

CASES = {
    # the quick start's task at the prior's large end, whose first grasps fail (the monitor fires)
    "container": dict(domain="container", true_size=0.0579, particles=16, seed=1),
    "chute": dict(domain="chute", truth={"friction": 0.6}, particles=8, seed=2),
    "slide": dict(domain="slide", truth={"friction": 0.2}, particles=16, seed=1),
}


def _full_replay(*args, step_bound=None, **kwargs):
    """``mh_move`` as it was before early rejection: every proposal over the whole window."""
    return rm.mh_move(*args, **kwargs)


def _one(cfg: RunConfig, screened: bool) -> tuple[dict, float]:
    pf.mh_move = rm.mh_move if screened else _full_replay
    try:
        t0 = time.perf_counter()
        result = run(cfg)
        return result, time.perf_counter() - t0
    finally:
        pf.mh_move = rm.mh_move


def _signature(result: dict) -> str:
    """What must not change: every episode's utility and posterior."""
    return json.dumps([(e["utility"], e["posterior"]) for e in result["episodes"]], sort_keys=True, default=str)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--episodes", type=int, default=3)
    args = ap.parse_args(argv)
    installed = set(names())
    same_everywhere = True
    print(f"bench_early_rejection: {args.episodes} episodes per run, the same seed each way")
    for name in args.cases.split(","):
        kw = CASES[name]
        if kw["domain"] not in installed:
            print(f"{name:10s} skipped: domain {kw['domain']!r} not installed")
            continue
        cfg = RunConfig(episodes=args.episodes, particle_budget="fixed", **kw)
        full, t_full = _one(cfg, screened=False)
        screened, t_screened = _one(cfg, screened=True)
        pa_full = full["runtime"]["particle_actions"]
        pa_screened = screened["runtime"]["particle_actions"]
        same = _signature(full) == _signature(screened)
        same_everywhere &= same
        print(f"{name:10s} particle-actions {pa_full:6d} -> {pa_screened:6d} (x{pa_full / pa_screened:.2f} fewer)  "
              f"wall {t_full:6.1f} s -> {t_screened:6.1f} s (x{t_full / t_screened:.2f})  "
              f"same run: {'yes' if same else 'NO'}")
    return 0 if same_everywhere else 1


if __name__ == "__main__":
    raise SystemExit(main())
