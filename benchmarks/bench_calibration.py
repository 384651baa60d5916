"""Is the posterior over L calibrated? Small runs across the prior (issue 24).

Each case is one `tmoc run` (in-process particle worlds, no Ray: one core), and for every
property of L (every block's, under --sizes-variation) the final posterior's error in units
of its std, whether the truth lies within mean +- 2 std (coverage), the final utility and,
where the episode records have them, the informative / uninformative update counts:

    python benchmarks/bench_calibration.py --suite container --seeds 1 2 --out /tmp/cal.jsonl
    python benchmarks/bench_calibration.py --suite density --seeds 1
    python benchmarks/bench_calibration.py --suite variation --seeds 1
    python benchmarks/bench_calibration.py --table /tmp/cal.jsonl      # the table of a file
    python benchmarks/bench_calibration.py --compare before.jsonl after.jsonl --plot calibration.png

`--set KEY=VALUE` sets any RunConfig field for every case (e.g. to compare a setting);
cases already in the output file (same label and seed) are skipped, so a killed run resumes.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")

# (label, RunConfig fields) per suite; every case 16 particles (the kld budget's most).
SUITES: dict[str, list[tuple[str, dict]]] = {
    "container": [(f"container {s * 1000:.0f} mm", {"domain": "container", "true_size": s})
                  for s in (0.032, 0.040, 0.048, 0.056)],
    "density": [(f"s&p {s * 1000:.0f} mm {rho:.0f} kg/m3 {sig} N",
                 {"domain": "stack_and_push", "truth": {"size": s, "density": rho},
                  "options": {"unknown_density": True, "force_sigma": sig}})
                for sig in (0.1, 3.5) for s, rho in ((0.054, 900.0), (0.036, 2200.0))],
    "variation": [("container variation 34 mm", {"domain": "container", "true_size": 0.034,
                                                 "sizes_variation": True}),
                  ("s&p variation 40 mm", {"domain": "stack_and_push", "true_size": 0.040,
                                           "sizes_variation": True})],
}


def run_case(label: str, fields: dict, seed: int, args) -> dict:
    """One run; the per-dimension truth, posterior and episode figures as a JSON-able row."""
    from coordinator.distributed.fanout import ShardPool
    from coordinator.run_config import RunConfig
    from coordinator.loop.runner import run

    cfg = RunConfig(**{"particles": args.particles, "episodes": args.episodes, "seed": seed,
                       **fields, **args.set})
    truth = {}

    def keep_truth(record, session, checkpoint):
        truth["row"] = session.truth_row().tolist()
        truth["names"] = [n for n in session.L.names
                          for _ in range(session.n_blocks if session.per_block else 1)]

    t0 = time.perf_counter()
    pool = ShardPool(cfg.domain, {"n_blocks": cfg.n_blocks, **cfg.options}, n_shards=0)
    try:
        res = run(cfg, pool=pool, on_episode=keep_truth)
    finally:
        pool.close()
    eps = res["episodes"]
    post = eps[-1]["posterior"]
    return {"label": label, "seed": seed, "names": truth["names"], "truth": truth["row"],
            "mean": post["mean"], "std": post["std"],
            "identified": {k: v.get("identified") for k, v in post["properties"].items()},
            "utilities": [e["utility"] for e in eps], "failures": [e["failures"] for e in eps],
            "actions": [e["actions"] for e in eps],
            "informative": [e.get("informative_updates") for e in eps],
            "uninformative": [e.get("uninformative_updates") for e in eps],
            "rejuvenations": [e.get("rejuvenations") for e in eps],
            "particle_actions": res["runtime"]["particle_actions"],
            "wall_s": time.perf_counter() - t0, "set": args.set}


def z_scores(row: dict) -> list[tuple[str, float, float, float, float]]:
    """(name, truth, mean, std, |error| / std) per dimension."""
    out = []
    for name, t, m, s in zip(row["names"], row["truth"], row["mean"], row["std"]):
        out.append((name, t, m, s, abs(m - t) / s if s > 0 else float("inf")))
    return out


def table(rows: list[dict]) -> str:
    """Markdown: one line per run and property (sizes-variation runs: the worst block),
    then coverage within 2 std over every dimension of every run."""
    lines = ["| case | seed | property | truth | posterior mean +- std | abs error / std | final utility |",
             "|---|---|---|---|---|---|---|"]
    dims = covered = 0
    for row in rows:
        zs = z_scores(row)
        dims += len(zs)
        covered += sum(z <= 2.0 for *_, z in zs)
        for name in dict.fromkeys(n for n, *_ in zs):
            mine = [z for z in zs if z[0] == name]
            worst = max(mine, key=lambda z: z[4])
            _, t, m, s, z = worst
            scale, unit = (1000.0, "mm") if name == "size" else (1.0, "")
            tag = f"{name} (worst of {len(mine)})" if len(mine) > 1 else name
            lines.append(f"| {row['label']} | {row['seed']} | {tag} | {t * scale:.1f} | "
                         f"{m * scale:.1f} +- {s * scale:.1f} | {z:.1f} | {row['utilities'][-1]:.0f} |")
    lines.append(f"\ncoverage (truth within mean +- 2 std): {covered}/{dims} = {covered / max(dims, 1):.0%}")
    return "\n".join(lines)


def compare(before: list[dict], after: list[dict]) -> str:
    """Markdown: per case, seed and property (sizes-variation runs: the worst block and how
    many blocks are covered) the posterior and its error in stds before and after, the
    final utility (and the run's mean), then the coverage of each."""
    lines = ["| case | seed | property | truth | before: mean +- std (error / std) | after: mean +- std "
             "(error / std) | final utility (mean) before / after |", "|---|---|---|---|---|---|---|"]
    index = {(r["label"], r["seed"]): r for r in after}
    cov = {"before": [0, 0], "after": [0, 0]}
    for b in before:
        a = index.get((b["label"], b["seed"]))
        if a is None:
            continue
        cells = []
        for which, row in (("before", b), ("after", a)):
            zs = z_scores(row)
            cov[which][0] += sum(z <= 2.0 for *_, z in zs)
            cov[which][1] += len(zs)
            cells.append(zs)
        for name in dict.fromkeys(n for n, *_ in cells[0]):
            out = []
            for zs in cells:
                mine = [z for z in zs if z[0] == name]
                _, t, m, sd, z = max(mine, key=lambda z: z[4])
                scale = 1000.0 if name == "size" else 1.0
                covered = (f"; block of {t * scale:.1f}; {sum(z[4] <= 2 for z in mine)}/{len(mine)} within 2 std"
                           if len(mine) > 1 else "")
                out.append((t * scale, f"{m * scale:.1f} +- {sd * scale:.1f} ({z:.1f}{covered})"))
            many = len([z for z in cells[0] if z[0] == name]) > 1
            tag = f"{name} (worst block)" if many else name
            util = " / ".join(f"{r['utilities'][-1]:.0f} ({sum(r['utilities']) / len(r['utilities']):.0f})"
                              for r in (b, a))
            truth = "per block" if many else f"{out[0][0]:.1f}"
            lines.append(f"| {b['label']} | {b['seed']} | {tag} | {truth} | {out[0][1]} | {out[1][1]} | {util} |")
    pairs = [(b, index[(b["label"], b["seed"])]) for b in before if (b["label"], b["seed"]) in index]
    for k, (which, (c, n)) in enumerate(cov.items()):
        runs = [p[k] for p in pairs]
        final = sum(r["utilities"][-1] for r in runs) / max(len(runs), 1)
        mean = sum(sum(r["utilities"]) / len(r["utilities"]) for r in runs) / max(len(runs), 1)
        lines.append(f"\n{which}: coverage {c}/{n} = {c / max(n, 1):.0%}; over {len(runs)} runs final utility "
                     f"{final:.0f}, mean utility {mean:.0f}, particle-actions {sum(r['particle_actions'] for r in runs)}")
    return "\n".join(lines)


def plot(before: list[dict], after: list[dict], path: str) -> None:
    """Each truth's posterior error in stds before and after (log scale), the 2-std line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    index = {(r["label"], r["seed"]): r for r in after}
    labels, zb, za = [], [], []
    for b in before:
        a = index.get((b["label"], b["seed"]))
        if a is None:
            continue
        names = [n for n, *_ in z_scores(b)]
        for k, ((name, *_, z0), (*_, z1)) in enumerate(zip(z_scores(b), z_scores(a))):
            block = f" b{k % names.count(name) + 1}" if names.count(name) > 1 else ""
            labels.append(f"{b['label']} s{b['seed']} {name}{block}")
            zb.append(max(z0, 1e-2))
            za.append(max(z1, 1e-2))
    fig, ax = plt.subplots(figsize=(9, 0.16 * len(labels) + 1.5))
    y = range(len(labels))
    ax.scatter(zb, y, marker="x", color="tab:red", label="before")
    ax.scatter(za, y, marker="o", facecolors="none", edgecolors="tab:blue", label="after")
    ax.axvline(2.0, color="k", ls="--", lw=1, label="2 std")
    ax.set_xscale("log")
    ax.set_yticks(list(y), labels, fontsize=6)
    ax.set_xlabel("|posterior mean - truth| / posterior std")
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _setting(text: str) -> tuple[str, object]:
    key, _, value = text.partition("=")
    try:
        return key, json.loads(value)
    except ValueError:
        return key, value


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", choices=sorted(SUITES), action="append", default=[])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--particles", type=int, default=16)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a RunConfig field for every case (JSON value)")
    ap.add_argument("--only", default=None, help="only cases whose label contains this")
    ap.add_argument("--out", default=None, help="append one JSON line per run here")
    ap.add_argument("--table", default=None, metavar="FILE", help="print the table of FILE and exit")
    ap.add_argument("--compare", nargs=2, default=None, metavar=("BEFORE", "AFTER"),
                    help="print the before/after table of two files and exit")
    ap.add_argument("--plot", default=None, metavar="PNG", help="with --compare: the errors as a figure")
    args = ap.parse_args(argv)
    args.set = dict(_setting(s) for s in args.set)
    if args.compare:
        rows = [[json.loads(line) for line in Path(f).read_text().splitlines() if line] for f in args.compare]
        print(compare(*rows))
        if args.plot:
            plot(*rows, args.plot)
        return 0
    if args.table:
        print(table([json.loads(line) for line in Path(args.table).read_text().splitlines() if line]))
        return 0
    done = set()
    if args.out and Path(args.out).exists():
        done = {(r["label"], r["seed"]) for r in map(json.loads, Path(args.out).read_text().splitlines()) if r}
    rows = []
    for suite in args.suite:
        for label, fields in SUITES[suite]:
            if args.only and args.only not in label:
                continue
            for seed in args.seeds:
                if (label, seed) in done:
                    continue
                row = run_case(label, fields, seed, args)
                rows.append(row)
                print(json.dumps({k: row[k] for k in ("label", "seed", "utilities", "wall_s")}), flush=True)
                if args.out:
                    with open(args.out, "a") as fh:
                        fh.write(json.dumps(row) + "\n")
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
