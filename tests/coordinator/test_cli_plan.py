"""`tmoc plan`, run in-process through coordinator.cli.main."""
from __future__ import annotations

import json

import pytest

from coordinator.cli import main
from planner import symbolic

ONES = ",".join(["1"] * 8)
FALLING = "1,1,1,0.9,0.8,0.6,0.4,0.3"


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = main(["plan", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_plan_under_optimistic_T(capsys):
    code, out, err = run(capsys, "--domain", "container", "--blocks", "8", "--p-pickup", "1",
                         "--p-stack", ONES, "--p-push", ONES, "--json")
    assert code == 0, err
    data = json.loads(out)
    assert {"plan", "loads", "expected_utility", "optimal", "solve_ms"} <= set(data)
    assert data["loads"] == [8] and data["optimal"] is True
    assert data["expected_utility"] == pytest.approx(90.0)
    assert symbolic.is_goal(symbolic.validate_plan(symbolic.initial_state(8), data["plan"]))


def test_json_plan_splits_when_heavy_pushes_fail(capsys):
    code, out, _ = run(capsys, "--blocks", "8", "--p-pickup", "1", "--p-stack", ONES,
                       "--p-push", FALLING, "--json")
    assert code == 0
    data = json.loads(out)
    assert len(data["loads"]) > 1 and sum(data["loads"]) == 8
    assert data["plan"].count("push(r,c,goal,init)") == len(data["loads"]) - 1


def test_readable_listing(capsys):
    code, out, _ = run(capsys, "--blocks", "3", "--p-push", "1,1,0.2")
    assert code == 0
    assert "pickup(r,b1,init)" in out and "push(r,c,init,goal)" in out
    assert "expected utility:" in out and "loads:" in out and "optimal" in out
    assert not out.lstrip().startswith("{")


def test_plans_from_a_state_file(tmp_path, capsys):
    path = tmp_path / "state.lp"
    path.write_text("% mid-episode\nis_in(b1,goal). at_container(b2,c).\n"
                    "is_holding(r,b3)\nis_in(b4,table) is_in(c,init).\n")
    code, out, err = run(capsys, "--state", str(path), "--p-push", "1,1,0.5,0.2", "--json")
    assert code == 0, err
    data = json.loads(out)
    assert data["plan"][0] == "stack(r,b3,c)"
    assert "pickup(r,b4,table)" in data["plan"]
    state = symbolic.parse_state(path.read_text().split("\n", 1)[1])
    assert symbolic.is_goal(symbolic.validate_plan(state, data["plan"]))


def test_sizes_variation_per_class_pickup(capsys):
    code, out, _ = run(capsys, "--blocks", "8", "--class", "b5=large",
                       "--p-pickup", "block=1,large=0.5", "--json")
    assert code == 0
    # the large block's pickup is repeated until it holds: 1/0.5 attempts, one failing
    assert json.loads(out)["expected_utility"] == pytest.approx(90.0 - ((15 + 0.5 * 50) / 0.5 - 15))


@pytest.mark.parametrize("argv, named", [
    (["--blocks", "8", "--p-push", "1,1,1"], "--p-push: expected 8 probabilities"),
    (["--blocks", "8", "--p-stack", "1,1,1,1,1,1,1,1,1"], "--p-stack: expected 8 probabilities"),
    (["--blocks", "8", "--p-push", "1,1,1,1,1,1,1,1.5"], "--p-push[7]: probability 1.5"),
    (["--blocks", "2", "--p-pickup", "-0.5"], "--p-pickup: probability -0.5"),
    (["--blocks", "2", "--p-stack", "1,x"], "--p-stack: 'x' is not a number"),
    (["--domain", "kitchen"], "unknown domain 'kitchen'"),
    (["--blocks", "many"], "--blocks: 'many' is not an integer"),
    (["--blocks", "0"], "--blocks: 0 must be at least 1"),
    (["--blocks", "8", "--max-steps", "3"], "max_steps=3"),
    (["--blocks", "2", "--cost", "push=-1"], "--cost: 'push' must be a finite number >= 0"),
    (["--blocks", "2", "--class", "b7=large"], "unknown block 'b7'"),
])
def test_bad_input_is_named_with_exit_code_2(capsys, argv, named):
    code, out, err = run(capsys, *argv)
    assert code == 2
    assert named in err and "Traceback" not in err and out == ""


@pytest.mark.parametrize("text, named", [
    ("is_in(b1,init) is_in(b2,moon) hand_empty(r) is_in(c,init)", "is_in(b2,moon)"),
    ("is_in(b1,init) hand_empty(r) is_in(c,init) on(b1,b2)", "on(b1,b2)"),
    ("is_in(b1,init) garbage hand_empty(r) is_in(c,init)", "garbage"),
    ("is_in(b1,init) is_in(b3,init) hand_empty(r) is_in(c,init)", "b2 has no location"),
    ("is_holding(r,b1) is_in(c,goal)", "goal unreachable"),
])
def test_bad_state_files_are_named(tmp_path, capsys, text, named):
    path = tmp_path / "state.txt"
    path.write_text(text)
    code, _, err = run(capsys, "--state", str(path))
    assert code == 2 and named in err and "Traceback" not in err


def test_missing_state_file_and_block_mismatch(tmp_path, capsys):
    code, _, err = run(capsys, "--state", str(tmp_path / "nope.txt"))
    assert code == 2 and "cannot read" in err
    path = tmp_path / "state.txt"
    path.write_text("is_in(b1,init) is_in(b2,init) hand_empty(r) is_in(c,init)")
    code, _, err = run(capsys, "--state", str(path), "--blocks", "3")
    assert code == 2 and "does not match the 2 blocks" in err
