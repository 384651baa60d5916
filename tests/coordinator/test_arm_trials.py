"""Probe trials done by an arm (issue 41): `tmoc probe --robot` and T* probed with the runs'
robot. Real pybullet worlds, the real arm planner (IK, joint-space search, toppra) and the
real servo tracking; an action the arm cannot do fails its trial."""
from __future__ import annotations

import json

import numpy as np
import pytest

from coordinator.cli import main
from coordinator.experiments.spec import Spec
from coordinator.experiments.true_T import t_star_params
from coordinator.loop.arm_trials import ArmForTrials, with_robot
from sim_workers.probe import probe, run_trial
from sim_workers.robots import robot
from sim_workers.robots.acting import arm_moves


class Watched(ArmForTrials):
    """The real trial arm, keeping what it planned and what the world was handed."""

    seen: list = []

    def track(self, domain, believed, rows, motion):
        tool, actual = super().track(domain, believed, rows, motion)
        Watched.seen.append((tool, actual))
        return tool, actual


def test_an_arm_plans_and_moves_in_every_action_of_a_trial():
    Watched.seen = []
    doing = with_robot("ur5e")
    with arm_moves(lambda: Watched("ur5e", doing)):
        r = probe("stack", 0.045, load_k=1, trials=1, seed=0, domain="container")
    assert r.successes == 1
    # a stack probe of one block is a pickup and a stack: the arm did both
    assert len(Watched.seen) == 2 and doing.actions == 2
    doing.check_used("container")
    arm = robot("ur5e")
    for tool, motion in Watched.seen:
        assert motion.robot == "ur5e" and motion.joints.shape[1] == 6
        assert np.all(motion.joints >= arm.low - 1e-9) and np.all(motion.joints <= arm.high + 1e-9)
        # the rows the world follows are where the tracked arm's tool went, on its clock
        assert tool[0, 0] <= motion.times[0] + 1e-9 and tool[-1, 0] >= motion.times[-1] - 1e-9


def test_a_trial_with_an_arm_depends_on_its_seed_alone():
    children = np.random.default_rng(4).spawn(2)
    again = np.random.default_rng(4).spawn(2)
    with with_robot("ur5e"):
        first = [run_trial("pickup", 0.045, 0.045, 1, rng, domain="container") for rng in children]
        alone = run_trial("pickup", 0.045, 0.045, 1, again[1], domain="container")
    assert first[1] == alone


def test_an_action_the_arm_cannot_do_fails_the_trial():
    """Stack-and-push's push with the closed fingers: the UR5e's wrist meets the tower on
    every branch (why an arm pushes with the open front finger, `options_for`)."""
    with with_robot("ur5e"):
        closed = probe("push", 0.045, load_k=3, trials=2, seed=0, domain="stack_and_push",
                       options={"push_open": False})
        opened = probe("push", 0.045, load_k=3, trials=2, seed=0, domain="stack_and_push",
                       options={"push_open": True})
    assert closed.successes == 0 and opened.successes == 2
    # the floating gripper pushes the same tower with its fingers closed
    assert probe("push", 0.045, load_k=3, trials=2, seed=0, domain="stack_and_push").successes == 2


def test_tmoc_probe_takes_the_robot(capsys):
    base = ["probe", "--domain", "stack_and_push", "--action", "push", "--load", "3", "--true-size", "0.045",
            "--trials", "1", "--json"]
    assert main(base + ["--robot", "ur5e"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["robot"] == "ur5e" and out["successes"] == 1      # pushed open-fingered, as the arm runs it
    assert main(base) == 0
    assert json.loads(capsys.readouterr().out)["robot"] == "gripper"
    assert main(base + ["--robot", "ur5f"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--robot: no robot 'ur5f' (known: gripper, ur5e" in err


@pytest.mark.parametrize("fields, robot_key", [({}, None), ({"robot": "gripper"}, None),
                                                ({"robot": "ur5e"}, "ur5e")])
def test_t_star_is_probed_by_the_runs_robot(fields, robot_key):
    spec = Spec(name="sweep", runs=1, episodes=1, particles=4, domain="stack_and_push", run_fields=fields)
    params = t_star_params(spec, n_blocks=4)
    assert params.get("robot") == robot_key
    # the gripper's T* keeps its parameters, so caches made before stay valid
    if robot_key is None:
        assert "robot" not in params


def test_an_arm_a_probe_never_let_act_is_named_not_ignored():
    """A domain's probe that does not act through grounded_world.act cannot be done by the
    arm: `tmoc probe --robot` and T* say so instead of probing the floating gripper."""
    idle = with_robot("ur5e")            # (one that did act: the first test above)
    with pytest.raises(ValueError, match="robot: the slide domain's probe does not run its actions through"):
        idle.check_used("slide")
    with_robot("gripper").check_used("slide")      # the floating gripper needs nothing
