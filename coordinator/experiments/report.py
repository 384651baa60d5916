"""An experiment's files: DIR/NAME.csv (one row per episode), DIR/NAME.json (the summary),
DIR/NAME.md (the summary as markdown tables, embedded in docs/RESULTS.md) and
DIR/NAME.png (the figure its catalogue entry names)."""
from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

import numpy as np

from .analysis import summarize, table_rows
from .catalogue import REGISTRY, WEIGHTS_TRUE_DENSITY, Spec
from .runfiles import write_atomic
from .true_T import Optimality, t_star_files

SYMLOG_ABOVE, SYMLOG_LINEAR = 1000.0, 200.0        # utility plot: symlog when curves span > 1000
CSV_COLUMNS = ("setting", "run", "episode", "seed", "agent", "particles", "utility", "actions",
               "failures", "delivered", "size_mean", "size_std", "size_error", "loads", "plan_loads",
               "optimal_plan", "success_rate", "particle_actions")


def write_csv(rows: list[dict], path: Path) -> None:
    """The episode rows as CSV (floats as repr: the file reproduces bit for bit)."""
    buf = io.StringIO()
    extra = [k for k in ("density_mean", "density_std", "density_error") if rows and k in rows[0]]
    w = csv.DictWriter(buf, fieldnames=[*CSV_COLUMNS, *extra], lineterminator="\n")
    w.writeheader()
    for row in rows:
        w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    write_atomic(path, buf.getvalue())


def plot(spec: Spec, arrays: dict, summary: dict, path: Path) -> None:
    """Draw the figure of `spec`'s catalogue entry into `path` (PNG, written atomically)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure = REGISTRY[spec.name].figure
    if figure == "milestone_bars":
        fig = _milestone_bars(plt, spec, summary["milestones"])
    else:
        fig = _curves(plt, spec, arrays, density=figure == "curves+density")
    fig.tight_layout()
    tmp = path.with_name(path.name + f".tmp{os.getpid()}.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)


def _milestone_bars(plt, spec: Spec, table: list[dict]):
    """% optimal plans and % successful actions per milestone span, as bars."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, key, title in ((axes[0], "optimal_plans_pct", "optimal plans"),
                           (axes[1], "successful_actions_pct", "successful actions")):
        rows = list(table)
        x = np.arange(len(rows))
        vals = [np.nan if t[key] is None else t[key] for t in rows]
        errs = [0.0 if t[key + "_std"] is None else t[key + "_std"] for t in rows]
        bars = ax.bar(x, vals, yerr=errs, capsize=3,
                      color="tab:blue" if "optimal" in key else "tab:green")
        ax.bar_label(bars, labels=["n/a" if np.isnan(v) else f"{v:.0f}" for v in vals],
                     padding=2, fontsize=8)
        ax.set_xticks(x, [str(t["episode"]) if t["from_episode"] == t["episode"]
                          else f"{t['from_episode']}-{t['episode']}" for t in rows])
        ax.set_ylim(0, 105)
        ax.set_xlabel("episodes")
        ax.set_ylabel("%")
        ax.set_title(f"{title} (mean ± std over runs)")
    fig.suptitle(f"milestones: TMOC, {spec.runs} runs, N = {spec.particles}, {truth_label(spec.to_dict())}")
    return fig


