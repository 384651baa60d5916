"""From run files to numbers: the per-episode rows, the per-setting arrays, convergence,
the summary and its tables (milestones, the paper's Table II), and a run's tails
(``run_tails``: failure loops, regret, calibration; the sweep's per-run analysis)."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from sim_workers.properties import SIZES_VARIATION_SCALE

from .catalogue import ROBOT_EPISODES, Spec, run_config
from .runfiles import run_path
from .true_T import Optimality

CONVERGENCE_BAND = 0.05                           # "within 5 % of the final level"
# A run's tails (``run_tails``): the sweep's aims, in utility and in posterior std.
TAIL_NEAR_OPTIMUM = 30.0          # "within 30 of the T*-optimum"
TAIL_BY_EPISODE = 4               # ... by this episode (1-based)
LOOP_RUN = 6                      # a run of >= 6 back-to-back failures of one action loops
TAIL_COVERAGE_Z = 2.0             # a true value within +- 2 posterior std is covered
SHARP_RATIO = 1.5                 # posterior std <= 1.5 x the exact posterior's: sharp enough


def posterior_error(posterior: dict, config: dict) -> float:
    """|posterior size mean - true size| (metres); with sizes_variation (block 1 is 20 %
    larger, sim_workers.container) the mean over blocks of |block mean - block truth|."""
    if config["sizes_variation"] and len(posterior.get("mean") or []) == config["n_blocks"]:
        truth = np.full(config["n_blocks"], config["true_size"])
        truth[0] *= SIZES_VARIATION_SCALE
        return float(np.mean(np.abs(np.array(posterior["mean"]) - truth)))
    if "size_mean" not in posterior:     # a domain without a size: L's entries by name
        from .sweep import true_row

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



# ----------------------------------------------------------------------------- a run's tails
def steps_path(out: Path, setting, r: int) -> Path:
    """Run r's step records beside its run file: ``DIR/runs/<setting>/<r>.steps.jsonl``,
    one ``coordinator.step_record`` a line, as ``tmoc run``'s steps.jsonl (the sweep keeps
    them; runs made before it did have none)."""
    return Path(out) / "runs" / setting.key / f"{r}.steps.jsonl"


def read_steps(path: Path) -> list[dict] | None:
    """The step records of a ``steps.jsonl`` (a run directory's, or ``steps_path``'s);
    None if there is no such file (a run from before step records were kept)."""
    path = Path(path)
    if not path.exists():
        return None
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def longest_failure_run(records: Iterable[dict]) -> tuple[int, str | None, int | None]:
    """(length, action, episode) of the longest run of back-to-back failed records of one
    action string (one action on one object, e.g. ``pickup(r,b1,init)``) within an
    episode. Any other record (a success, a failure of another action, a new episode)
    ends a run; (0, None, None) without a failure."""
    best, best_action, best_episode = 0, None, None
    n, action, episode = 0, None, None
    for rec in records:
        ep, act, ok = rec["episode"], rec["action"], bool(rec["success"])
        if ok:
            n, action = 0, None
        elif act == action and ep == episode:
            n += 1
        else:
            n, action = 1, act
        episode = ep
        if n > best:
            best, best_action, best_episode = n, action, episode
    return best, best_action, best_episode


def _z(truth: float, mean: float, std: float) -> float:
    err = abs(mean - truth)
    return 0.0 if err == 0 else (err / std if std > 0 else math.inf)


def run_tails(records: Sequence[dict] | None, episodes: Sequence, optimum: float | None,
              truth_row: Mapping[str, float], posterior: Mapping[str, Mapping],
              reference: Mapping[str, Mapping] | None = None) -> dict:
    """One run's tails, from its step records and episodes alone (pure).

    `records`: the run's step records in order (``coordinator.step_record``: ``episode``,
    ``action``, ``success`` are read), or None where the run kept none (then the failure
    figures are None). `episodes`: each episode's utility, or its record (``utility``).
    `optimum`: the optimum's expected utility under the truth's T* (None: not judged
    against one; then regret, `near_optimum_by` and `never_improves` are None).
    `truth_row`: the true value per entry of L (``{"size": 0.045}``; a per-block entry
    under its own key, e.g. ``"size[0]"``); `posterior`: the final ``{"mean", "std"}``
    per entry of the same keys (result.json's ``summary.posterior``).

    `reference` (optional; the exact-posterior judge, ``coordinator.experiments.reference``,
    fills it): its ``{"mean", "std"}`` per entry; given, ``sharpness`` is the posterior std
    over the reference std per entry (1: as sharp as the exact posterior).

    Returns: ``regret`` per episode (optimum - utility), ``regret_last_episode``,
    ``longest_failure_run`` (+ its ``_action`` and ``_episode``), ``loops`` (that run
    >= LOOP_RUN), ``never_improves`` (no later episode beats the first, and the first is not
    already within TAIL_NEAR_OPTIMUM of the optimum; None for a single episode),
    ``near_optimum_by`` (within TAIL_NEAR_OPTIMUM from episode TAIL_BY_EPISODE on, as the
    sweep counts it), ``z`` (|posterior mean - truth| / posterior std per entry) and
    ``sharpness`` (None without a reference).
    """
    u = [float(e["utility"] if isinstance(e, Mapping) else e) for e in episodes]
    out: dict = {"utility": u, "optimum": optimum}
    if records is None:
        out.update(longest_failure_run=None, longest_failure_run_action=None,
                   longest_failure_run_episode=None, loops=None)
    else:
        n, action, episode = longest_failure_run(records)
        out.update(longest_failure_run=n, longest_failure_run_action=action,
                   longest_failure_run_episode=episode, loops=n >= LOOP_RUN)
    if optimum is None or not u:
        out.update(regret=None, regret_last_episode=None, near_optimum_by=None, never_improves=None)
    else:
        regret = [optimum - x for x in u]
        by = min(TAIL_BY_EPISODE, len(u))
        out.update(regret=regret, regret_last_episode=regret[-1],
                   near_optimum_by=all(r <= TAIL_NEAR_OPTIMUM for r in regret[by - 1:]),
                   never_improves=None if len(u) < 2 else
                   bool(max(u[1:]) <= u[0] and regret[0] > TAIL_NEAR_OPTIMUM))
    out["z"] = {k: _z(float(t), float(posterior[k]["mean"]), float(posterior[k]["std"]))
                for k, t in truth_row.items() if k in posterior}
    out["sharpness"] = None
    if reference is not None:           # the exact posterior's hook
        out["sharpness"] = {k: (float(posterior[k]["std"]) / float(ref["std"]) if float(ref["std"]) > 0
                                else math.inf)
                            for k, ref in reference.items() if k in posterior}
    return out


def distribution(values: Iterable) -> dict | None:
    """{n, median, p90, worst} of the values that are not None (worst: the largest, for
    figures where larger is worse; p90 by linear interpolation); None if there are none."""
    v = np.array([float(x) for x in values if x is not None], dtype=float)
    if v.size == 0:
        return None
    return {"n": int(v.size), "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "worst": float(np.max(v))}


def _share(flags: Iterable) -> float | None:
    f = [bool(x) for x in flags if x is not None]
    return sum(f) / len(f) if f else None


def summarize_tails(tails: Sequence[dict], labels: Sequence[str] | None = None) -> dict:
    """Distributions over runs (not truths) of `run_tails` results: regret at the last
    episode and the longest failure run (median, p90, worst), the shares of runs that loop,
    never improve and are within TAIL_NEAR_OPTIMUM by episode TAIL_BY_EPISODE (each over
    the runs where it is defined), and over every entry of L of every run: coverage
    (|z| <= TAIL_COVERAGE_Z), mean z^2, median and p90 |z|; with references, sharpness
    (median, p90, share <= SHARP_RATIO). `labels` name the runs in the lists of runs that
    loop or never improve."""
    labels = list(labels) if labels is not None else [str(i) for i in range(len(tails))]
    z = np.array([v for t in tails for v in t["z"].values()], dtype=float)
    sharp = [v for t in tails for v in (t.get("sharpness") or {}).values()]
    with_steps = [t for t in tails if t["longest_failure_run"] is not None]
    worst_loop = max(zip(tails, labels), key=lambda tl: tl[0]["longest_failure_run"] or 0) if with_steps else None
    out = {
        "runs": len(tails),
        "runs_with_steps": len(with_steps),
        "regret_last_episode": distribution(t["regret_last_episode"] for t in tails),
        "longest_failure_run": distribution(t["longest_failure_run"] for t in tails),
        "loop_share": _share(t["loops"] for t in tails),
        "loops": [lab for t, lab in zip(tails, labels) if t["loops"]],
        "never_improves_share": _share(t["never_improves"] for t in tails),
        "never_improves": [lab for t, lab in zip(tails, labels) if t["never_improves"]],
        f"near_optimum_by_episode_{TAIL_BY_EPISODE}_share": _share(t["near_optimum_by"] for t in tails),
        "z_entries": int(z.size),
        "coverage": float(np.mean(z <= TAIL_COVERAGE_Z)) if z.size else None,
        "mean_z2": float(np.mean(z ** 2)) if z.size else None,
        "median_abs_z": float(np.median(z)) if z.size else None,
        "p90_abs_z": float(np.percentile(z, 90)) if z.size else None,
        "worst_loop": None if worst_loop is None else {
            "run": worst_loop[1], "length": worst_loop[0]["longest_failure_run"],
            "action": worst_loop[0]["longest_failure_run_action"],
            "episode": worst_loop[0]["longest_failure_run_episode"]},
        "sharpness": None,
        "definitions": {
            "loops": f"the longest run of back-to-back failures of one action (string) in an "
                     f"episode is >= {LOOP_RUN}",
            "never_improves": f"no episode after the first beats the first, and the first is not "
                              f"within {TAIL_NEAR_OPTIMUM:g} of the optimum",
            "regret_last_episode": "optimum's expected utility under T* - the last episode's utility",
            "z": "|posterior mean - truth| / posterior std per entry of L after the last episode",
        },
    }
    if sharp:
        s = np.array(sharp, dtype=float)
        out["sharpness"] = {"n": int(s.size), "median": float(np.median(s)),
                            "p90": float(np.percentile(s, 90)),
                            f"share_le_{SHARP_RATIO:g}": float(np.mean(s <= SHARP_RATIO))}
    return out


def run_dir_tails(run_dir: Path, optimum: float | None, reference: Mapping[str, Mapping] | None = None) -> dict:
    """`run_tails` of a ``tmoc run`` directory (its ``steps.jsonl`` and ``result.json``),
    judged against the property means of L (per-block entries as their mean)."""
    from ..step_record import STEPS_FILE

    d = Path(run_dir)
    result = json.loads((d / "result.json").read_text())
    summary = result["summary"]
    post = summary["posterior"]
    return run_tails(read_steps(d / STEPS_FILE), result["episodes"], optimum,
                     {k: v for k, v in (summary.get("truth") or {}).items() if k in post},
                     post, reference)
