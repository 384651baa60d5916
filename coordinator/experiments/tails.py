"""A run's tails and its truths: failure loops, regret against the T*-optimum, calibration
(|z| of every entry of L) and sharpness against the exact posterior, per run (``run_tails``)
and over runs (``summarize_tails``). Pure functions of the step records and the result; the
sweep, the experiments' analysis and ``bench_learning.py`` share them (this module imports
neither, so neither imports the other for them)."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from sim_workers.properties import SIZES_VARIATION_SCALE

# A run's tails (``run_tails``): the sweep's aims, in utility and in posterior std.
TAIL_NEAR_OPTIMUM = 30.0          # "within 30 of the T*-optimum"
TAIL_BY_EPISODE = 4               # ... by this episode (1-based)
LOOP_RUN = 6                      # >= 6 failed attempts of one action, none of it succeeding between, loops
TAIL_COVERAGE_Z = 2.0             # a true value within +- 2 posterior std is covered
SHARP_RATIO = 1.5                 # posterior std <= 1.5 x the exact posterior's: sharp enough


def _default_truths(config: dict) -> dict[str, float]:
    """L's default truth by name for the run's domain and options."""
    from sim_workers.domains import load

    L = load(config["domain"], n_blocks=config["n_blocks"], **(config.get("options") or {})).L
    return dict(zip(L.names, (float(t) for t in L.truth)))


def true_row(config: dict, posterior: dict) -> list[tuple[str, int | None, float, float, float]]:
    """(property, block or None, truth, posterior mean, posterior std) for every entry of
    L that the posterior reports (per block with ``sizes_variation``)."""
    props = posterior.get("properties") or {}
    names = list(props) or ["size"]
    mean, std = posterior.get("mean"), posterior.get("std")
    n = config["n_blocks"]
    truths = {"size": float(config["true_size"])}
    if any(n not in ("size", "density") for n in names):
        truths = {**_default_truths(config), **truths, **(config.get("truth") or {})}
    if "density" in names:
        truths["density"] = float(config["truth"].get("density", config["options"].get("density", 700.0)))
    per_block = bool(config["sizes_variation"]) and mean is not None and len(mean) == n * len(names)
    out = []
    for j, name in enumerate(names):
        if per_block:
            for b in range(n):
                t = truths[name] * (SIZES_VARIATION_SCALE if name == "size" and b == 0 else 1.0)
                out.append((name, b, t, float(mean[j * n + b]), float(std[j * n + b])))
        else:
            m = props[name]["mean"] if name in props else posterior["size_mean"]
            s = props[name]["std"] if name in props else posterior["size_std"]
            out.append((name, None, truths[name], float(m), float(s)))
    return out


def steps_path(out: Path, setting, r: int) -> Path:
    """Run r's step records beside its run file: ``DIR/runs/<setting>/<r>.steps.jsonl``,
    one ``coordinator.loop.step_record`` a line, as ``tmoc run``'s steps.jsonl (the sweep keeps
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
    """(length, action, episode) of the longest run of failed attempts of one action string
    (one action on one object, e.g. ``pickup(r,b1,init)``) within an episode: a success of
    that action, or a new episode, ends its run; attempts of other actions between do not.
    A stack that fails, drops its block, and is retried after a pickup that succeeds is
    one action failing again and again (a loop), though no two failed records are
    adjacent. (0, None, None) without a failure."""
    best, best_action, best_episode = 0, None, None
    runs: dict[str, int] = {}
    episode = None
    for rec in records:
        ep, act, ok = rec["episode"], rec["action"], bool(rec["success"])
        if ep != episode:
            runs, episode = {}, ep
        runs[act] = 0 if ok else runs.get(act, 0) + 1
        if runs[act] > best:
            best, best_action, best_episode = runs[act], act, ep
    return best, best_action, best_episode


def _z(truth: float, mean: float, std: float) -> float:
    err = abs(mean - truth)
    return 0.0 if err == 0 else (err / std if std > 0 else math.inf)


def run_tails(records: Sequence[dict] | None, episodes: Sequence, optimum: float | None,
              truth_row: Mapping[str, float], posterior: Mapping[str, Mapping],
              reference: Mapping[str, Mapping] | None = None) -> dict:
    """One run's tails, from its step records and episodes alone (pure).

    `records`: the run's step records in order (``coordinator.loop.step_record``: ``episode``,
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
            "loops": f"the longest run of failed attempts of one action (string) in an episode, "
                     f"only a success of that action ending it, is >= {LOOP_RUN}",
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
    from ..loop.step_record import STEPS_FILE

    d = Path(run_dir)
    result = json.loads((d / "result.json").read_text())
    summary = result["summary"]
    post = summary["posterior"]
    return run_tails(read_steps(d / STEPS_FILE), result["episodes"], optimum,
                     {k: v for k, v in (summary.get("truth") or {}).items() if k in post},
                     post, reference)