def _curves(plt, spec: Spec, arrays: dict, density: bool):
    """Utility and posterior error of L per episode (and of the density), mean ± std over runs."""
    fig, axes = plt.subplots(1, 3 if density else 2, figsize=(16 if density else 11, 3.8))
    ax1, ax2 = axes[0], axes[1]
    x = np.arange(1, spec.episodes + 1)
    for label, a in arrays.items():
        panels = [(ax1, a["utility"], 1.0), (ax2, a["size_err"], 1000.0)]
        if density:
            panels.append((axes[2], a["density_err"], 1.0))
        for ax, v, scale in panels:
            if np.all(np.isnan(v)):        # the density known: nothing to plot
                ax.plot([], [])
                continue
            m, s = v.mean(axis=0) * scale, v.std(axis=0) * scale
            line, = ax.plot(x, m, label=label, marker="o" if len(x) < 30 else None, ms=3)
            ax.fill_between(x, m - s, m + s, alpha=0.2, color=line.get_color())
    if density:
        axes[2].set_xlabel("episode")
        axes[2].set_ylabel("|density mean - truth| (kg/m^3)")
        axes[2].set_title("posterior error of the density", fontsize=10)
    ax1.set_xlabel("episode")
    ax1.set_ylabel("utility")
    ax1.set_title("utility (mean ± 1 std over runs)")
    means = np.concatenate([a["utility"].mean(axis=0) for a in arrays.values()])
    if np.ptp(means) > SYMLOG_ABOVE:
        # An agent that never grounds the blocks (TMP-RL off the prior mean) fails every
        # action of every episode, ~30x below the others: a linear axis flattens them.
        ax1.set_yscale("symlog", linthresh=SYMLOG_LINEAR)
        lo, hi = ax1.get_ylim()
        ticks = [t for t in (-1e5, -1e4, -1e3, -100, 0, 100, 1e3) if lo <= t <= hi]
        ax1.set_yticks(ticks, [f"{t:.0f}" for t in ticks])
        ax1.set_title(f"utility (mean ± 1 std; linear within ±{SYMLOG_LINEAR:.0f}, log beyond)",
                      fontsize=10)
    ax2.set_xlabel("episode")
    ax2.set_ylabel("|size mean - truth| (mm)")
    ax2.set_title("posterior error of L (agents without a belief: the prior mean's)", fontsize=10)
    from matplotlib.ticker import MaxNLocator

    for ax in axes:
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax1.legend(fontsize=8)
    fig.suptitle(f"{spec.name}: {spec.runs} runs x {spec.episodes} episodes, {truth_label(spec.to_dict())}"
                 + (f", density {WEIGHTS_TRUE_DENSITY:.0f} kg/m^3" if density else ""))
    return fig


def truth_label(spec: dict) -> str:
    """"true size 34 mm", or the runs' sizes across the prior."""
    if spec.get("truths"):
        return "true sizes " + ", ".join(f"{t * 1000:.1f}" for t in spec["truths"]) + " mm (one per run)"
    return f"true size {spec['true_size'] * 1000:.0f} mm"


def _fmt(v, digits: int = 1, unit: str = "") -> str:
    return "n/a" if v is None else f"{v:.{digits}f}{unit}"


