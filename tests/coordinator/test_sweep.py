"""The learning-quality sweep (`tmoc experiment sweep`, benchmarks/bench_learning.py): its
truths span the prior, each run is judged against its own truth's T*, and the summary
lines count what the issue's aims count."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from coordinator import experiments as ex
from coordinator.cli import main
from coordinator.experiments.sweep import BY_EPISODE, NEAR_OPTIMUM


def _run(utilities, sizes_mean=0.045, size_std=0.001, true_size=0.045, **config):
    cfg = {"n_blocks": 8, "true_size": true_size, "sizes_variation": False, "truth": {}, "options": {},
           **config}
    post = {"size_mean": sizes_mean, "size_std": size_std, "mean": [sizes_mean], "std": [size_std],
            "properties": {"size": {"mean": sizes_mean, "std": size_std, "unit": "m"}}}
    eps = [{"utility": u, "failures": {"stack": 1}, "transit_fallbacks": 0, "delivered": 8,
            "posterior": post} for u in utilities]
    return {"config": cfg, "episodes": eps}


def test_truths_span_the_prior_of_every_domain():
    sizes = ex.prior_sizes(0.030, 0.060, 7)
    assert len(sizes) == 7 and sizes[0] > 0.030 and sizes[-1] < 0.060
    assert np.allclose(np.diff(sizes), 0.030 / 7, atol=1e-4)
    container = ex.sweep_settings("container")
    sp = ex.sweep_settings("stack_and_push")
    for settings in (container, sp):
        keys = [s.key for s in settings]
        assert len(keys) == len(set(keys))
        assert sum("per block" in s.label for s in settings) == 1
        plain = [s for s in settings if "per block" not in s.label and "kg/m3" not in s.label]
        assert [s.overrides["true_size"] for s in plain] == sizes
        for s in settings:       # every truth carries the T* probe parameters of its own truth
            assert s.t_star["true_size"] == s.overrides["true_size"]
    grid = [s for s in sp if "kg/m3" in s.label]       # size x density x sensor
    assert {(s.overrides["truth"]["density"], s.overrides["options"]["force_sigma"]) for s in grid} == \
        {(900.0, 0.1), (900.0, 3.5), (2200.0, 0.1), (2200.0, 3.5)}
    assert all(s.t_star["options"]["density"] == s.overrides["truth"]["density"] for s in grid)
    assert not any("kg/m3" in s.label for s in container)      # the container has no density in L
    paper = ex.sweep_settings("container", "paper")
    assert sum("per block" not in s.label for s in paper) == 13


def test_each_truth_gets_its_own_T_star_file():
    from coordinator.cli import build_parser
    from coordinator.commands.experiment import spec_from_args

    spec = spec_from_args(build_parser().parse_args(["experiment", "sweep", "--domain", "stack_and_push"]))
    files = ex.t_star_files(spec)
    assert len(files) == len(spec.settings) * spec.runs
    names = {name for name, _ in files.values()}
    # the per-block case shares its size's T* (T* is probed with equal blocks), and the two
    # sensors of one density share theirs (the sensor does not change what the robot can do)
    assert len(names) == 7 + 2
    assert all(name.startswith("true_T/") for name in names)
    assert spec.probe_trials == 10 and (spec.runs, spec.episodes, spec.particles) == (1, 4, 16)
    one = spec_from_args(build_parser().parse_args(["experiment", "compare", "--true-size", "0.034"]))
    assert {name for name, _ in ex.t_star_files(one).values()} == {"true_T.json"}
    assert "truths" not in one.to_dict()


def test_a_subset_of_the_grid_keeps_the_grids_run_seeds():
    # bench_learning.py --truths 1,3: those truths' runs are the whole grid's, seed for seed,
    # so a subset re-run compares in pairs with a committed sweep of the grid.
    from dataclasses import replace

    from coordinator.cli import build_parser
    from coordinator.commands.experiment import spec_from_args

    args = ["experiment", "sweep", "--domain", "stack_and_push", "--runs", "3"]
    grid = spec_from_args(build_parser().parse_args(args))
    subset = spec_from_args(build_parser().parse_args(args))
    subset.settings = [replace(grid.settings[i], seed_index=i) for i in (1, 3)]
    for k, i in enumerate((1, 3)):
        for r in range(3):
            assert ex.run_config(subset, k, r) == ex.run_config(grid, i, r)
    # without the grid's index a setting's place in its spec draws the seeds (as before)
    plain = spec_from_args(build_parser().parse_args(args))
    plain.settings = [grid.settings[3]]
    assert ex.run_config(plain, 0, 0).seed == ex.run_config(grid, 0, 0).seed != ex.run_config(grid, 3, 0).seed


def test_compare_draws_one_truth_per_run_across_the_prior():
    """By default `compare` hides a size per run, run r's from bin r of the prior, the same
    for every agent (paired), each judged against its own truth's T*."""
    from coordinator.cli import build_parser
    from coordinator.commands.experiment import spec_from_args

    spec = spec_from_args(build_parser().parse_args(["experiment", "compare", "--runs", "5", "--seed", "2"]))
    assert len(spec.truths) == 5 and spec.to_dict()["truths"] == list(spec.truths)
    for r, t in enumerate(spec.truths):
        assert 0.030 + r * 0.006 <= t <= 0.030 + (r + 1) * 0.006
        assert {ex.run_config(spec, k, r).true_size for k in range(len(spec.settings))} == {t}
    files = ex.t_star_files(spec)
    assert len({name for name, _ in files.values()}) == 5
    assert all(files[(s.key, r)][1]["true_size"] == spec.truths[r]
               for s in spec.settings for r in range(5))
    again = spec_from_args(build_parser().parse_args(["experiment", "compare", "--runs", "5", "--seed", "2"]))
    other = spec_from_args(build_parser().parse_args(["experiment", "compare", "--runs", "5", "--seed", "3"]))
    assert again.truths == spec.truths != other.truths


