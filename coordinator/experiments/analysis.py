"""From run files to numbers: the per-episode rows, the per-setting arrays, convergence,
the summary and its tables (milestones, the paper's Table II). A run's tails are
``coordinator.experiments.tails`` (re-exported here for callers from before)."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable

import numpy as np

from sim_workers.properties import SIZES_VARIATION_SCALE

from .catalogue import ROBOT_EPISODES, Spec, run_config
from .runfiles import run_path
from .tails import (LOOP_RUN, SHARP_RATIO, TAIL_BY_EPISODE, TAIL_COVERAGE_Z, TAIL_NEAR_OPTIMUM,  # noqa: F401
                    distribution, longest_failure_run, read_steps, run_dir_tails, run_tails, steps_path,
                    summarize_tails, true_row)
from .true_T import Optimality

CONVERGENCE_BAND = 0.05                           # "within 5 % of the final level"


def posterior_error(posterior: dict, config: dict) -> float:
    """|posterior size mean - true size| (metres); with sizes_variation (block 1 is 20 %
    larger, sim_workers.container) the mean over blocks of |block mean - block truth|."""
    if config["sizes_variation"] and len(posterior.get("mean") or []) == config["n_blocks"]:
        truth = np.full(config["n_blocks"], config["true_size"])
        truth[0] *= SIZES_VARIATION_SCALE
        return float(np.mean(np.abs(np.array(posterior["mean"]) - truth)))
    if "size_mean" not in posterior:     # a domain without a size: L's entries by name
        entries = true_row(config, posterior)
        return float(np.mean([abs(m - t) for _, _, t, m, _ in entries])) if entries else float("nan")
    return abs(posterior["size_mean"] - config["true_size"])


def table_rows(spec: Spec, out: Path, judge_of: Callable[[int, int], Optimality]) -> tuple[list[dict], dict]:
    """CSV rows (setting order, run, episode) and the per-setting arrays for the summary;
    `judge_of(k, r)` is the Optimality of run r of setting k (its truth's T*)."""
    rows, arrays = [], {}
    for k, s in enumerate(spec.settings):
        per = {"utility": [], "size_err": [], "optimal": [], "successes": [], "actions": [],
               "wall_s": [], "density_err": [], "density_std": [], "particle_actions": []}
        for r in range(spec.runs):
            optimal = judge_of(k, r)
            data = json.loads(run_path(out, s, r).read_text())
            cfg = data["config"]
            eps = data["episodes"]
            judge = not cfg["sizes_variation"]       # T* is probed with equal blocks
            u, err, opt, succ, acts, d_err, d_std, pa = [], [], [], [], [], [], [], []
            true_density = _true_density(cfg)
            for e in eps:
                n_fail = int(sum(e["failures"].values()))
                plan_loads = list(e["plans"][0]) if e.get("plans") else []
                is_opt = optimal(plan_loads) if judge else None
                rate = (e["actions"] - n_fail) / e["actions"] if e["actions"] else None
                rows.append({
                    "setting": s.label, "run": r, "episode": e["episode"] + 1, "seed": data["seed"],
                    "agent": cfg["agent"], "particles": cfg["particles"],
                    "utility": e["utility"], "actions": e["actions"], "failures": n_fail,
                    "delivered": e["delivered"], "size_mean": e["posterior"].get("size_mean"),
                    "size_std": e["posterior"].get("size_std"),
                    "size_error": posterior_error(e["posterior"], cfg),
                    "loads": "+".join(str(x) for x in e["loads"]),
                    "plan_loads": "+".join(str(x) for x in plan_loads),
                    "optimal_plan": "" if is_opt is None else int(is_opt),
                    "success_rate": "" if rate is None else rate,
                    "particle_actions": e.get("particle_actions", ""),
                })
                dens = (e["posterior"].get("properties") or {}).get("density")
                if spec.name == "weights":
                    rows[-1].update(_density_cells(dens, true_density))
                d_err.append(np.nan if dens is None or true_density is None
                             else abs(dens["mean"] - true_density))
                d_std.append(np.nan if dens is None else dens["std"])
                u.append(e["utility"])
                err.append(rows[-1]["size_error"])
                opt.append(np.nan if is_opt is None else float(is_opt))
                succ.append(e["actions"] - n_fail)
                acts.append(e["actions"])
                pa.append(e.get("particle_actions", np.nan))     # runs from before the budget: unknown
            for key, v in (("utility", u), ("size_err", err), ("optimal", opt),
                           ("successes", succ), ("actions", acts), ("density_err", d_err),
                           ("density_std", d_std), ("particle_actions", pa)):
                per[key].append(v)
            per["wall_s"].append(data["runtime"]["wall_s"])
        arrays[s.label] = {key: (np.array(v, dtype=float) if key != "wall_s" else v)
                           for key, v in per.items()}
    return rows, arrays


def _true_density(cfg: dict) -> float | None:
    """The run's true block density: the hidden truth's, or the known one it was set to."""
    value = (cfg.get("truth") or {}).get("density", (cfg.get("options") or {}).get("density"))
    return None if value is None else float(value)


def _density_cells(dens: dict | None, truth: float | None) -> dict:
    """CSV cells of the density posterior (empty where L has no density: it is known)."""
    if dens is None:
        return {"density_mean": "", "density_std": "", "density_error": ""}
    return {"density_mean": dens["mean"], "density_std": dens["std"],
            "density_error": "" if truth is None else abs(dens["mean"] - truth)}


def convergence_episode(curve: np.ndarray, band: float = CONVERGENCE_BAND) -> tuple[int | None, float, int]:
    """(episode, final level, smoothing window) for a mean curve.

    final level = mean of the curve over its last fifth (at least one episode). The curve
    is smoothed by a trailing moving average over w = max(1, E // 20) episodes (per-episode
    means over a few runs are too noisy to ever "stay" anywhere). The answer is the first
    episode (1-based) from which the smoothed curve stays within band x |final level| of
    the final level to the end; None if its last point is outside.
    """
    E = len(curve)
    tail = max(1, int(math.ceil(E / 5)))
    final = float(np.mean(curve[-tail:]))
    w = max(1, E // 20)
    c = np.cumsum(np.concatenate([[0.0], curve]))
    idx = np.arange(1, E + 1)
    smooth = (c[idx] - c[np.maximum(0, idx - w)]) / np.minimum(idx, w)
    inside = np.abs(smooth - final) <= band * abs(final) + 1e-12
    if not inside[-1]:
        return None, final, w
    outside = np.flatnonzero(~inside)
    return (int(outside[-1]) + 2 if len(outside) else 1), final, w


def _nan_mean(a) -> float | None:
    a = np.asarray(a, dtype=float)
    return None if a.size == 0 or np.all(np.isnan(a)) else float(np.nanmean(a))


def summarize(spec: Spec, arrays: dict, judge_of: Callable[[int, int], Optimality]) -> dict:
    """The experiment's summary (DIR/NAME.json): per setting the final level, convergence,
    posterior error, optimal plans and successful actions, with the definitions used."""
    E = spec.episodes
    tail = max(1, int(math.ceil(E / 5)))
    settings = {}
    for k, s in enumerate(spec.settings):
        a = arrays[s.label]
        curve = a["utility"].mean(axis=0)
        conv, final, w = convergence_episode(curve)
        last = a["utility"][:, -tail:].mean(axis=1)
        cfg = run_config(spec, k, 0)
        opt_tail = a["optimal"][:, -tail:]
        settings[s.label] = {
            "key": s.key, "agent": cfg.agent, "particles": cfg.particles,
            "sizes_variation": cfg.sizes_variation, "likelihood": cfg.likelihood,
            "runs": spec.runs, "episodes": E,
            "mean_utility_last_fifth": float(final),
            "std_utility_last_fifth": float(np.std(last)),
            "episodes_to_converge": conv,
            "final_posterior_error": float(np.mean(a["size_err"][:, -1])),
            "final_posterior_error_mm": float(np.mean(a["size_err"][:, -1]) * 1000),
            "optimal_plans_pct_last_fifth": (None if np.all(np.isnan(opt_tail))
                                             else 100 * _nan_mean(opt_tail)),
            "successful_actions_pct_last_fifth": 100 * float(a["successes"][:, -tail:].sum()
                                                             / max(1.0, a["actions"][:, -tail:].sum())),
            "mean_wall_s_per_run": float(np.mean(a["wall_s"])),
            # the adaptive budget at work: particle worlds per episode, first and last
            "particle_actions_first_episode": _nan_mean(a["particle_actions"][:, 0]),
            "particle_actions_last_episode": _nan_mean(a["particle_actions"][:, -1]),
        }
        if spec.name == "weights":
            truth = _true_density(cfg.model_dump())
            d_err, d_std = a["density_err"][:, -1], a["density_std"][:, -1]
            learned = not np.all(np.isnan(d_err))
            settings[s.label].update({
                "true_density": truth,
                "density_in_L": bool(learned or not np.all(np.isnan(d_std))),
                "final_density_error": _nan_mean(d_err) if learned else None,
                "final_density_error_pct": (100 * _nan_mean(d_err) / truth) if learned and truth else None,
                "final_density_std": _nan_mean(d_std),
            })
    summary = {
        "experiment": spec.name, "spec": spec.to_dict(), "settings": settings,
        "optimum_under_true_T": (
            [{"true_size": spec.truths[r], "loads": judge_of(0, r).best_loads,
              "expected_utility": judge_of(0, r).best_value} for r in range(spec.runs)] if spec.truths
            else {"loads": judge_of(0, 0).best_loads, "expected_utility": judge_of(0, 0).best_value}),
        "definitions": {
            "episode": "1-based",
            "last_fifth": f"the last {tail} of {E} episodes (ceil(E / 5))",
            "mean_utility_last_fifth": "mean over runs of the utility over the last fifth "
                                       "(= the final level of the mean curve)",
            "episodes_to_converge": convergence_episode.__doc__.strip().split("\n\n")[1]
                                    .replace("\n", " ").replace("    ", ""),
            "final_posterior_error": "|posterior size mean - true size| after the last episode, "
                                     "metres, mean over runs (tmp_rl and toep: the prior mean); "
                                     "with sizes_variation the mean over blocks of |block mean - "
                                     "block truth|",
            "optimal_plan": "the episode's first plan (from the initial state) has a load split "
                            "whose expected utility under T* equals the optimum's; not judged "
                            "with sizes_variation (T* is probed with equal blocks)",
            "success_rate": "successful actions / actions in the episode",
            "particle_actions": "particle worlds simulated in the episode (actions x particles; "
                                "with --particle-budget kld the count falls as the belief converges)",
        },
    }
    if spec.name == "milestones":
        summary["milestones"] = milestone_table(spec, arrays)
    if spec.name == "robot":
        summary["table_ii"] = robot_table(spec, arrays)
    if spec.name == "weights":
        summary["definitions"]["final_density_error"] = (
            "|posterior density mean - true density| after the last episode, kg/m^3, mean over "
            "runs (TMP-RL: the prior mean's; none where the density is known, not in L)")
        summary["definitions"]["final_density_std"] = "the density posterior's std after the last episode, kg/m^3"
    return summary


def milestone_table(spec: Spec, arrays: dict) -> list[dict]:
    """Per setting and milestone m: % optimal plans and % successful actions over the
    episodes since the previous milestone (exclusive) up to m (inclusive), per run, then
    mean and std over runs."""
    out = []
    for label, a in arrays.items():
        lo = 0
        for m in spec.milestones:
            opt = a["optimal"][:, lo:m]
            succ = a["successes"][:, lo:m].sum(axis=1) / np.maximum(1, a["actions"][:, lo:m].sum(axis=1))
            per_run_opt = (np.array([np.nan if np.all(np.isnan(row)) else np.nanmean(row) for row in opt])
                           * 100)
            out.append({"setting": label, "episode": m, "from_episode": lo + 1,
                        "optimal_plans_pct": _nan_mean(per_run_opt),
                        "optimal_plans_pct_std": (None if np.all(np.isnan(per_run_opt))
                                                  else float(np.nanstd(per_run_opt))),
                        "successful_actions_pct": float(np.mean(succ) * 100),
                        "successful_actions_pct_std": float(np.std(succ) * 100)})
            lo = m
    return out


def robot_table(spec: Spec, arrays: dict) -> list[dict]:
    """Table II of the paper: utility mean and std over runs at episodes 0, 4, ..., 36
    (0-based, as the paper counts), per setting; episodes beyond the run are left out."""
    rows = []
    for s in spec.settings:
        u = arrays[s.label]["utility"]
        cells = {str(e): {"mean": float(np.mean(u[:, e])), "std": float(np.std(u[:, e]))}
                 for e in ROBOT_EPISODES if e < u.shape[1]}
        rows.append({"setting": s.label, "episodes": cells})
    return rows
