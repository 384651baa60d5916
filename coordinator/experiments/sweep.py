"""The learning-quality sweep (issue 24): hidden truths spanning the whole prior, each
judged against the optimum under its own T*.

A sweep's settings are truths, not agents: block sizes evenly over the prior of the size
(bin centres, so neither bound nor the prior mean is favoured: 7 sizes by default, 13 at
paper scale), a few per-block cases (``sizes_variation``: one block 20 % larger) and, for a
domain that can put the density in L, a size x density x wrist-sensor grid. Every truth
gets T* from probes at that truth (``Setting.t_star``), so "optimal" means optimal for the
objects the robot is really handling.

Per run: utility per episode against the expected utility of the optimum under T* (plus
the all-delivered bonus, which the planner's figure leaves out and an episode's includes),
regret over the last half of the episodes, the episode from which it stays within
``NEAR_OPTIMUM`` of the optimum, failures and transit fallbacks per episode, and every
property's posterior error in units of its std. Summary: the share of truths within
``NEAR_OPTIMUM`` by episode ``BY_EPISODE``, coverage (the share of true values inside the
posterior's +- 2 std), the truths whose utility does not improve, and the worst truth.

Tails (issue 37): with several seeds per truth every run is also judged on its own
(``tails.run_tails``, from its step records ``runs/<key>/<r>.steps.jsonl`` and its run
file): regret per episode, the longest run of failed attempts of one action (only its
success ends it), whether
it loops (that run >= ``LOOP_RUN``) or never improves, |z| per entry of L. The summary's
``tails`` gives their distributions over runs (median, p90, worst), the shares that loop,
never improve or are near the optimum by episode ``BY_EPISODE``, and calibration (coverage,
mean z^2, median and p90 |z|); a run without step records (a sweep from before they were
kept) has no failure figures (None). An exact-posterior reference per run (``references``
of ``write_sweep``) adds sharpness: posterior std over the reference's.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np


from .tails import (LOOP_RUN, TAIL_BY_EPISODE, TAIL_COVERAGE_Z, TAIL_NEAR_OPTIMUM, _default_truths,  # noqa: F401
                    _z, read_steps, run_tails, steps_path, summarize_tails, true_row)
from .spec import Setting, Spec
from .runfiles import run_path, write_atomic
from .true_T import Optimality, t_star_files

NEAR_OPTIMUM = TAIL_NEAR_OPTIMUM   # utility: "within 30 of the T*-optimum" (the aim)
BY_EPISODE = TAIL_BY_EPISODE       # ... by this episode (1-based)
COVERAGE_Z = TAIL_COVERAGE_Z       # a true value within +- 2 posterior std is covered
SIZE_COUNTS = {"default": 7, "paper": 13}
# Per-block truths (index into the sizes) and the density grid, per scale.
VARIATION_AT = {"default": (2,), "paper": (1, 6, 11)}
DENSITY_GRID = {"default": ((3,), (900.0, 2200.0), (0.1, 3.5)),
                "paper": ((1, 6, 11), (600.0, 1400.0, 2200.0), (0.1, 3.5))}
SWEEP_PROBE_TRIALS = 10    # per T* probe (default scale): 14 truths' T* in ~8 CPU-min


def prior_sizes(low: float, high: float, count: int) -> list[float]:
    """`count` sizes at the centres of equal bins of [low, high], rounded to 0.1 mm.

    >>> [round(s * 1000, 1) for s in prior_sizes(0.030, 0.060, 7)]
    [32.1, 36.4, 40.7, 45.0, 49.3, 53.6, 57.9]
    """
    return [round(low + (i + 0.5) * (high - low) / count, 4) for i in range(count)]


def _mm(size: float) -> str:
    return f"{size * 1000:.1f}"


def sweep_settings(domain: str, scale: str = "default") -> list[Setting]:
    """The truths of `domain`'s sweep at `scale` ("default" or "paper")."""
    from ..domains import load, options_of

    phys = load(domain).physics
    L = phys.L
    low, high = L.bounds(1, False)
    sizes = prior_sizes(float(low[0]), float(high[0]), SIZE_COUNTS[scale])
    if L.names[0] != "size":
        return _property_settings(domain, L.names[0], sizes)
    out = [Setting(f"sweep-{domain}-{_mm(s)}mm", f"{_mm(s)} mm", {"agent": "tmoc", "true_size": s},
                   {"true_size": s}) for s in sizes]
    for i in VARIATION_AT[scale]:
        s = sizes[i]
        out.append(Setting(f"sweep-{domain}-{_mm(s)}mm-perblock", f"{_mm(s)} mm, per block",
                           {"agent": "tmoc", "true_size": s, "sizes_variation": True},
                           {"true_size": s}))
    if "unknown_density" in options_of(phys):
        at, densities, sigmas = DENSITY_GRID[scale]
        for i in at:
            s = sizes[i]
            for d in densities:
                for sg in sigmas:
                    out.append(Setting(
                        f"sweep-{domain}-{_mm(s)}mm-rho{d:g}-sigma{sg:g}", f"{_mm(s)} mm, {d:g} kg/m3, {sg:g} N",
                        {"agent": "tmoc", "true_size": s, "truth": {"density": d},
                         "options": {"unknown_density": True, "force_sigma": sg}},
                        {"true_size": s, "options": {"density": d, "force_from_mass": True}}))
    return out


