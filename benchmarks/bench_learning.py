"""Learning quality over the whole prior (issue 24): `tmoc experiment sweep` for every
built-in domain in one run, the per-truth table and the summary lines.

For each domain, hidden truths spanning the prior (7 sizes at the default scale, 13 at
paper scale; per-block sizes; for stack-and-push a size x density x wrist-sensor grid),
each judged against the expected utility of the optimum under its own T* (probes at that
truth). The aims: within 30 utility of the optimum by episode 4 for at least 90 % of the
truths, no truth whose utility fails to improve, coverage (truth within +-2 posterior std)
of at least 90 %.

    python benchmarks/bench_learning.py                          # default scale, ~30-40 min on 2 cores
    python benchmarks/bench_learning.py --domains container --out runs/bl
    python benchmarks/bench_learning.py --scale paper            # the whole grid, 3 seeds, 8 episodes
    python benchmarks/bench_learning.py --before runs/bl-old     # side by side with an earlier sweep
    python benchmarks/bench_learning.py --engine mujoco --reality-engine pybullet --out runs/bl-x
        # the particles in one engine, reality in the other (issue 27's cross-engine sweep)
    python benchmarks/bench_learning.py --rejudge runs/bl-old --t-star-from runs/bl
        # an earlier sweep's runs judged again against another sweep's T* caches (no run)

Each domain's runs, T* caches and sweep.{md,json,csv,png} go to OUT/<domain>/; a run that
is there with the same settings is reused with --resume.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from coordinator import experiments as ex  # noqa: E402
from coordinator.commands.experiment import spec_from_args  # noqa: E402
from coordinator.experiments.sweep import BY_EPISODE  # noqa: E402
from coordinator.fanout import init_ray  # noqa: E402

SUMMARY_KEYS = (f"near_optimum_by_episode_{BY_EPISODE}", "coverage", "truths_covered", "mean_regret_last",
                "fallbacks_per_episode")


def sweep_args(domain: str, args) -> argparse.Namespace:
    """What `tmoc experiment sweep --domain D ...` would parse."""
    return argparse.Namespace(
        name="sweep", domain=domain, runs=args.runs, episodes=args.episodes, particles=args.particles,
        seed=args.seed, particle_budget=args.particle_budget, min_particles=8, scale=args.scale,
        max_steps=60, true_size=None, milestones=None, probe_trials=args.probe_trials, probe_seed=0,
        checkpoint_s=60.0, ray_address=None, out=None, resume=args.resume, no_progress=True,
        engine=args.engine, reality_engine=args.reality_engine)


def _fmt(v) -> str:
    if v is None:
        return "-"
    return f"{100 * v:.0f} %" if isinstance(v, float) and v <= 1.0 else f"{v:.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domains", default="container,stack_and_push")
    ap.add_argument("--scale", default="default", choices=("default", "paper"))
    ap.add_argument("--runs", type=int, default=None, help="seeds per truth (default: the scale's)")
    ap.add_argument("--episodes", type=int, default=None)
    ap.add_argument("--particles", type=int, default=None)
    ap.add_argument("--particle-budget", default="kld", choices=("fixed", "kld"),
                    help="as `tmoc run` (default kld, the service's default)")
    ap.add_argument("--probe-trials", type=int, default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--engine", default=None, help="the particle worlds' engine (default: pybullet)")
    ap.add_argument("--reality-engine", default=None,
                    help="the simulated reality's engine and T*'s (another than --engine's: a simulator "
                         "that is not reality)")
    ap.add_argument("--out", default="runs/bench_learning")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--before", default=None, metavar="DIR", help="an earlier OUT to compare with")
    ap.add_argument("--rejudge", default=None, metavar="DIR",
                    help="write DIR's sweep files again from its run files (no run) ...")
    ap.add_argument("--t-star-from", default=None, metavar="DIR",
                    help="... with the T* caches of this sweep (default: DIR's own)")
    args = ap.parse_args(argv)
    if args.rejudge:
        return rejudge(args)
    init_ray(None)
    out = Path(args.out)
    combined = {}
    for domain in [d.strip() for d in args.domains.split(",") if d.strip()]:
        spec = spec_from_args(sweep_args(domain, args))
        t0 = time.perf_counter()
        done = ex.execute(spec, out / domain, resume=args.resume, progress=False)
        data = json.loads(Path(done["json"]).read_text())
        combined[domain] = {"summary": data["summary"], "wall_s": time.perf_counter() - t0}
        print(f"## {domain}: {len(spec.settings)} truths x {spec.runs} run(s), {spec.episodes} episodes, "
              f"N <= {spec.particles} ({spec.particle_budget}), {time.perf_counter() - t0:.0f} s\n")
        print(Path(done["md"]).read_text())
    (out / "bench_learning.json").write_text(json.dumps(combined, indent=2))
    print("summary" + "".join(f" | {k}" for k in SUMMARY_KEYS) + " | not improving")
    for domain, c in combined.items():
        s = c["summary"]
        line = domain + "".join(f" | {_fmt(s[k])}" for k in SUMMARY_KEYS) + f" | {len(s['not_improving'])}"
        before = Path(args.before) / domain / "sweep.json" if args.before else None
        if before is not None and before.exists():
            b = json.loads(before.read_text())["summary"]
            line += "\n  before" + "".join(f" | {_fmt(b[k])}" for k in SUMMARY_KEYS) + \
                f" | {len(b['not_improving'])}"
        print(line)
    return 0


def rejudge(args) -> int:
    """Judge an earlier sweep's runs against T* caches (its own or another sweep's), so that
    a before/after comparison uses one reference."""
    from coordinator.experiments.sweep import write_sweep
    from coordinator.experiments.true_T import cached_true_T, t_star_files

    for domain in [d.strip() for d in args.domains.split(",") if d.strip()]:
        spec = spec_from_args(sweep_args(domain, args))
        out = Path(args.rejudge) / domain
        source = Path(args.t_star_from) / domain if args.t_star_from else out
        t_stars = {}
        for name, params in dict(t_star_files(spec).values()).items():
            t_stars[name] = cached_true_T(source, params, name)
            if t_stars[name] is None:
                raise SystemExit(f"bench_learning: no T* {name} in {source} for these settings")
        done = write_sweep(spec, out, t_stars)
        print(f"## {domain} (rejudged against {source})\n")
        print(Path(done["md"]).read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
