"""Learning quality over the whole prior (issues 24 and 37): `tmoc experiment sweep` for
every built-in domain in one run, the per-run table, the summary lines and the tails.

For each domain, hidden truths spanning the prior (7 sizes at the default scale, 13 at
paper scale; per-block sizes; for stack-and-push a size x density x wrist-sensor grid),
each run with several seeds (5 per truth at the default scale, 20 at paper scale; --seeds)
and judged against the expected utility of the optimum under its truth's T* (40 probe
trials per context at that truth by default, --probe-trials; probed once per truth and
shared by its seeds). The aims: within 30 utility of the optimum by episode 4 for at
least 90 % of the runs, none whose utility fails to improve, coverage (truth within +-2
posterior std) of at least 90 %.

Tails (issue 37), over runs, not truths, from each run's step records: the regret at the
last episode and the longest run of failed attempts of one action on one object, only its
success ending it (median, p90, worst); the shares of runs that loop (such a run >= 6), that never improve
on episode 1 (and did not start within 30 of the optimum) and that are within 30 of the
optimum by episode 4; calibration over every entry of L: coverage (|z| <= 2), mean z^2,
median and p90 |z|. They are in each domain's sweep.json (summary.tails, rows[].tails),
sweep.md and sweep.csv, and printed last.

    python benchmarks/bench_learning.py                          # default scale: 5 seeds per truth
    python benchmarks/bench_learning.py --domains container --out runs/bl
    python benchmarks/bench_learning.py --scale paper            # the whole grid, 20 seeds, 8 episodes
    python benchmarks/bench_learning.py --domains container --truths 0,4 --seeds 2 --episodes 2 \
        --particles 4 --probe-trials 2 --max-steps 12 --out runs/bl-smoke    # a smoke run (minutes)
    python benchmarks/bench_learning.py --before runs/bl-old     # side by side with an earlier sweep
    python benchmarks/bench_learning.py --engine mujoco --reality-engine pybullet --out runs/bl-x
        # the particles in one engine, reality in the other (issue 27's cross-engine sweep)
    python benchmarks/bench_learning.py --rejudge runs/bl-old --t-star-from runs/bl
        # an earlier sweep's runs judged again against another sweep's T* caches (no run)
    python benchmarks/bench_learning.py --rejudge runs/bl --reference
        # ... and each run against its exact posterior (re-filtered offline; sharpness)

Each domain's runs (with their step records, runs/<truth>/<r>.steps.jsonl), T* caches and
sweep.{md,json,csv,png} go to OUT/<domain>/; a run that is there with the same settings is
reused with --resume. --rejudge takes the seeds, scale and probe trials of the sweep it
rejudges (and of --t-star-from's) from their sweep.json unless flags say otherwise; a sweep
from before step records were kept has no failure figures (shown as -). --reference re-filters
each run offline on an exact grid over the prior (coordinator/experiments/reference.py; about
2 min of 2 cores per container run of 4 episodes), caches it as runs/<truth>/<r>.reference.json
and adds sharpness (posterior std over the exact posterior's: median, p90, share <= 1.5x).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

from coordinator import experiments as ex  # noqa: E402
from coordinator.commands.experiment import spec_from_args  # noqa: E402
from coordinator.experiments.tails import SHARP_RATIO  # noqa: E402
from coordinator.experiments.sweep import BY_EPISODE  # noqa: E402
from coordinator.distributed.fanout import init_ray  # noqa: E402

SUMMARY_KEYS = (f"near_optimum_by_episode_{BY_EPISODE}", "coverage", "truths_covered", "mean_regret_last",
                "fallbacks_per_episode")
SEEDS = {"default": 5, "paper": 20}       # seeds per truth (issue 37: the tails need several)
PROBE_TRIALS = 40                         # per probe context of T*, once per truth


def sweep_args(domain: str, args) -> argparse.Namespace:
    """What `tmoc experiment sweep --domain D ...` would parse."""
    return argparse.Namespace(
        name="sweep", domain=domain, runs=args.seeds, episodes=args.episodes, particles=args.particles,
        seed=args.seed, particle_budget=args.particle_budget, min_particles=8, scale=args.scale or "default",
        max_steps=args.max_steps, true_size=None, milestones=None, probe_trials=args.probe_trials, probe_seed=0,
        probe_perception=args.probe_perception or 0.0,
        checkpoint_s=60.0, ray_address=None, out=None, resume=args.resume, no_progress=True,
        engine=args.engine, reality_engine=args.reality_engine, run_fields=_run_fields(args))


def _run_fields(args) -> list[str]:
    """`--set` items, after `--filter before`'s (issue 24's filter as it ran before issue 37)."""
    items = []
    if getattr(args, "filter", "current") == "before":
        from coordinator.run_config import PRE_ISSUE_37_FILTER

        items = [f"{k}={json.dumps(v)}" for k, v in PRE_ISSUE_37_FILTER.items()]
    return items + list(getattr(args, "set", None) or [])


def _fmt(v, key: str = "") -> str:
    """A summary cell: a share as a percentage, any other figure as a number."""
    if v is None:
        return "-"
    return f"{v:.2f}" if key in ("mean_regret_last", "fallbacks_per_episode") else f"{100 * v:.0f} %"


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def _num(v, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def _dist(d: dict | None, digits: int = 0) -> str:
    return "-" if d is None else "/".join(f"{d[k]:.{digits}f}" for k in ("median", "p90", "worst"))


TAILS_HEADER = ("tails (over runs) | runs | regret, last episode (median/p90/worst) "
                "| longest failure run (median/p90/worst) | loop | never improve "
                f"| within 30 by episode {BY_EPISODE} | coverage | mean z^2 | median |z| | p90 |z| "
                f"| sharpness (median/p90/<= {SHARP_RATIO:g}x)")


def tails_line(t: dict | None) -> str:
    """One line of the tails table (a summary without tails: every cell -)."""
    if not t:
        return " | -" * 11
    sh = t.get("sharpness")
    sharp = "-" if not sh else f"{sh['median']:.2f}/{sh['p90']:.2f}/{_pct(sh[f'share_le_{SHARP_RATIO:g}'])}"
    return (f" | {t['runs']} | {_dist(t['regret_last_episode'])} | {_dist(t['longest_failure_run'])} "
            f"| {_pct(t['loop_share'])} | {_pct(t['never_improves_share'])} "
            f"| {_pct(t[f'near_optimum_by_episode_{BY_EPISODE}_share'])} | {_pct(t['coverage'])} "
            f"| {_num(t['mean_z2'])} | {_num(t['median_abs_z'])} | {_num(t['p90_abs_z'])} | {sharp}")


def _stored_spec(domain_dir: Path) -> dict:
    """The spec an earlier sweep was written with (its sweep.json), or {} if there is none."""
    path = Path(domain_dir) / "sweep.json"
    try:
        return json.loads(path.read_text()).get("spec") or {}
    except (OSError, ValueError):
        return {}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domains", default="container,stack_and_push")
    ap.add_argument("--scale", default=None, choices=("default", "paper"), help="(default: default)")
    ap.add_argument("--seeds", "--runs", dest="seeds", type=int, default=None,
                    help=f"seeds per truth (default {SEEDS['default']}, {SEEDS['paper']} at --scale paper; "
                         "--rejudge: the sweep's own)")
    ap.add_argument("--episodes", type=int, default=None)
    ap.add_argument("--particles", type=int, default=None)
    ap.add_argument("--max-steps", type=int, default=60, help="actions per episode at most (default 60)")
    ap.add_argument("--truths", default=None, metavar="I,J,...",
                    help="only these truths of each domain's grid, by index (their runs are the whole "
                         "grid's, seed for seed)")
    ap.add_argument("--particle-budget", default="kld", choices=("fixed", "kld"),
                    help="as `tmoc run` (default kld, the service's default)")
    ap.add_argument("--probe-trials", type=int, default=None,
                    help=f"T*'s probe trials per context (default {PROBE_TRIALS}; --rejudge: the T* "
                         "sweep's own)")
    ap.add_argument("--probe-perception", type=float, default=None, metavar="M",
                    help="T*'s probes plan from positions perceived with this std (m), as the runs' "
                         "robot does (e.g. 0.002; default 0: exact, the committed sweeps' judge; "
                         "--rejudge: the T* sweep's own)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--engine", default=None, help="the particle worlds' engine (default: pybullet)")
    ap.add_argument("--reality-engine", default=None,
                    help="the simulated reality's engine and T*'s (another than --engine's: a simulator "
                         "that is not reality)")
    ap.add_argument("--filter", default="current", choices=("current", "before"),
                    help="before: issue 24's filter as it ran before issue 37 (PRE_ISSUE_37_FILTER), "
                         "for a before/after on the same noisy reality")
    ap.add_argument("--set", action="append", default=None, metavar="KEY=VALUE",
                    help="a RunConfig field for every run (repeatable), e.g. sensor_noise=2")
    ap.add_argument("--out", default="runs/bench_learning")
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--before", default=None, metavar="DIR", help="an earlier OUT to compare with")
    ap.add_argument("--rejudge", default=None, metavar="DIR",
                    help="write DIR's sweep files again from its run files (no run) ...")
    ap.add_argument("--t-star-from", default=None, metavar="DIR",
                    help="... with the T* caches of this sweep (default: DIR's own)")
    ap.add_argument("--reference", action="store_true",
                    help="judge every run against its exact posterior too (each run re-filtered "
                         "offline on a grid over the prior, cached beside its run file): sharpness")
    ap.add_argument("--reference-grid", type=int, default=81, metavar="CELLS",
                    help="cells of the reference's grid and of its refinement (default 81)")
    args = ap.parse_args(argv)
    if args.rejudge:
        return rejudge(args)
    args.scale = args.scale or "default"
    if args.seeds is None:
        args.seeds = SEEDS[args.scale]
    if args.probe_trials is None:
        args.probe_trials = PROBE_TRIALS
    init_ray(None)
    out = Path(args.out)
    combined = {}
    for domain in [d.strip() for d in args.domains.split(",") if d.strip()]:
        spec = spec_from_args(sweep_args(domain, args))
        if args.truths:
            picked = [int(i) for i in args.truths.split(",") if i.strip()]
            # the grid's own run seeds: the subset's runs are the whole grid's, seed for seed
            spec.settings = [replace(spec.settings[i], seed_index=i) for i in picked]
        t0 = time.perf_counter()
        done = ex.execute(spec, out / domain, resume=args.resume, progress=False)
        if args.reference:
            done = _with_references(spec, out / domain, out / domain, args)
        data = json.loads(Path(done["json"]).read_text())
        combined[domain] = {"summary": data["summary"], "wall_s": time.perf_counter() - t0,
                            "seeds": spec.runs, "probe_trials": spec.probe_trials}
        print(f"## {domain}: {len(spec.settings)} truths x {spec.runs} seed(s), {spec.episodes} episodes, "
              f"N <= {spec.particles} ({spec.particle_budget}), T* from {spec.probe_trials} probe trials "
              f"per context, {time.perf_counter() - t0:.0f} s\n")
        print(Path(done["md"]).read_text())
    (out / "bench_learning.json").write_text(json.dumps(combined, indent=2))
    befores = {}
    for domain in combined:
        before = Path(args.before) / domain / "sweep.json" if args.before else None
        if before is not None and before.exists():
            befores[domain] = json.loads(before.read_text())["summary"]
    print("summary" + "".join(f" | {k}" for k in SUMMARY_KEYS) + " | not improving")
    for domain, c in combined.items():
        s = c["summary"]
        line = domain + "".join(f" | {_fmt(s[k], k)}" for k in SUMMARY_KEYS) + f" | {len(s['not_improving'])}"
        if domain in befores:
            b = befores[domain]
            line += "\n  before" + "".join(f" | {_fmt(b.get(k), k)}" for k in SUMMARY_KEYS) + \
                f" | {len(b.get('not_improving') or [])}"
        print(line)
    print("\n" + TAILS_HEADER)
    for domain, c in combined.items():
        line = domain + tails_line(c["summary"].get("tails"))
        if domain in befores:
            line += "\n  before" + tails_line(befores[domain].get("tails"))
        print(line)
    return 0


def _t_stars(spec, source: Path) -> dict:
    """The sweep's T* records from `source`'s caches (exit naming the one missing)."""
    from coordinator.experiments.true_T import cached_true_T, t_star_files

    t_stars = {}
    for name, params in dict(t_star_files(spec).values()).items():
        t_stars[name] = cached_true_T(source, params, name)
        if t_stars[name] is None:
            raise SystemExit(f"bench_learning: no T* {name} in {source} for these settings")
    return t_stars


def _with_references(spec, out: Path, source: Path, args) -> dict:
    """The sweep's files written again with every run's exact-posterior reference
    (``sweep.sweep_references``, computed once and cached per run): sharpness."""
    from coordinator.experiments.sweep import sweep_references, write_sweep

    refs = sweep_references(spec, out, grid=args.reference_grid, progress=print)
    return write_sweep(spec, out, _t_stars(spec, source), refs)


def rejudge(args) -> int:
    """Judge an earlier sweep's runs against T* caches (its own or another sweep's), so that
    a before/after comparison uses one reference."""
    from coordinator.experiments.sweep import write_sweep

    for domain in [d.strip() for d in args.domains.split(",") if d.strip()]:
        out = Path(args.rejudge) / domain
        source = Path(args.t_star_from) / domain if args.t_star_from else out
        # The rejudged sweep's own seeds and scale, the T* source's probe trials (each as
        # written in its sweep.json), unless a flag says otherwise; none: the experiment's
        # defaults, as this benchmark used before issue 37.
        own, src = _stored_spec(out), _stored_spec(source)
        a = argparse.Namespace(**vars(args))
        for key, stored in (("seeds", own.get("runs")), ("episodes", own.get("episodes")),
                            ("particles", own.get("particles")), ("scale", own.get("scale")),
                            ("probe_trials", src.get("probe_trials")),
                            ("probe_perception", src.get("probe_perception")),
                            ("reality_engine", src.get("reality_engine"))):
            if getattr(a, key) is None:
                setattr(a, key, stored)
        spec = spec_from_args(sweep_args(domain, a))
        if args.truths:
            spec.settings = [replace(spec.settings[int(i)], seed_index=int(i))
                             for i in args.truths.split(",") if i.strip()]
        if args.reference:
            done = _with_references(spec, out, source, args)
        else:
            done = write_sweep(spec, out, _t_stars(spec, source))
        print(f"## {domain} (rejudged against {source})\n")
        print(Path(done["md"]).read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
