"""The exact posterior as the judge of a recorded run (issue 37 item 2).

    python benchmarks/bench_reference.py RUN_DIR [--grid 81] [--refine all|final|none]
                                         [--draws 2000] [--out FILE] [--ray-address ADDR]
                                         [--symbolic declared|learned]

Re-filters a `tmoc run --out RUN_DIR` offline (coordinator/experiments/reference.py): every
recorded step re-simulated for every row of an exact grid over the prior of L (one
dimension; refined around the mass) or for prior draws (more), scored with the session's
likelihood under the run's declared settings. Prints the reference and the run's
posterior side by side with the scores (one line per property of L, then per episode) and
the verdict, and writes them as JSON (default RUN_DIR/reference.json). Bad input: one line
on stderr, exit 2.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from coordinator.experiments.reference import RefilterError, judge, load_run, reference_posterior, score


def _run_posterior(result: dict, episode: int) -> tuple[list, list] | None:
    """The run's (mean, std) per dimension of L after `episode` (None: no belief)."""
    eps = result.get("episodes") or []
    post = eps[episode].get("posterior", {}) if -len(eps) <= episode < len(eps) else {}
    return (post["mean"], post["std"]) if "mean" in post and "std" in post else None


def _jsonable(scores: dict) -> dict:
    return {k: [v.item() for v in value] for k, value in scores.items()}


def compare(ref: dict, result: dict) -> dict:
    """Scores and verdict of the run's final posterior, and each episode's scores."""
    final = _run_posterior(result, -1)
    if final is None:
        return {"final": None, "verdict": None, "episodes": []}
    s = score(*final, ref["mean"], ref["std"], ref["truth"], prior_std=ref["prior_std"])
    episodes = []
    for snap in ref["episodes"]:
        post = _run_posterior(result, snap["episode"])
        if post is not None:
            episodes.append({"episode": snap["episode"], "mean": post[0], "std": post[1], **_jsonable(
                score(*post, snap["mean"], snap["std"], ref["truth"], prior_std=ref["prior_std"]))})
    return {"mean": final[0], "std": final[1], "final": _jsonable(s), "verdict": judge(s), "episodes": episodes}


def report(ref: dict, cmp: dict) -> str:
    """The side-by-side table: one line per property of L, then one per episode."""
    lines = [f"reference: {ref['method']}, {ref['steps']} steps, {ref['wall_s']:.1f} s"]
    head = (f"{'property':<12} {'truth':>9} {'prior std':>9} {'reference':>21} {'run':>21} "
            f"{'z':>6} {'ref z':>6} {'cover':>5} {'log sc':>7} {'crps':>9} {'sharp':>6}")
    lines.append(head)
    for j, name in enumerate(ref["names"]):
        r = f"{ref['mean'][j]:.5g} +- {ref['std'][j]:.3g}"
        if cmp["final"] is None:
            lines.append(f"{name:<12} {ref['truth'][j]:>9.5g} {ref['prior_std'][j]:>9.3g} {r:>21} {'(no belief)':>21}")
            continue
        f = {k: v[j] for k, v in cmp["final"].items()}
        run = f"{cmp['mean'][j]:.5g} +- {cmp['std'][j]:.3g}"
        lines.append(f"{name:<12} {ref['truth'][j]:>9.5g} {ref['prior_std'][j]:>9.3g} {r:>21} {run:>21} "
                     f"{f['z']:>6.2f} {f['ref_z']:>6.2f} {str(f['covered']):>5} {f['log_score']:>7.2f} "
                     f"{f['crps']:>9.3g} {f['sharpness']:>6.2f}")
    for e in cmp["episodes"]:
        snap = ref["episodes"][e["episode"]]
        lines.append(f"episode {e['episode']:>3}: " + "; ".join(
            f"{name} ref {snap['mean'][j]:.5g} +- {snap['std'][j]:.3g}, run {e['mean'][j]:.5g} +- "
            f"{e['std'][j]:.3g}, z {e['z'][j]:.2f}, sharpness {e['sharpness'][j]:.2f}"
            for j, name in enumerate(ref["names"])))
    if cmp["verdict"] is not None:
        v = cmp["verdict"]
        lines.append("verdict: " + ("pass" if v["pass"] else "FAIL: " + "; ".join(v["reasons"])))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", help="a `tmoc run --out` directory")
    p.add_argument("--grid", type=int, default=81, help="cells of the 1-D grid and of each refinement")
    p.add_argument("--refine", default="all", help="all (every episode's snapshot) | final | none")
    p.add_argument("--draws", type=int, default=2000, help="prior draws when L has 2+ dimensions")
    p.add_argument("--seed", type=int, default=0, help="seed of the prior draws")
    p.add_argument("--out", default=None, help="the JSON to write (default RUN_DIR/reference.json)")
    p.add_argument("--ray-address", default=None, help="join a running Ray cluster")
    p.add_argument("--symbolic", default="declared",
                   help="declared (the run's match model) | learned (its error rate unknown per action "
                        "kind, marginalised per row)")
    args = p.parse_args(argv)
    out = Path(args.out) if args.out else Path(args.run_dir) / "reference.json"
    try:
        load_run(args.run_dir)                  # a run directory, or one line and exit 2
        if not out.parent.is_dir():
            raise RefilterError(f"--out: {out.parent} is not a directory")
        ref = reference_posterior(args.run_dir, grid=args.grid, refine=args.refine, draws=args.draws,
                                  seed=args.seed, ray_address=args.ray_address, symbolic=args.symbolic)
    except RefilterError as exc:
        print(f"bench_reference: error: {exc}", file=sys.stderr)
        return 2
    result = json.loads((Path(args.run_dir) / "result.json").read_text())
    cmp = compare(ref, result)
    print(report(ref, cmp))
    out.write_text(json.dumps({"reference": ref, "run": cmp, "run_dir": str(args.run_dir)}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
