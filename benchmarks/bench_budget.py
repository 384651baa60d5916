"""Fixed against adaptive (KLD) particle budgets, side by side in one run (issue 15).

The same task twice on local Ray (one shard actor per CPU), same seed and episodes: once
with `--particles P` for every action, once with `--particle-budget kld` (P the most,
`--min-particles` the floor). Per episode: particle-actions, wall seconds, utility and the
posterior error; then the ratios over the run:

    python benchmarks/bench_budget.py                      # container, P 100, 8 episodes
    python benchmarks/bench_budget.py --particles 32 --episodes 4 --quick-note
    python benchmarks/bench_budget.py --domain stack_and_push --option unknown_density=true \
        --truth size=0.040,density=2400 --particles 48 --episodes 6     # L = (size, density)
"""
from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from coordinator.commands.run import parse_options, parse_truth  # noqa: E402
from coordinator.run_config import RunConfig  # noqa: E402
from coordinator.loop.runner import run  # noqa: E402


def one(budget: str, args) -> tuple[list[dict], float]:
    cfg = RunConfig(domain=args.domain, particles=args.particles, episodes=args.episodes, seed=args.seed,
                    true_size=args.true_size, particle_budget=budget, min_particles=args.min_particles,
                    truth=parse_truth([args.truth]) if args.truth else {},
                    options=parse_options(args.option))
    t0 = time.perf_counter()
    res = run(cfg)
    return res["episodes"], time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domain", default="container")
    ap.add_argument("--particles", type=int, default=100)
    ap.add_argument("--min-particles", type=int, default=8)
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--true-size", type=float, default=0.034)
    ap.add_argument("--truth", default=None, metavar="NAME=VALUE[,...]", help="as on tmoc run")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="as on tmoc run")
    ap.add_argument("--quick-note", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.truth and "size" in parse_truth([args.truth]):
        args.true_size = parse_truth([args.truth])["size"]
    import ray

    out = {}
    for budget in ("fixed", "kld"):
        out[budget] = one(budget, args)
        ray.shutdown()          # the next run starts its own local Ray, as `tmoc run` does
    print(f"{args.domain}, P {args.particles}, floor {args.min_particles}, {args.episodes} episodes, "
          f"true size {args.true_size * 1000:.0f} mm, seed {args.seed}, {os.cpu_count()} CPUs")
    print("episode | particle-actions fixed / kld | wall s fixed / kld | utility fixed / kld | "
          "|size error| mm fixed / kld")
    (fx, fx_wall), (kl, kl_wall) = out["fixed"], out["kld"]
    for a, b in zip(fx, kl):
        err = lambda e: abs(e["posterior"]["size_mean"] - args.true_size) * 1000  # noqa: E731
        line = (f"{a['episode'] + 1:7d} | {a['particle_actions']:6d} / {b['particle_actions']:6d} | "
                f"{a['wall_s']:6.1f} / {b['wall_s']:6.1f} | {a['utility']:6.0f} / {b['utility']:6.0f} | "
                f"{err(a):5.2f} / {err(b):5.2f}")
        if "density" in (a["posterior"].get("properties") or {}):
            d = lambda e: e["posterior"]["properties"]["density"]  # noqa: E731
            line += (f" | density {d(a)['mean']:.0f}+-{d(a)['std']:.0f} / "
                     f"{d(b)['mean']:.0f}+-{d(b)['std']:.0f}")
        print(line)
    pa = sum(e["particle_actions"] for e in kl) / max(1, sum(e["particle_actions"] for e in fx))
    print(f"particle_actions_ratio={pa:.3f}  (kld / fixed over the run)")
    print(f"wall_ratio={kl_wall / fx_wall:.3f}  (whole runs, Ray start included: {kl_wall:.0f} s / {fx_wall:.0f} s)")
    print(f"final_utility fixed={fx[-1]['utility']:.0f} kld={kl[-1]['utility']:.0f}; "
          f"last kld episode {kl[-1]['wall_s']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
