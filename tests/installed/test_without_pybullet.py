"""Installed where pybullet has no wheel (issue 27): the package without pybullet.

pybullet ships wheels for CPython <= 3.11 only, so ``pip install .`` requires it only there
(an environment marker) and the default engine falls back to MuJoCo. Here a fresh venv
gets the wheel of this tree with ``--no-deps`` and every dependency it declares except
pybullet: every command works with the MuJoCo engine, and asking for pybullet fails in
one line naming the missing package.
"""
from __future__ import annotations

import json
import re
import subprocess
import zipfile
from pathlib import Path

import pytest

from tests.installed.test_installed_product import fresh_venv, run_in

pytestmark = [pytest.mark.timeout(1800), pytest.mark.slow]   # a venv of its own


def requirements(wheel: Path) -> list[str]:
    """The wheel's own dependencies (Requires-Dist without extras), as pip reads them."""
    with zipfile.ZipFile(wheel) as z:
        meta = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        lines = z.read(meta).decode().splitlines()
    reqs = [ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("Requires-Dist:")]
    return [r for r in reqs if "extra ==" not in r]


@pytest.fixture(scope="module")
def bare(tree_wheel, tmp_path_factory) -> dict:
    """A fresh venv: the wheel (--no-deps) and its dependencies but pybullet."""
    reqs = requirements(tree_wheel)
    kept = [r for r in reqs if re.split(r"[ ;<>=!~\[]", r, maxsplit=1)[0].lower() != "pybullet"]
    assert len(kept) == len(reqs) - 1, reqs          # pybullet is declared, once
    bindir, env = fresh_venv(tmp_path_factory.mktemp("nopybullet"))
    root = bindir.parents[1]
    python = str(bindir / "python")
    for args in (["--no-deps", str(tree_wheel)], kept):
        proc = subprocess.run([python, "-m", "pip", "install", "-q", *args], env=env, capture_output=True,
                              text=True, timeout=1500)
        assert proc.returncode == 0, proc.stderr[-3000:]
    away = root / "elsewhere"
    away.mkdir()
    return {"python": python, "tmoc": str(bindir / "tmoc"), "env": env, "cwd": away}


def test_pybullet_is_absent_and_mujoco_is_the_default(bare):
    proc = run_in(bare, [bare["python"], "-c", "import importlib.util as u; print(u.find_spec('pybullet'))"])
    assert proc.stdout.strip() == "None"
    proc = run_in(bare, [bare["python"], "-c", "from sim_workers.engines import default_engine; print(default_engine())"])
    assert proc.stdout.strip() == "mujoco", proc.stderr


def test_a_run_goes_in_mujoco(bare):
    out = bare["cwd"] / "one"
    proc = run_in(bare, [bare["tmoc"], "run", "--particles", "4", "--episodes", "1", "--max-steps", "6",
                         "--no-progress", "--out", str(out)], timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads((out / "result.json").read_text())
    assert result["runtime"]["engines"] == {"particles": "mujoco", "reality": "mujoco"}
    assert result["runtime"]["particle_actions"] > 0


def test_probe_check_domain_plan_and_domains_work(bare):
    probe = run_in(bare, [bare["tmoc"], "probe", "--action", "pickup", "--true-size", "0.045", "--trials", "2",
                          "--json"])
    assert probe.returncode == 0, probe.stderr[-2000:]
    assert json.loads(probe.stdout)["engine"] == "mujoco" and json.loads(probe.stdout)["successes"] == 2
    check = run_in(bare, [bare["tmoc"], "check-domain", "stack_and_push", "--no-ray"], timeout=600)
    assert check.returncode == 0, check.stdout[-2000:] + check.stderr[-2000:]
    assert "stack_and_push (mujoco): " in check.stdout
    for argv in (["domains"], ["plan", "--blocks", "3"]):
        proc = run_in(bare, [bare["tmoc"], *argv])
        assert proc.returncode == 0, (argv, proc.stderr[-2000:])


@pytest.mark.parametrize("argv", [["run", "--engine", "pybullet"], ["run", "--reality-engine", "pybullet"],
                                  ["probe", "--action", "pickup", "--true-size", "0.045", "--engine", "pybullet"],
                                  ["run", "--frames"]])
def test_asking_for_pybullet_fails_in_one_line_naming_it(bare, argv):
    proc = run_in(bare, [bare["tmoc"], *argv, *(["--out", str(bare["cwd"] / "x")] if argv[0] == "run" else [])])
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-2000:]
    assert "pybullet" in lines[0] and "Traceback" not in proc.stderr
