"""`tmoc run`: bad arguments exit 2 naming the flag; a tiny real run writes its files."""
from __future__ import annotations

import json

import pytest

from coordinator.cli import main


@pytest.mark.parametrize("args, flag", [
    (["--particles", "0"], "--particles"),
    (["--episodes", "-1"], "--episodes"),
    (["--agent", "oracle"], "--agent"),
    (["--likelihood", "guess"], "--likelihood"),
    (["--true-size", "0.5"], "--true-size"),
    (["--domain", "kitchen"], "--domain"),
    (["--max-steps", "0"], "--max-steps"),
    (["--counterfactual", "-1"], "--counterfactual"),
    (["--counterfactual", "257"], "--counterfactual"),
])
def test_bad_arguments_exit_2_naming_the_flag(args, flag, capsys, tmp_path):
    assert main(["run", "--out", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err
    assert flag in err and "Traceback" not in err
    assert not (tmp_path / "result.json").exists()


def test_non_numeric_particles_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run", "--particles", "many"])
    assert exc.value.code == 2 and "--particles" in capsys.readouterr().err


@pytest.mark.slow          # the session's Ray
def test_a_tiny_run_writes_result_json_and_curve_png(ray_cluster, tmp_path, capsys):
    code = main(["run", "--particles", "4", "--episodes", "2", "--max-steps", "3", "--seed", "2",
                 "--out", str(tmp_path), "--no-progress"])
    assert code == 0
    result = json.loads((tmp_path / "result.json").read_text())
    assert set(result) >= {"config", "episodes", "summary", "runtime"}
    assert len(result["episodes"]) == 2
    # The default asks the worlds first: 4 rows x the container's 17 contexts an episode.
    assert result["config"]["counterfactual_rows"] == 4
    assert all(e["counterfactual_trials"] >= 4 * 17 for e in result["episodes"])
    for e in result["episodes"]:
        assert set(e) >= {"utility", "actions", "failures", "loads", "delivered", "posterior", "ess", "wall_s"}
        assert e["actions"] == 3 and set(e["posterior"]) >= {"size_mean", "size_std"}
    assert set(result["summary"]) >= {"mean_utility", "final_size_mean", "final_size_std", "transition"}
    assert len(result["summary"]["transition"]["push"]) == 8
    assert set(result["runtime"]) >= {"shards", "nodes", "particle_actions", "wall_s"}
    # Every action replays 4 particle worlds; a split belief's pose candidates and a
    # resample-move (issue 37) simulate more, and are counted too.
    assert sum(sum(e["particles_per_action"]) for e in result["episodes"]) == 4 * 2 * 3
    assert result["runtime"]["particle_actions"] >= 4 * 2 * 3
    png = (tmp_path / "curve.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert json.loads(capsys.readouterr().out)["result"].endswith("result.json")

    # Every real step in steps.jsonl; `tmoc export` writes them as MCAP, read back by mcap.
    steps = [json.loads(line) for line in (tmp_path / "steps.jsonl").read_text().splitlines()]
    assert [(s["episode"], s["step"]) for s in steps] == [(e, k) for e in range(2) for k in range(3)]
    assert steps[3]["belief"] != steps[0]["belief"]
    out = tmp_path / "run.mcap"
    assert main(["export", str(tmp_path), "-o", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["messages"] == {"/tmoc/step": 6, "/tmoc/trajectory": 6,
                                                               "/tmoc/episode": 2}
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        reader = make_reader(f)
        got = [(ch.topic, json.loads(m.data)) for _, ch, m in reader.iter_messages()]
    step_msgs = [m for t, m in got if t == "/tmoc/step"]
    assert [m["action"] for m in step_msgs] == [s["action"] for s in steps]
    assert [m["measurements"] for m in step_msgs] == [s["measurements"] for s in steps]
    trajs = [m for t, m in got if t == "/tmoc/trajectory"]
    assert trajs[2]["points"] == steps[2]["trajectory"]["points"]
    assert [m["utility"] for t, m in got if t == "/tmoc/episode"] == [e["utility"] for e in result["episodes"]]


def test_export_refuses_what_is_not_a_run_in_one_line(tmp_path, capsys):
    cases = [([str(tmp_path / "nowhere"), "-o", str(tmp_path / "x.mcap")], "run_dir"),
             ([str(tmp_path), "-o", str(tmp_path / "x.mcap")], "run_dir"),            # no result.json
             (["-o", str(tmp_path / "x.mcap")], "run_dir"),
             (["--session", "s_1", "-o", str(tmp_path / "x.mcap")], "--session"),
             (["--server", "http://127.0.0.1:9", "-o", str(tmp_path / "x.mcap")], "--server"),
             ([str(tmp_path), "-o", str(tmp_path / "no" / "x.mcap")], "--out")]
    for args, flag in cases:
        assert main(["export", *args]) == 2, args
        err = capsys.readouterr().err
        assert flag in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.mcap").exists()


GOOD_STEP = {"episode": 0, "step": 0, "action": "pickup(r,b1,init)", "time": 1.0,
             "trajectory": {"columns": ["t"], "points": [[0.0]]}}


@pytest.mark.parametrize("result, steps, named", [
    ("{", json.dumps(GOOD_STEP), "result.json: not JSON"),
    ("[]", json.dumps(GOOD_STEP), "result.json: not a JSON object"),
    ('{"episodes": 3}', json.dumps(GOOD_STEP), "'episodes' is not a list"),
    ('{"config": []}', json.dumps(GOOD_STEP), "'config' is not an object"),
    ("{}", json.dumps(GOOD_STEP) + "\n{oops", "steps.jsonl, line 2: not JSON"),
    ("{}", "[1, 2]", "steps.jsonl, line 1: not an object"),
    ("{}", json.dumps({**GOOD_STEP, "action": None}), "line 1: a step record with no 'action'"),
    ("{}", json.dumps({**GOOD_STEP, "trajectory": [1]}), "'trajectory' is not"),
    ("{}", json.dumps({**GOOD_STEP, "time": "noon"}), "'time' is not a number"),
    ("\udcff", json.dumps(GOOD_STEP), "unreadable"),
])
def test_export_over_malformed_run_files_is_one_line(tmp_path, capsys, result, steps, named):
    """Issue 38, row 12: five malformed run files gave five different tracebacks."""
    (tmp_path / "result.json").write_text(result, encoding="utf-8", errors="surrogateescape")
    (tmp_path / "steps.jsonl").write_text(steps, encoding="utf-8")
    assert main(["export", str(tmp_path), "-o", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert named in err and err.count("\n") == 1 and "Traceback" not in err, err
    assert not (tmp_path / "x.mcap").exists()


def test_config_file_then_flags_and_print_config(tmp_path, capsys):
    """Every setting reachable from a file (issue 16 item 5): settings without a flag
    (pose_rule, error_rate, use_measurements, costs) come from it; flags override it."""
    yaml_file = tmp_path / "run.yaml"
    yaml_file.write_text("agent: gp\nparticles: 12\npose_rule: mean\nerror_rate: 0.1\n"
                         "use_measurements: false\ncosts:\n  push: 20\n")
    assert main(["run", "--config", str(yaml_file), "--particles", "7", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert (cfg["agent"], cfg["particles"], cfg["pose_rule"], cfg["error_rate"]) == ("gp", 7, "mean", 0.1)
    assert cfg["use_measurements"] is False and cfg["costs"]["push"] == 20 and cfg["costs"]["stack"] == 10
    json_file = tmp_path / "run.json"
    json_file.write_text(json.dumps(cfg))           # the printed config is a valid --config
    assert main(["run", "--config", str(json_file), "--print-config"]) == 0
    assert json.loads(capsys.readouterr().out) == cfg
    assert main(["run", "--print-config"]) == 0      # the defaults
    assert json.loads(capsys.readouterr().out)["particles"] == 32


@pytest.mark.parametrize("content, needle", [
    ("particles: [1\n", "not valid YAML"),
    ("- 1\n- 2\n", "expected a mapping"),
    ("partcles: 3\n", "partcles"),
    ("pose_rule: median\n", "pose_rule"),
    ("costs:\n  jump: 3\n", "costs.jump"),
])
def test_a_bad_config_file_exits_2_naming_the_setting(tmp_path, capsys, content, needle):
    f = tmp_path / "bad.yaml"
    f.write_text(content)
    assert main(["run", "--config", str(f), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert f"--config {f}" in err and needle in err and "Traceback" not in err
    assert main(["run", "--config", str(tmp_path / "missing.json")]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_a_billion_laughs_config_is_refused_in_one_line(tmp_path, capsys):
    """Issue 25 row 10: 349 bytes of nested YAML aliases took 11 s and 830 MB (or a
    MemoryError traceback), and the error repeated the whole expanded input."""
    import time

    rows = ['a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]']
    rows += [f"{b}: &{b} [{','.join(['*' + a] * 9)}]" for a, b in zip("abcdefg", "bcdefgh")]
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("\n".join(rows) + "\nparticles: *h\n")
    t0 = time.perf_counter()
    assert main(["run", "--config", str(bomb), "--print-config"]) == 2
    assert time.perf_counter() - t0 < 2.0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "aliases" in err[0] and "line 2" in err[0], err
    big = tmp_path / "big.json"
    big.write_text('{"particles": "' + "x" * 5000 + '"}')
    assert main(["run", "--config", str(big), "--print-config"]) == 2
    err = capsys.readouterr().err
    assert "particles" in err and len(err) < 400, len(err)          # the value cut, not echoed
    huge = tmp_path / "huge.json"
    huge.write_bytes(b" " * ((1 << 20) + 1))
    assert main(["run", "--config", str(huge)]) == 2
    assert "not a settings file" in capsys.readouterr().err