def test_judging_a_run_against_its_optimum():
    good = ex.judge_run(_run([-100, 95, 110, 110]), optimum=110.0)
    assert good["near_optimum_by"] and good["episodes_to_converge"] == 2
    assert good["regret_last"] == 0.0 and not good["not_improving"]
    assert good["covered"] == good["entries"] == 1 and good["z_max"] == 0.0
    stuck = ex.judge_run(_run([-1800, -1700, -1900, -1850], sizes_mean=0.049, size_std=0.001,
                              true_size=0.045), optimum=110.0)
    assert not stuck["near_optimum_by"] and stuck["episodes_to_converge"] is None
    assert stuck["not_improving"] and stuck["regret_last"] == pytest.approx(110 + 1875)
    assert stuck["z_max"] == pytest.approx(4.0) and stuck["covered"] == 0
    late = ex.judge_run(_run([-500, -400, -300, 110 - NEAR_OPTIMUM]), optimum=110.0)
    assert late["near_optimum_by"] == (BY_EPISODE <= 4) and late["episodes_to_converge"] == 4
    assert not ex.judge_run(_run([-500]), optimum=110.0)["not_improving"]    # one episode: undefined


def test_per_block_truths_are_judged_per_block():
    run = _run([110, 110], sizes_variation=True)
    mean = [0.054] + [0.045] * 7                # block 1 is 20 % larger: 54 mm
    run["episodes"][-1]["posterior"].update(mean=mean, std=[0.001] * 8)
    judged = ex.judge_run(run, optimum=110.0)
    assert judged["entries"] == 8 and judged["covered"] == 8
    run["episodes"][-1]["posterior"]["mean"] = [0.030] + [0.045] * 7       # locked in at the floor
    judged = ex.judge_run(run, optimum=110.0)
    assert judged["covered"] == 7 and judged["z_max"] == pytest.approx(24.0)
    # per-block truths are not judged against an optimum (T* is probed with equal blocks)
    unjudged = ex.judge_run(run, optimum=None)
    assert unjudged["near_optimum_by"] is None and unjudged["regret_last"] is None
    assert not unjudged["not_improving"]