def summary_table(summary: dict) -> str:
    """The summary as a markdown table (one row per setting; `milestones` adds its bars as a
    second table). DIR/NAME.md holds it, and docs/RESULTS.md embeds it verbatim."""
    from ..agents import agent

    if "rows" in summary:                  # the sweep's DIR/sweep.json: its own table
        from .sweep import sweep_table

        return sweep_table(summary["rows"], summary["summary"])
    spec = summary["spec"]
    optima = summary["optimum_under_true_T"]
    if isinstance(optima, list):       # one truth per run
        best = "optimum under T* per truth: " + "; ".join(
            f"{'+'.join(map(str, o['loads']))} (expected utility {o['expected_utility']:.1f})" for o in optima)
    else:
        best = (f"optimum under T*: {'+'.join(map(str, optima['loads']))} "
                f"(expected utility {optima['expected_utility']:.1f}")
    lines = [f"`{summary['experiment']}`: {spec['runs']} runs x {spec['episodes']} episodes, "
             f"{truth_label(spec)}, seed {spec['seed']}; {best}"
             f"{'; ' if isinstance(optima, list) else ', '}without "
             f"the all-delivered bonus that every complete plan earns alike{'' if isinstance(optima, list) else ')'}",
             "",
             "| setting | N | utility, last fifth (mean ± std over runs) | episodes to converge "
             "| posterior error (mm) | optimal plans, last fifth | successful actions, last fifth "
             "| wall per run (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for label, v in summary["settings"].items():
        lines.append(
            f"| {label} | {v['particles'] if agent(v['agent']).learn_belief else '-'} "
            f"| {v['mean_utility_last_fifth']:.1f} ± {v['std_utility_last_fifth']:.1f} "
            f"| {'not converged' if v['episodes_to_converge'] is None else v['episodes_to_converge']} "
            f"| {v['final_posterior_error_mm']:.1f} "
            f"| {_fmt(v['optimal_plans_pct_last_fifth'], 0, ' %')} "
            f"| {_fmt(v['successful_actions_pct_last_fifth'], 1, ' %')} "
            f"| {v['mean_wall_s_per_run']:.0f} |")
    if "table_ii" in summary:
        episodes = list(summary["table_ii"][0]["episodes"]) if summary["table_ii"] else []
        lines += ["", "| setting (utility, mean (std) over runs) | " + " | ".join(
                      f"ep {e}" for e in episodes) + " |",
                  "|---|" + "---|" * len(episodes)]
        for row in summary["table_ii"]:
            lines.append(f"| {row['setting']} | " + " | ".join(
                f"{c['mean']:.0f} ({c['std']:.0f})" for c in row["episodes"].values()) + " |")
    if spec.get("particle_budget", "fixed") != "fixed":
        lines += ["", f"Particle budget `{spec['particle_budget']}` (floor {spec.get('min_particles')}): "
                      "particle-actions per episode, mean over runs", "",
                  "| setting | episode 1 | last episode |", "|---|---|---|"]
        for label, v in summary["settings"].items():
            lines.append(f"| {label} | {_fmt(v['particle_actions_first_episode'], 0, '')} "
                         f"| {_fmt(v['particle_actions_last_episode'], 0, '')} |")
    if summary["experiment"] == "weights":
        lines += ["", "| setting | density | posterior error of the density, last episode "
                      "| density posterior std | posterior error of the size (mm) |",
                  "|---|---|---|---|---|"]
        for label, v in summary["settings"].items():
            err = ("-" if v["final_density_error"] is None
                   else f"{v['final_density_error']:.0f} kg/m^3 ({v['final_density_error_pct']:.1f} %)")
            std = "-" if v["final_density_std"] is None else f"{v['final_density_std']:.0f} kg/m^3"
            where = ("known" if not v["density_in_L"] else "prior mean" if not agent(v["agent"]).learn_belief
                     else "learned")
            lines.append(f"| {label} | {where} | {err} | {std} | {v['final_posterior_error_mm']:.1f} |")
    if "milestones" in summary:
        lines += ["", "| setting | episodes | optimal plans (mean ± std) | successful actions (mean ± std) |",
                  "|---|---|---|---|"]
        for m in summary["milestones"]:
            span = (str(m["episode"]) if m["from_episode"] == m["episode"]
                    else f"{m['from_episode']}-{m['episode']}")
            opt = ("n/a" if m["optimal_plans_pct"] is None
                   else f"{m['optimal_plans_pct']:.0f} ± {m['optimal_plans_pct_std']:.0f} %")
            lines.append(f"| {m['setting']} | {span} | {opt} "
                         f"| {m['successful_actions_pct']:.1f} ± {m['successful_actions_pct_std']:.1f} % |")
    return "\n".join(lines) + "\n"


def write_outputs(spec: Spec, out: Path, t_star: dict) -> dict:
    """Every file of the experiment from its run files and T* (or, for an experiment with
    a T* per truth, ``{cache file: T*}``); their paths by kind."""
    from ..domains import task_half

    costs = dict(task_half(spec.domain).default_costs)
    if "transition" in t_star:
        t_star = {"true_T.json": t_star}
    elif spec.name == "sweep":
        from .sweep import write_sweep

        return write_sweep(spec, out, t_star)
    files = t_star_files(spec)
    judges = {name: Optimality(t["transition"], costs, t["params"]["n_blocks"], spec.domain)
              for name, t in t_star.items()}
    judge_of = lambda k, r: judges[files[(spec.settings[k].key, r)][0]]  # noqa: E731
    rows, arrays = table_rows(spec, out, judge_of)
    summary = summarize(spec, arrays, judge_of)
    summary["true_T"] = (next(iter(t_star.values()))["transition"] if len(t_star) == 1
                         else [t_star[files[(spec.settings[0].key, r)][0]]["transition"]
                               for r in range(spec.runs)])
    paths = {"csv": out / f"{spec.name}.csv", "json": out / f"{spec.name}.json",
             "png": out / f"{spec.name}.png", "md": out / f"{spec.name}.md"}
    write_csv(rows, paths["csv"])
    write_atomic(paths["json"], json.dumps(summary, indent=2))
    write_atomic(paths["md"], summary_table(summary))
    plot(spec, arrays, summary, paths["png"])
    return {k: str(v) for k, v in paths.items()}
