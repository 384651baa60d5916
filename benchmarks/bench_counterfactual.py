"""Counterfactual simulated experience on and off (issue 40), over truths across the prior.

Runs `benchmarks/bench_learning.py` twice on the same grid, truths and seeds (the runs'
seeds depend on the truth and the seed index only, so run r of a truth is paired across the
two): the paper's loop (``counterfactual_rows`` 0) and with M rows of counterfactual
experience per episode; the second reuses the first's T* caches. Then, per run and over
runs (median, mean, worst):

- real failures before the first episode within 30 utility of the T*-optimum (all of the
  run's failures if it never gets there), and over all episodes;
- cumulative regret over the episodes (optimum's expected utility minus the episode's);
- the compute the counterfactuals cost: world trials and wall seconds per episode, against
  the particle-actions of the loop itself.

    python benchmarks/bench_counterfactual.py                                   # the defaults below
    python benchmarks/bench_counterfactual.py --rows 8 --seeds 5 --episodes 6 --out runs/bcf
    python benchmarks/bench_counterfactual.py --set reality_fail=push:3 --out runs/bcf-gap
        # a reality gap the worlds cannot represent, both arms

Each arm's sweep is in OUT/off and OUT/on (with --resume, runs already there are reused);
the comparison is printed and written to OUT/counterfactual.json.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_learning  # noqa: E402

NEAR = 30.0            # "within 30 utility of the optimum", as the learning benchmark's aim


def run_figures(row: dict) -> dict:
    """One judged sweep row's figures: failures before the first near-optimal episode (all
    failures if none is), all failures, cumulative regret."""
    u, fails, opt = row["utility"], row["failures"], row["optimum"]
    first = next((i for i, x in enumerate(u) if x >= opt - NEAR), None)
    before = sum(fails) if first is None else sum(fails[:first])
    return {"failures_before_near": int(before), "reached_near": first is not None,
            "failures": int(sum(fails)), "cumulative_regret": float(sum(opt - x for x in u))}


def _runs(out: Path, domain: str) -> dict:
    data = json.loads((out / domain / "sweep.json").read_text())
    return {(r["key"], r["run"]): r for r in data["rows"]}


def _cost(out: Path, domain: str) -> dict:
    """World trials and seconds of the counterfactuals, and the loop's particle-actions, per
    episode over every run file."""
    trials, secs, pacts, eps = 0, 0.0, 0, 0
    for path in (out / domain / "runs").glob("*/*.json"):
        for e in json.loads(path.read_text())["episodes"]:
            trials += int(e.get("counterfactual_trials", 0))
            secs += float(e.get("counterfactual_s", 0.0))
            pacts += int(e["particle_actions"])
            eps += 1
    eps = max(eps, 1)
    return {"counterfactual_trials_per_episode": trials / eps, "counterfactual_s_per_episode": secs / eps,
            "particle_actions_per_episode": pacts / eps}


def _stats(values: list[float]) -> dict:
    v = np.asarray(values, dtype=np.float64)
    return {"median": float(np.median(v)), "mean": float(np.mean(v)), "worst": float(np.max(v))}


def compare(out: Path, domain: str) -> dict:
    off, on = _runs(out / "off", domain), _runs(out / "on", domain)
    keys = sorted(set(off) & set(on))
    figs = {arm: [run_figures(rows[k]) for k in keys] for arm, rows in (("off", off), ("on", on))}
    summary = {"runs": len(keys)}
    for arm in ("off", "on"):
        f = figs[arm]
        summary[arm] = {
            "failures_before_near": _stats([x["failures_before_near"] for x in f]),
            "failures": _stats([x["failures"] for x in f]),
            "cumulative_regret": _stats([x["cumulative_regret"] for x in f]),
            "reached_near_share": float(np.mean([x["reached_near"] for x in f])),
            **_cost(out / arm, domain)}
    per_run = [{"key": k[0], "run": k[1], "off": a, "on": b} for k, a, b in zip(keys, figs["off"], figs["on"])]
    return {"summary": summary, "runs": per_run}


def _share_t_star(src: Path, dst: Path) -> None:
    """The first arm's T* caches for the second (the same probes: it would re-run them)."""
    dst.mkdir(parents=True, exist_ok=True)
    for path in src.glob("true_T*"):
        target = dst / path.name
        if path.is_dir():
            shutil.copytree(path, target, dirs_exist_ok=True)
        elif not target.exists():
            shutil.copy2(path, target)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--domain", default="container")
    ap.add_argument("--rows", type=int, default=4, help="counterfactual rows per episode (default 4)")
    ap.add_argument("--truths", default="0,2,4,6", help="truths of the sweep's grid, by index")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--objects", type=int, default=6)
    ap.add_argument("--probe-trials", type=int, default=10, help="T*'s trials per context (default 10)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="both arms, as `tmoc run`'s")
    ap.add_argument("--out", default="runs/bench_counterfactual")
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args(argv)
    out = Path(args.out)
    common = ["--domains", args.domain, "--truths", args.truths, "--seeds", str(args.seeds),
              "--episodes", str(args.episodes), "--probe-trials", str(args.probe_trials),
              "--set", f"n_blocks={args.objects}"] + [x for s in args.set for x in ("--set", s)]
    if args.resume:
        common.append("--resume")
    bench_learning.main(common + ["--set", "counterfactual_rows=0", "--out", str(out / "off")])
    _share_t_star(out / "off" / args.domain, out / "on" / args.domain)
    bench_learning.main(common + ["--set", f"counterfactual_rows={args.rows}", "--out", str(out / "on")])
    result = compare(out, args.domain)
    (out / "counterfactual.json").write_text(json.dumps(result, indent=2))
    s = result["summary"]
    print(f"\n{args.domain}, {args.objects} objects, {s['runs']} runs, {args.episodes} episodes, "
          f"M = {args.rows} rows (median / mean / worst):")
    for key in ("failures_before_near", "failures", "cumulative_regret"):
        print(f"  {key:22s} off {s['off'][key]['median']:7.1f} / {s['off'][key]['mean']:7.1f} / "
              f"{s['off'][key]['worst']:7.1f}   on {s['on'][key]['median']:7.1f} / {s['on'][key]['mean']:7.1f} / "
              f"{s['on'][key]['worst']:7.1f}")
    print(f"  reached within {NEAR:g}: off {100 * s['off']['reached_near_share']:.0f} %, "
          f"on {100 * s['on']['reached_near_share']:.0f} %")
    print(f"  per episode: counterfactual trials {s['on']['counterfactual_trials_per_episode']:.0f} "
          f"({s['on']['counterfactual_s_per_episode']:.1f} s), loop particle-actions "
          f"{s['on']['particle_actions_per_episode']:.0f} (off {s['off']['particle_actions_per_episode']:.0f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