def test_summary_lines():
    rows = [dict(ex.judge_run(_run(u), optimum=110.0), case=c, run=0, domain="container")
            for c, u in (("a", [110, 110]), ("b", [-900, -1000]), ("c", [100, 105]))]
    s = ex.summarize_sweep(rows)
    assert s["truths"] == 3
    assert s[f"near_optimum_by_episode_{BY_EPISODE}"] == pytest.approx(2 / 3)
    assert s["not_improving"] == ["b (run 0)"] and s["worst_regret"]["case"] == "b"
    assert s["coverage"] == 1.0
    table = ex.sweep_table(rows, s)
    assert table.count("\n| container |") == 3 and "67 % of 3 truths" in table
    rows.append(dict(ex.judge_run(_run([-900, -1000]), optimum=None), case="d", run=0, domain="container"))
    s = ex.summarize_sweep(rows)
    assert (s["truths"], s["judged"]) == (4, 3) and s[f"near_optimum_by_episode_{BY_EPISODE}"] == pytest.approx(2 / 3)
    assert s["not_improving"] == ["b (run 0)", "d (run 0)"]
    assert "| - | - |" in ex.sweep_table(rows, s)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_sweep_writes_its_files(ray_cluster, tmp_path):
    out = tmp_path / "sweep"
    # Four blocks: T* probes 9 contexts per truth, not 17 (22 s against 38 s on 2 cores).
    assert main(["experiment", "sweep", "--episodes", "1", "--particles", "4", "--max-steps", "3",
                 "--probe-trials", "1", "--no-progress", "--seed", "3", "--set", "n_blocks=4",
                 "--set", "counterfactual_rows=0", "--out", str(out)]) == 0
    data = json.loads((out / "sweep.json").read_text())
    n = len(ex.sweep_settings("container"))
    assert len(data["rows"]) == n and data["summary"]["truths"] == n
    assert len(list((out / "true_T").glob("*.json"))) == n - 1
    for row in data["rows"]:
        t_star = json.loads((out / "true_T" / f"{row['key'].removesuffix('-perblock')}.json").read_text())
        assert t_star["params"]["true_size"] == row["true_size"]
        assert len(row["utility"]) == 1
        assert (row["optimum"] is None) == row["case"].endswith("per block")
        assert row["optimum"] is None or row["optimum"] <= 150
        # each run keeps its step records (issue 37), and its tails are counted from them
        steps = ex.analysis.read_steps(out / "runs" / row["key"] / "0.steps.jsonl")
        assert steps and {s["episode"] for s in steps} == {0} and len(steps) <= 3
        assert row["tails"]["longest_failure_run"] is not None
    assert data["summary"]["tails"]["runs"] == data["summary"]["tails"]["runs_with_steps"] == n
    with open(out / "sweep.csv", newline="") as f:
        assert len(list(csv.DictReader(f))) == n
    assert (out / "sweep.md").read_text() == ex.sweep_table(data["rows"], data["summary"])
    assert (out / "sweep.png").read_bytes()[:4] == b"\x89PNG"


# ----------------------------------------------------------------------------- tails (issue 37)
def _steps(*episodes):
    """Step records (as coordinator.loop.step_record writes them: only what run_tails reads)
    from per-episode lists of (action, success)."""
    out = []
    for e, steps in enumerate(episodes):
        out += [{"episode": e, "step": i, "action": a, "success": ok} for i, (a, ok) in enumerate(steps)]
    return out


TRUTH = {"size": 0.045}
POST = {"size": {"mean": 0.046, "std": 0.001}}