def _property_settings(domain: str, name: str, values: list[float]) -> list[Setting]:
    """A domain whose L has no size: truths of its first property over the prior. The run
    takes it as ``truth``; its T* probes as the physics spec's ``true_<name>`` option (the
    kit's convention for a property's default truth)."""
    return [Setting(f"sweep-{domain}-{name}{v:g}", f"{name} {v:g}", {"agent": "tmoc", "truth": {name: v}},
                    {"options": {f"true_{name}": v}}) for v in values]


# ----------------------------------------------------------------------------- analysis
def judge_run(data: dict, optimum: float | None) -> dict:
    """One run's figures against the optimum's expected utility under its T* (None: not
    judged against an optimum, e.g. per-block truths, whose T* is probed with equal blocks)."""
    eps = data["episodes"]
    u = [float(e["utility"]) for e in eps]
    entries = true_row(data["config"], eps[-1]["posterior"])
    zs = [_z(t, m, s) for _, _, t, m, s in entries]
    out = {
        "utility": u, "optimum": optimum,
        "failures": [int(sum(e["failures"].values())) for e in eps],
        "fallbacks": [int(e.get("transit_fallbacks", 0)) for e in eps],
        "delivered": [int(e.get("delivered", 0)) for e in eps],
        "posterior": [{"property": p, "block": b, "truth": t, "mean": m, "std": s, "z": _z(t, m, s)}
                      for p, b, t, m, s in entries],
        "z_max": float(max(zs)) if zs else 0.0,
        "covered": int(sum(z <= COVERAGE_Z for z in zs)), "entries": len(zs),
    }
    if optimum is None:
        # No optimum to be near: only "got worse" counts as not improving.
        out.update(regret_last=None, near_optimum_by=None, episodes_to_converge=None,
                   not_improving=bool(len(u) > 1 and u[-1] < u[0]))
        return out
    near = [x >= optimum - NEAR_OPTIMUM for x in u]
    by = min(BY_EPISODE, len(u))
    out.update(
        regret_last=optimum - float(np.mean(u[len(u) // 2:])),
        near_optimum_by=bool(all(near[by - 1:])),
        episodes_to_converge=next((i + 1 for i in range(len(u)) if all(near[i:])), None),
        # Not improving: still short of the optimum at the end, and no better than at first
        # (undefined for a single episode).
        not_improving=bool(len(u) > 1 and not near[-1] and u[-1] <= u[0]))
    return out


def entry_key(name: str, block: int | None) -> str:
    """An entry of L by name: the property's, or ``name[b]`` for block b's own."""
    return name if block is None else f"{name}[{block}]"


def tails_of(data: dict, optimum: float | None, steps: list[dict] | None,
             reference: dict | None = None) -> dict:
    """``tails.run_tails`` of a run file's run (its step records `steps`, None if it kept
    none), its entries of L keyed by ``entry_key``; `reference`: the exact posterior's
    {"mean", "std"} per entry, keyed alike (optional)."""
    entries = true_row(data["config"], data["episodes"][-1]["posterior"])
    truth = {entry_key(p, b): t for p, b, t, _, _ in entries}
    post = {entry_key(p, b): {"mean": m, "std": s} for p, b, _, m, s in entries}
    return run_tails(steps, data["episodes"], optimum, truth, post, reference)


def sweep_rows(spec: Spec, out: Path, t_stars: dict, references: dict | None = None) -> list[dict]:
    """One judged row per (truth, run), in setting order; each with its ``tails``
    (``tails_of``). `references`: {(setting key, run): the exact posterior per entry of L}
    for the runs that have one (the exact-posterior judge's hook: sharpness)."""
    from ..domains import task_half

    files = t_star_files(spec)
    costs = dict(task_half(spec.domain).default_costs)
    rows = []
    for s in spec.settings:
        for r in range(spec.runs):
            t_star = t_stars[files[(s.key, r)][0]]
            # The planner's expected utility leaves out the all-delivered bonus (every
            # complete plan earns it alike); an episode's utility includes it.
            optimum = Optimality(t_star["transition"], costs, t_star["params"]["n_blocks"],
                                 spec.domain).best_value + costs.get("all_delivered", 0.0)
            data = json.loads(run_path(out, s, r).read_text())
            if data["config"]["sizes_variation"]:       # T* is probed with equal blocks
                optimum = None
            first = true_row(data["config"], data["episodes"][-1]["posterior"])[0]
            row = {"domain": spec.domain, "case": s.label, "key": s.key, "run": r, "seed": data["seed"],
                   "true_size": data["config"]["true_size"], "truth_name": first[0], "truth_value": first[2],
                   "t_star": t_star["transition"]}
            row.update(judge_run(data, optimum))
            row["tails"] = tails_of(data, optimum, read_steps(steps_path(out, s, r)),
                                    (references or {}).get((s.key, r)))
            rows.append(row)
    return rows


def summarize_sweep(rows: list[dict]) -> dict:
    """The sweep's summary lines (see the module docstring); the optimum's figures over the
    truths judged against one (per-block truths are not: their T* is for equal blocks)."""
    n = len(rows)
    judged = [r for r in rows if r["optimum"] is not None]
    covered = sum(r["covered"] for r in rows)
    entries = sum(r["entries"] for r in rows)
    worst = max(judged, key=lambda r: r["regret_last"]) if judged else None
    worst_z = max(rows, key=lambda r: r["z_max"]) if rows else None
    with_tails = [r for r in rows if r.get("tails") is not None]
    return {
        "truths": n, "judged": len(judged),
        f"near_optimum_by_episode_{BY_EPISODE}":
            sum(r["near_optimum_by"] for r in judged) / len(judged) if judged else None,
        "coverage": covered / entries if entries else None,
        "truths_covered": sum(r["covered"] == r["entries"] for r in rows) / n if n else None,
        "not_improving": [f"{r['case']} (run {r['run']})" for r in rows if r["not_improving"]],
        "mean_regret_last": float(np.mean([r["regret_last"] for r in judged])) if judged else None,
        "worst_regret": None if worst is None else
        {"case": worst["case"], "run": worst["run"], "regret_last": worst["regret_last"],
         "utility": worst["utility"], "optimum": worst["optimum"]},
        "worst_z": None if worst_z is None else
        {"case": worst_z["case"], "run": worst_z["run"], "z_max": worst_z["z_max"]},
        "fallbacks_per_episode": float(np.mean([np.mean(r["fallbacks"]) for r in rows])) if n else None,
        "aims": {"near_optimum_share": 0.9, "coverage": 0.9, "not_improving": 0},
        # Distributions over runs (issue 37); None for rows judged before tails were.
        "tails": summarize_tails([r["tails"] for r in with_tails],
                                 [f"{r['case']} (run {r['run']})" for r in with_tails]) if with_tails else None,
    }


# ----------------------------------------------------------------------------- report
def _cell(v, digits: int = 0) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def sweep_table(rows: list[dict], summary: dict) -> str:
    """Markdown: one line per truth and run, then the summary lines."""
    # The longest failure run's column where rows were judged with tails (issue 37; the
    # committed tables from before keep their columns).
    loops = any("tails" in r for r in rows)
    lines = ["| domain | truth | run | utility per episode | optimum | regret (last half) | converged at |"
             " failures/ep |" + (" longest failure run |" if loops else "")
             + " fallbacks/ep | error/std (max) | covered |",
             "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if loops else "")]
    for r in rows:
        loop = f" {_loop_cell(r.get('tails') or {})} |" if loops else ""
        lines.append(
            f"| {r['domain']} | {r['case']} | {r['run']} | {', '.join(f'{x:.0f}' for x in r['utility'])} "
            f"| {_cell(r['optimum'])} | {_cell(r['regret_last'])} | {_cell(r['episodes_to_converge'])} "
            f"| {np.mean(r['failures']):.1f} |{loop} {np.mean(r['fallbacks']):.1f} "
            f"| {r['z_max']:.1f} | {r['covered']}/{r['entries']} |")
    s = summary
    key = f"near_optimum_by_episode_{BY_EPISODE}"
    lines += ["", f"- within {NEAR_OPTIMUM:g} of the T*-optimum by episode {BY_EPISODE}: "
                  f"{_pct(s[key])} of {s.get('judged', s['truths'])} truths judged (aim 90 %; per-block "
                  "truths are not: T* is probed with equal blocks)",
              f"- coverage (true value within +-{COVERAGE_Z:g} posterior std): {_pct(s['coverage'])} "
              f"of the entries of L; every entry covered in {_pct(s['truths_covered'])} of the truths "
              "(aim 90 %)",
              f"- not improving from episode 1 to the last: {len(s['not_improving'])} "
              f"({', '.join(s['not_improving']) or 'none'}) (aim 0)",
              f"- mean regret over the last half: {_cell(s['mean_regret_last'], 1)}; transit fallbacks "
              f"per episode: {_cell(s['fallbacks_per_episode'], 2)}"]
    if s["worst_regret"]:
        w = s["worst_regret"]
        lines.append(f"- worst truth: {w['case']} (run {w['run']}), regret {w['regret_last']:.0f} "
                     f"(utility {', '.join(f'{x:.0f}' for x in w['utility'])}, optimum {w['optimum']:.0f})")
    if s["worst_z"]:
        lines.append(f"- worst posterior: {s['worst_z']['case']}, {s['worst_z']['z_max']:.1f} std off")
    if s.get("tails"):
        lines += tails_lines(s["tails"])
    return "\n".join(lines) + "\n"


def _loop_cell(tails: dict) -> str:
    n = tails.get("longest_failure_run")
    if n is None:
        return "-"
    return f"{n} ({tails['longest_failure_run_action']}, loops)" if tails.get("loops") else str(n)


def _dist(d: dict | None, digits: int = 0) -> str:
    return "-" if d is None else f"{d['median']:.{digits}f} / {d['p90']:.{digits}f} / {d['worst']:.{digits}f}"


def _failure_run_words(t: dict) -> str:
    """What the summary's failure runs count, as its own definitions say: a summary made
    before only an action's success ended its run counted back-to-back failures."""
    loops = t.get("definitions", {}).get("loops", "")
    return "back-to-back failures" if "back-to-back" in loops else "failed attempts"


def tails_lines(t: dict) -> list[str]:
    """The summary's tails as markdown list lines (over runs, not truths)."""
    out = ["", f"Tails over {t['runs']} runs ({t['runs_with_steps']} with step records):",
           f"- regret at the last episode, median / p90 / worst: {_dist(t['regret_last_episode'])}",
           f"- longest run of {_failure_run_words(t)} of one action, median / p90 / worst: "
           f"{_dist(t['longest_failure_run'])}",
           f"- runs that loop (>= {LOOP_RUN} such failures): {_pct(t['loop_share'])}"
           + (f" ({', '.join(t['loops'])})" if t["loops"] else ""),
           f"- runs that never improve on episode 1: {_pct(t['never_improves_share'])}"
           + (f" ({', '.join(t['never_improves'])})" if t["never_improves"] else ""),
           f"- runs within {NEAR_OPTIMUM:g} of the optimum by episode {BY_EPISODE}: "
           f"{_pct(t[f'near_optimum_by_episode_{BY_EPISODE}_share'])}",
           f"- calibration over {t['z_entries']} entries of L: coverage (|z| <= {COVERAGE_Z:g}) "
           f"{_pct(t['coverage'])}, mean z^2 {_cell(t['mean_z2'], 2)}, median |z| {_cell(t['median_abs_z'], 2)}, "
           f"p90 |z| {_cell(t['p90_abs_z'], 2)}"]
    if t.get("worst_loop") and t["worst_loop"]["length"]:
        w = t["worst_loop"]
        out.append(f"- longest failure run: {w['run']}, {w['action']} failed {w['length']} times in a row "
                   f"in episode {w['episode'] + 1}")
    if t.get("sharpness"):
        sh = t["sharpness"]
        le = next(k for k in sh if k.startswith("share_le_"))
        out.append(f"- sharpness (posterior std / exact posterior's) over {sh['n']} entries: median "
                   f"{sh['median']:.2f}, p90 {sh['p90']:.2f}, within {le.removeprefix('share_le_')}x: {_pct(sh[le])}")
    return out


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def plot_sweep(rows: list[dict], path: Path) -> None:
    """Regret and the posterior's error/std against the true size, one marker per case kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4))
    kinds = {"sizes": lambda r: "per block" not in r["case"] and "kg/m3" not in r["case"],
             "per block": lambda r: "per block" in r["case"], "density grid": lambda r: "kg/m3" in r["case"]}
    if rows and rows[0].get("truth_name", "size") != "size":
        kinds = {"truths": lambda r: True}
    for (label, pick), marker in zip(kinds.items(), "o^s"):
        sel = [r for r in rows if pick(r)]
        if not sel:
            continue
        x = [_x(r) for r in sel]
        judged = [r for r in sel if r["regret_last"] is not None]
        a.scatter([_x(r) for r in judged], [r["regret_last"] for r in judged],
                  marker=marker, label=label)
        b.scatter(x, [min(r["z_max"], 20.0) for r in sel], marker=marker, label=label)
    a.axhline(NEAR_OPTIMUM, color="grey", ls="--", lw=1)
    xlabel = "true block size (mm)" if rows[0].get("truth_name", "size") == "size" \
        else f"true {rows[0]['truth_name']}"
    a.set(xlabel=xlabel, ylabel="regret over the last half (utility)",
          title="regret against the T*-optimum")
    a.set_yscale("symlog", linthresh=50)
    b.axhline(COVERAGE_Z, color="grey", ls="--", lw=1)
    b.set(xlabel=xlabel, ylabel="|error| / posterior std (max over L, capped at 20)",
          title="posterior calibration")
    a.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _x(row: dict) -> float:
    """The truth on the plot's axis: the size in mm, else the first property as it is."""
    if row.get("truth_name", "size") == "size":
        return 1000 * row["true_size"]
    return row["truth_value"]


def reference_path(out: Path, setting: Setting, r: int) -> Path:
    """Where run `r`'s exact-posterior reference is kept: beside its run file."""
    return Path(out) / "runs" / setting.key / f"{r}.reference.json"


def sweep_references(spec: Spec, out: Path, *, grid: int = 81, refine: str = "final",
                     progress=None) -> dict:
    """{(setting key, run): the exact posterior per entry of L} for every run of the sweep
    that has step records (``reference.reference_posterior``: each run re-filtered offline,
    its steps re-simulated for every row of an exact grid over the prior), cached as
    ``runs/<key>/<r>.reference.json`` and reused while its grid and refinement match: what
    ``write_sweep``'s `references` takes (the sharpness figures). `progress(line)` hears
    one line per run."""
    import shutil
    import tempfile

    from .reference import entries, reference_posterior

    found = {}
    for s in spec.settings:
        for r in range(spec.runs):
            steps, cache = steps_path(out, s, r), reference_path(out, s, r)
            if not steps.exists():
                continue
            ref = None
            if cache.exists():
                kept = json.loads(cache.read_text())
                if kept.get("grid") == grid and kept.get("refine") == refine:
                    ref = kept["reference"]
            if ref is None:
                # the reference reads a `tmoc run --out` directory: the run file and its steps
                with tempfile.TemporaryDirectory() as tmp:
                    shutil.copyfile(run_path(out, s, r), Path(tmp) / "result.json")
                    shutil.copyfile(steps, Path(tmp) / "steps.jsonl")
                    ref = _jsonable(reference_posterior(tmp, grid=grid, refine=refine))
                write_atomic(cache, json.dumps({"grid": grid, "refine": refine, "reference": ref}))
                if progress is not None:
                    progress(f"reference {s.key} run {r}: {ref['wall_s']:.0f} s")
            found[(s.key, r)] = entries(ref)
    return found


def _jsonable(value):
    """numpy arrays and scalars as lists and floats, recursively."""
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_sweep(spec: Spec, out: Path, t_stars: dict, references: dict | None = None) -> dict:
    """DIR/sweep.{json,csv,md,png} from the run files (and step records) and the truths'
    T*; `references` as ``sweep_rows``'s (the exact-posterior judge's, optional)."""
    import csv
    import io

    out = Path(out)
    rows = sweep_rows(spec, out, t_stars, references)
    summary = summarize_sweep(rows)
    paths = {"csv": out / "sweep.csv", "json": out / "sweep.json", "png": out / "sweep.png",
             "md": out / "sweep.md"}
    write_atomic(paths["json"], json.dumps({"spec": spec.to_dict(), "summary": summary, "rows": rows}, indent=1))
    buf = io.StringIO()
    cols = ["domain", "case", "run", "seed", "true_size", "optimum", "regret_last", "near_optimum_by",
            "episodes_to_converge", "not_improving", "z_max", "covered", "entries"]
    tail_cols = ["regret_last_episode", "longest_failure_run", "longest_failure_run_action", "loops",
                 "never_improves"]
    w = csv.writer(buf)
    w.writerow(cols + ["utility", "failures", "fallbacks"] + tail_cols)
    for r in rows:
        w.writerow([r[c] for c in cols] + [" ".join(f"{x:g}" for x in r[k])
                                           for k in ("utility", "failures", "fallbacks")]
                   + [r["tails"][c] for c in tail_cols])
    write_atomic(paths["csv"], buf.getvalue())
    write_atomic(paths["md"], sweep_table(rows, summary))
    plot_sweep(rows, paths["png"])
    return {k: str(v) for k, v in paths.items()}
