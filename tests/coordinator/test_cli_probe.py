"""`tmoc probe` through coordinator.cli.main, in-process: exit codes, output, errors."""
from __future__ import annotations

import json

import pytest

from coordinator.cli import main

BASE = ["probe", "--domain", "container", "--true-size", "0.045", "--seed", "3"]


def test_pickup_json_has_the_rate_and_the_inputs(capsys):
    code = main(BASE + ["--action", "pickup", "--trials", "2", "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    data = json.loads(out)
    assert data["trials"] == 2 and data["success_rate"] == 1.0 and data["successes"] == 2
    assert data["action"] == "pickup" and data["domain"] == "container" and data["seed"] == 3
    assert data["true_size"] == 0.045 and data["believed_size"] == 0.045


def test_wrong_believed_size_fails_and_human_line(capsys):
    code = main(BASE + ["--action", "pickup", "--believed-size", "0.0315", "--trials", "2",
                        "--option", "grasp_clearance=0"])           # 1.15 sides: the fingers land on it
    out, _ = capsys.readouterr()
    assert code == 0
    assert out.count("\n") == 1
    assert "0/2 succeeded" in out and "success rate 0.000" in out and "believed 0.0315 m" in out


def test_an_option_reaches_the_probed_world(capsys):
    """--option sets the probed world's spec (the chute's truth is its `true_friction`)."""
    args = BASE + ["--action", "push", "--load", "2", "--trials", "2", "--json"]
    assert main(args + ["--option", "container_mass=0.3"]) == 0
    same = json.loads(capsys.readouterr().out)
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out) == same           # the default, given


def test_a_perception_error_reaches_y_and_only_y(capsys):
    """--perception-sigma: each action is planned from positions perceived with that std
    while the world acts in the truth. 0 is the exact probe of before, draw for draw; a
    camera off by centimetres lands the fingers on the blocks; a seed repeats its answer."""
    args = BASE + ["--action", "pickup", "--trials", "6", "--json"]
    runs = {}
    for sigma in ("0", "0.001", "0.03", "0.03"):
        assert main(args + ["--perception-sigma", sigma]) == 0
        runs.setdefault(sigma, []).append(json.loads(capsys.readouterr().out))
    assert main(args) == 0
    exact = json.loads(capsys.readouterr().out)
    assert exact["perception_sigma"] == 0.0 and runs["0"][0] == exact
    assert runs["0.001"][0]["successes"] == 6                  # 1 mm: inside the opening's margin
    assert runs["0.03"][0]["successes"] <= 3, runs["0.03"]    # 3 cm: the fingers meet the blocks
    assert runs["0.03"][0] == runs["0.03"][1]
    assert main(BASE + ["--action", "pickup", "--trials", "1", "--perception-sigma", "0.002"]) == 0
    assert "perception 2 mm" in capsys.readouterr().out


def test_a_block_lying_on_the_rail_is_probed_with_its_neighbours(capsys):
    """stack_and_push's rail_pickup: a block a topple left on the rail, --load 0-2 more
    lying beside it; other loads are refused naming --load."""
    args = ["probe", "--domain", "stack_and_push", "--action", "rail_pickup", "--true-size", "0.045",
            "--trials", "3", "--seed", "1", "--json"]
    for k in ("0", "2"):
        assert main(args + ["--load", k]) == 0
        data = json.loads(capsys.readouterr().out)
        assert data["action"] == "rail_pickup" and data["load"] == int(k) and data["successes"] == 3
    assert main(args + ["--load", "3"]) == 2
    err = capsys.readouterr().err
    assert "--load" in err and "0..2" in err


def test_push_with_load_same_seed_same_answer(capsys):
    args = BASE + ["--action", "push", "--load", "2", "--trials", "2", "--json"]
    assert main(args) == 0
    first = json.loads(capsys.readouterr().out)
    assert main(args) == 0
    assert json.loads(capsys.readouterr().out) == first
    assert first["load"] == 2 and 0.0 <= first["success_rate"] <= 1.0


@pytest.mark.parametrize("extra, flag", [
    (["--domain", "kitchen", "--action", "pickup"], "--domain"),
    (["--action", "jump"], "--action"),
    (["--action", "pickup", "--true-size", "-0.045"], "--true-size"),
    (["--action", "pickup", "--true-size", "5"], "--true-size"),
    (["--action", "pickup", "--true-size", "nan"], "--true-size"),
    (["--action", "pickup", "--believed-size", "0.001"], "--believed-size"),
    (["--action", "pickup", "--believed-size", "inf"], "--believed-size"),
    (["--action", "pickup", "--trials", "0"], "--trials"),
    (["--action", "pickup", "--trials", "-3"], "--trials"),
    (["--action", "push", "--load", "0"], "--load"),
    (["--action", "push", "--load", "9"], "--load"),
    (["--action", "stack", "--seed", "-1"], "--seed"),
    (["--action", "push", "--option", "no_such=1"], "--option"),
    (["--action", "push", "--option", "push_speed=fast"], "--option"),
    (["--action", "pickup", "--perception-sigma", "-0.001"], "--perception-sigma"),
    (["--action", "pickup", "--perception-sigma", "nan"], "--perception-sigma"),
    (["--action", "pickup", "--perception-sigma", "0.5"], "--perception-sigma"),
])
def test_bad_input_names_the_flag_and_exits_2(capsys, extra, flag):
    # Later flags override BASE's (argparse keeps the last value).
    code = main(BASE + ["--trials", "1"] + extra)
    out, err = capsys.readouterr()
    assert code == 2
    assert out == ""
    assert err.startswith("tmoc probe: error: ") and flag in err
    assert "Traceback" not in err and err.count("\n") == 1


@pytest.mark.parametrize("args", [
    ["probe", "--true-size", "0.045"],                                   # --action missing
    ["probe", "--action", "pickup", "--true-size", "big"],
    ["probe", "--action", "pickup", "--true-size", "0.045", "--trials", "many"],
    ["probe", "--action", "pickup", "--true-size", "0.045", "--load", "2.5"],
    ["probe", "--action", "pickup", "--true-size", "0.045", "--color", "red"],
])
def test_argparse_errors_exit_2(capsys, args):
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    assert "usage: tmoc" in capsys.readouterr().err


def test_help_lists_the_flags(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["probe", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for flag in ("--domain", "--action", "--true-size", "--believed-size", "--load", "--trials", "--seed", "--json",
                 "--perception-sigma"):
        assert flag in out


def test_believed_density_shows_what_a_light_grip_costs(capsys):
    """Mass in Y through the CLI: 45 mm blocks of 2400 kg/m^3 gripped for 1000 kg/m^3 slip
    out; gripped for the truth they hold. The JSON names both densities."""
    sp = ["probe", "--domain", "stack_and_push", "--true-size", "0.045", "--action", "pickup",
          "--true-density", "2400", "--trials", "3", "--json"]
    assert main(sp + ["--believed-density", "1000"]) == 0
    light = json.loads(capsys.readouterr().out)
    assert main(sp + ["--believed-density", "2400"]) == 0
    right = json.loads(capsys.readouterr().out)
    assert light["successes"] == 0 and right["successes"] == 3
    assert light["true_density"] == 2400.0 and light["believed_density"] == 1000.0


@pytest.mark.parametrize("extra, message", [
    (["--domain", "container", "--believed-density", "1000"],
     "--believed-density: the container domain's probe does not read a belief of density"),
    (["--domain", "stack_and_push", "--believed-density", "-5"], "--believed-density: -5.0 kg/m^3 is outside"),
    (["--domain", "stack_and_push", "--true-density", "nan"], "--true-density: nan is not a finite number"),
])
def test_bad_densities_exit_2_naming_the_flag(extra, message, capsys):
    code = main(["probe", "--true-size", "0.045", "--action", "pickup", "--trials", "1", *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err


def test_truth_and_belief_by_the_names_of_L(capsys):
    """Issue 39: `--truth NAME=V` / `--belief NAME=V` for any domain (`--true-size` and its
    kin are their aliases), the default truth without either, and what the probe would
    ignore refused by the flag the user typed."""
    base = ["probe", "--domain", "container", "--action", "pickup", "--trials", "2", "--seed", "3", "--json"]
    assert main(base) == 0                                     # the domain's default truth
    default = json.loads(capsys.readouterr().out)
    assert default["truth"] == {"size": 0.045} == default["belief"] and default["true_size"] == 0.045
    narrow = ["--option", "grasp_clearance=0"]                 # 1.15 sides: the fingers land on it
    assert main(base + ["--truth", "size=0.045", "--belief", "size=0.0315"] + narrow) == 0
    named = json.loads(capsys.readouterr().out)
    assert main(base + ["--true-size", "0.045", "--believed-size", "0.0315"] + narrow) == 0
    assert json.loads(capsys.readouterr().out) == named and named["successes"] == 0
    for extra, needle in ((["--truth", "mass=3"], "--truth mass: not a property of L"),
                          (["--belief", "size=0.5"], "--belief size: 0.5 m is outside"),
                          (["--truth", "size=abc"], "--truth size=abc: expected NAME=NUMBER"),
                          (["--true-size", "0.04", "--truth", "size=0.05"], "--true-size: 0.04 disagrees")):
        assert main(base + extra) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1, err
    sp = ["probe", "--domain", "stack_and_push", "--action", "push", "--load", "2", "--trials", "2", "--json",
          "--option", "unknown_density=true"]
    assert main(sp + ["--truth", "density=2400", "--belief", "density=1650"]) == 0
    by_name = json.loads(capsys.readouterr().out)
    assert main(sp + ["--true-density", "2400", "--believed-density", "1650"]) == 0
    assert json.loads(capsys.readouterr().out) == by_name
    assert by_name["truth"] == {"size": 0.045, "density": 2400.0} and by_name["belief"]["density"] == 1650.0