def test_a_failure_loop_is_counted_and_loops():
    from coordinator.experiments.tails import LOOP_RUN, run_tails

    pick = "pickup(r,b1,init)"
    records = _steps([("pickup(r,b0,init)", True)] + [(pick, False)] * 24 + [(pick, True)],
                     [(pick, False)] * 3)
    t = run_tails(records, [-1800, -900], 110.0, TRUTH, POST)
    assert t["longest_failure_run"] == 24 and t["loops"] and LOOP_RUN == 6
    assert t["longest_failure_run_action"] == pick and t["longest_failure_run_episode"] == 0
    assert t["regret"] == [1910.0, 1010.0] and t["regret_last_episode"] == 1010.0
    assert t["z"] == {"size": pytest.approx(1.0)} and t["sharpness"] is None
    # 5 in a row does not loop; a new episode starts a new run (3 + 3 is not 6)
    five = run_tails(_steps([(pick, False)] * 5 + [(pick, True)]), [0], 110.0, TRUTH, POST)
    assert five["longest_failure_run"] == 5 and not five["loops"]
    split = run_tails(_steps([(pick, False)] * 3, [(pick, False)] * 3), [0, 0], 110.0, TRUTH, POST)
    assert split["longest_failure_run"] == 3


def test_a_failure_retried_between_other_actions_still_counts():
    from coordinator.experiments.tails import longest_failure_run, run_tails

    a, b = "pickup(r,b1,init)", "pickup(r,b2,init)"
    # Two actions failing in turn: each fails ten times, none succeeding (a loop of two).
    alternating = _steps([(a, False), (b, False)] * 10)
    t = run_tails(alternating, [0, 0], 110.0, TRUTH, POST)
    assert t["longest_failure_run"] == 10 and t["loops"]
    # A stack that drops its block, picked up again each time (the pickup succeeds): the
    # stack's run goes on across the pickups; the old back-to-back count read 1 here.
    stack, pick = "stack(r,b3,tower)", "pickup(r,b3,rail)"
    retried = longest_failure_run(_steps([(pick, True), (stack, False)] * 7))
    assert retried == (7, stack, 0)
    # Only a success of the same action ends its run.
    assert longest_failure_run(_steps([(a, False)] * 4 + [(a, True)] + [(a, False)] * 2))[0] == 4
    assert longest_failure_run(_steps([(a, False)] * 4 + [(b, True)] + [(a, False)] * 5))[:2] == (9, a)
    assert longest_failure_run(_steps([(a, False)] * 3 + [(b, False)] + [(a, True)] + [(b, False)] * 2))[:2] == (3, a)
    assert longest_failure_run(_steps([(a, True)] * 4)) == (0, None, None)
    # no step records (a sweep from before they were kept): no failure figures, not a crash
    old = run_tails(None, [0, 0], 110.0, TRUTH, POST)
    assert old["longest_failure_run"] is None and old["loops"] is None


def test_never_improving_and_improving_runs():
    from coordinator.experiments.tails import run_tails

    never = run_tails([], [-900, -1000, -950, -900], 110.0, TRUTH, POST)
    assert never["never_improves"] and not never["near_optimum_by"]
    assert never["longest_failure_run"] == 0 and not never["loops"]
    improves = run_tails([], [-900, -200, 100, 105], 110.0, TRUTH, POST)
    assert not improves["never_improves"] and improves["near_optimum_by"]
    assert improves["regret_last_episode"] == 5.0
    # already within 30 of the optimum at episode 1: nothing to improve on
    assert not run_tails([], [90, 85, 90, 90], 110.0, TRUTH, POST)["never_improves"]
    # a single episode, or no optimum (per-block truths): undefined
    assert run_tails([], [-900], 110.0, TRUTH, POST)["never_improves"] is None
    unjudged = run_tails([], [-900, -1000], None, TRUTH, POST)
    assert unjudged["never_improves"] is None and unjudged["regret"] is None
    # the exact posterior's hook: sharpness = posterior std / reference std
    sharp = run_tails([], [0], 110.0, TRUTH, POST, reference={"size": {"mean": 0.045, "std": 0.0005}})
    assert sharp["sharpness"] == {"size": pytest.approx(2.0)}


