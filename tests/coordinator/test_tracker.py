"""`tmoc run --log-to tensorboard:DIR` (issue 28, item 3): the event files read back with
TensorBoard's own reader."""
from __future__ import annotations

import json

import pytest

from coordinator.cli import main


def test_a_bad_log_to_is_refused_by_name(capsys, tmp_path):
    for value in ("mlflow:x", "tensorboard:", "nowhere"):
        assert main(["run", "--episodes", "1", "--log-to", value, "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("tmoc run: error: --log-to") and err.count("\n") == 1, err


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_run_logs_each_episode_to_tensorboard(tmp_path, capsys):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    logdir, out = tmp_path / "tb", tmp_path / "run"
    assert main(["run", "--episodes", "2", "--particles", "4", "--max-steps", "6", "--seed", "3",
                 "--counterfactual", "0", "--no-progress", "--out", str(out),
                 "--log-to", f"tensorboard:{logdir}"]) == 0
    result = json.loads((out / "result.json").read_text())
    acc = EventAccumulator(str(logdir), size_guidance={"scalars": 0, "histograms": 0})
    acc.Reload()
    tags = acc.Tags()
    assert {"utility", "failures", "particles_per_action", "posterior/size/mean", "posterior/size/std",
            "T/push/1"} <= set(tags["scalars"])
    assert [e.value for e in acc.Scalars("utility")] == [e["utility"] for e in result["episodes"]]
    assert [e.step for e in acc.Scalars("utility")] == [0, 1]
    last = acc.Scalars("posterior/size/mean")[-1].value
    assert last == pytest.approx(result["episodes"][-1]["posterior"]["properties"]["size"]["mean"], rel=1e-6)
    push = result["summary"]["transition"]["push"]           # T in the planner's form: p of k = 1..n
    assert acc.Scalars("T/push/1")[-1].value == pytest.approx(push[0], rel=1e-6)
    hist = acc.Histograms("posterior/size")
    assert [h.step for h in hist] == [0, 1]
    h = hist[-1].histogram_value
    assert h.num == pytest.approx(4.0) and 0.03 <= h.min <= h.max <= 0.06


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_an_experiment_logs_each_run_to_its_own_folder(ray_cluster, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    logdir, out = tmp_path / "tb", tmp_path / "exp"
    assert main(["experiment", "likelihood", "--runs", "1", "--episodes", "2", "--particles", "4",
                 "--max-steps", "3", "--probe-trials", "2", "--no-progress", "--out", str(out),
                 "--set", "counterfactual_rows=0",
                 "--log-to", f"tensorboard:{logdir}"]) == 0
    runs = sorted(p.relative_to(logdir).as_posix() for p in logdir.glob("*/run0"))
    summary = json.loads((out / "likelihood.json").read_text())
    assert runs and len(runs) == len(summary["settings"]), (runs, list(summary["settings"]))
    for folder in runs:
        acc = EventAccumulator(str(logdir / folder))
        acc.Reload()
        assert [e.step for e in acc.Scalars("utility")] == [0, 1]