def test_tails_summary_distributions_over_runs():
    from coordinator.experiments.tails import distribution, run_tails, summarize_tails

    d = distribution([10, 1, 2, 3, 4, 5, 6, 7, 8, 9, None])
    assert d == {"n": 10, "median": 5.5, "p90": pytest.approx(9.1), "worst": 10.0}
    assert distribution([None]) is None
    pick = "stack(r,b3,b2)"
    tails = [run_tails(_steps([(pick, False)] * n), [0, 110 - regret], 110.0, TRUTH,
                       {"size": {"mean": 0.045 + z * 0.001, "std": 0.001}},
                       reference={"size": {"mean": 0.045, "std": 0.001 / ratio}})
             for n, regret, z, ratio in ((24, 500, 3.0, 1.0), (2, 0, 0.5, 2.0), (0, 10, 1.0, 1.2),
                                         (7, 40, 2.5, 1.0))]
    s = summarize_tails(tails, ["a", "b", "c", "d"])
    assert s["runs"] == s["runs_with_steps"] == 4
    assert s["regret_last_episode"] == {"n": 4, "median": 25.0, "p90": pytest.approx(362.0), "worst": 500.0}
    assert s["longest_failure_run"]["median"] == 4.5 and s["longest_failure_run"]["worst"] == 24
    assert s["loop_share"] == 0.5 and s["loops"] == ["a", "d"]
    assert s["worst_loop"] == {"run": "a", "length": 24, "action": pick, "episode": 0}
    assert s["never_improves_share"] == 0.25 and s["never_improves"] == ["a"]    # 0, then -390
    assert s[f"near_optimum_by_episode_{BY_EPISODE}_share"] == 0.5
    assert s["z_entries"] == 4 and s["coverage"] == 0.5
    assert s["mean_z2"] == pytest.approx((9 + 0.25 + 1 + 6.25) / 4)
    assert s["median_abs_z"] == pytest.approx(1.75)
    assert s["sharpness"]["median"] == pytest.approx(1.1) and s["sharpness"]["share_le_1.5"] == 0.75
    # the sweep's summary carries them for rows that have tails, and its table shows them
    rows = [dict(ex.judge_run(_run([0, 110 - regret]), optimum=110.0), case=c, run=0, domain="container",
                 tails=t) for c, t, regret in zip("abcd", tails, (500, 0, 10, 40))]
    summary = ex.summarize_sweep(rows)
    assert summary["tails"]["loops"] == ["a (run 0)", "d (run 0)"]
    table = ex.sweep_table(rows, summary)
    assert f"24 ({pick}, loops)" in table and "Tails over 4 runs" in table
    assert ex.summarize_sweep([{k: v for k, v in r.items() if k != "tails"} for r in rows])["tails"] is None


def test_tails_of_a_run_file_and_old_sweeps(tmp_path):
    """sweep_rows reads each run's step records beside its run file; a run without them
    (a sweep from before they were kept) gets None failure figures."""
    from coordinator.experiments.tails import read_steps, steps_path
    from coordinator.experiments.sweep import tails_of

    run = _run([-900, 100])
    run["episodes"][-1]["posterior"]["properties"]["size"]["mean"] = 0.047
    t = tails_of(run, 110.0, None)
    assert t["z"] == {"size": pytest.approx(2.0)} and t["longest_failure_run"] is None
    per_block = _run([110, 110], sizes_variation=True)
    per_block["episodes"][-1]["posterior"].update(mean=[0.054] + [0.045] * 7, std=[0.001] * 8)
    assert set(tails_of(per_block, None, [])["z"]) == {f"size[{b}]" for b in range(8)}
    setting = ex.sweep_settings("container")[0]
    path = steps_path(tmp_path, setting, 1)
    assert path == tmp_path / "runs" / setting.key / "1.steps.jsonl" and read_steps(path) is None
    path.parent.mkdir(parents=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in _steps([("pickup(r,b1,init)", False)] * 6)))
    assert tails_of(run, 110.0, read_steps(path))["loops"]
