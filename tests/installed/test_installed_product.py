"""The product a user installs (issue 11): the wheel holds every module and data file of the
tree, and a fresh virtual environment built with the Docker image's own install steps runs
every `tmoc` command from a directory outside the checkout.

What these tests would have caught: a wheel without `coordinator.commands` (an explicit
package list that left out every subpackage) shipped while the whole suite passed, because
the suite imported the source tree. Here nothing is imported from the checkout: the wheel
is built from a copy, the fresh venv has no access to the test session's packages, and
every command runs with a temporary working directory.

The image cannot be built on these machines (no container engine), so its install steps
are performed instead: the files its `COPY` lines name become the build context, and its
`RUN ... pip install ...` line runs verbatim in bash with the fresh venv first on PATH.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
import zipfile
from pathlib import Path

import httpx
import pytest

from ..helpers import dockerfile_instructions

REPO = Path(__file__).resolve().parents[2]
DOCKERFILE = REPO / "deploy" / "Dockerfile"
PACKAGES = ("planner", "sim_workers", "coordinator", "api")
# Files a wheel never ships (build by-products); everything else under a package does.
_JUNK = re.compile(r"(__pycache__|\.pyc$|\.pyo$|\.egg-info)")
_TREE_IGNORE = shutil.ignore_patterns(".git", ".ci-venv", ".venv", "venv", "runs", "build",
                                      "dist", "*.egg-info", "__pycache__", ".pytest_cache")

pytestmark = [pytest.mark.slow, pytest.mark.timeout(1500)]


def package_files(root: Path) -> set[str]:
    """Every file under the four packages of a source tree, as wheel paths (a/b/c.py)."""
    files = set()
    for pkg in PACKAGES:
        for path in (root / pkg).rglob("*"):
            rel = path.relative_to(root).as_posix()
            if path.is_file() and not _JUNK.search(rel):
                files.add(rel)
    return files


def source_modules(root: Path) -> list[str]:
    """Dotted names of every Python module under the four packages of a source tree."""
    mods = []
    for rel in sorted(package_files(root)):
        if rel.endswith(".py"):
            name = rel[:-3].replace("/", ".")
            mods.append(name[: -len(".__init__")] if name.endswith(".__init__") else name)
    return mods


def build_wheel(source: Path, out: Path) -> Path:
    """`pip wheel` of `source` (isolated build, as `pip install .` does) into `out`."""
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out),
                           str(source)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (wheel,) = out.glob("tmoc_service-*.whl")
    return wheel


def wheel_files(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as z:
        return {n for n in z.namelist() if ".dist-info/" not in n}


@pytest.fixture(scope="module")
def docker_context(tmp_path_factory) -> Path:
    """The image's WORKDIR after its COPY lines: only the files the Dockerfile copies.

    Docker's rules: a file goes into a destination ending in `/` under its own name (else
    to the destination itself); a folder's *contents* go into the destination.
    """
    ctx = tmp_path_factory.mktemp("context")
    for op, args in dockerfile_instructions():
        if op != "COPY":
            continue
        *sources, dest = args.split()
        for src in sources:
            path = REPO / src
            if path.is_dir():
                shutil.copytree(path, ctx / dest, dirs_exist_ok=True,
                                ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
            elif dest.endswith("/"):
                (ctx / dest).mkdir(parents=True, exist_ok=True)
                shutil.copy2(path, ctx / dest / path.name)
            else:
                shutil.copy2(path, ctx / dest)
    return ctx


def fresh_venv(root: Path) -> tuple[Path, dict]:
    """A new venv under `root`: its bin folder and an environment that uses it and nothing
    of the test session's (no PYTHONPATH, token or Ray address)."""
    subprocess.run([sys.executable, "-m", "venv", str(root / "venv")], check=True, timeout=120)
    bindir = root / "venv" / "bin"
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "TMOC_API_TOKEN", "RAY_ADDRESS")}
    env.update(PATH=f"{bindir}{os.pathsep}{env.get('PATH', '')}", VIRTUAL_ENV=str(root / "venv"),
               RAY_USAGE_STATS_ENABLED="0", PIP_DISABLE_PIP_VERSION_CHECK="1")
    return bindir, env


@pytest.fixture(scope="module")
def venv(tmp_path_factory, docker_context) -> dict:
    """A fresh venv in which the image's `RUN ... pip install ...` line ran verbatim."""
    root = tmp_path_factory.mktemp("fresh")
    bindir, env = fresh_venv(root)
    install = [a for op, a in dockerfile_instructions() if op == "RUN" and "pip install" in a]
    assert len(install) == 1, install
    proc = subprocess.run(["bash", "-euo", "pipefail", "-c", install[0]], cwd=docker_context,
                          env=env, capture_output=True, text=True, timeout=1200)
    assert proc.returncode == 0, f"$ {install[0]}\n{proc.stdout[-3000:]}\n{proc.stderr[-4000:]}"
    away = root / "elsewhere"              # never the checkout, never the build context
    away.mkdir()
    python = str(bindir / "python")
    purelib = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                             env=env, cwd=away, capture_output=True, text=True, check=True).stdout.strip()
    return {"bin": bindir, "python": python, "tmoc": str(bindir / "tmoc"), "env": env,
            "cwd": away, "site": Path(purelib).resolve()}


def run_in(venv: dict, argv: list[str], timeout: float = 300, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=kw.pop("cwd", venv["cwd"]), env=venv["env"], capture_output=True,
                          text=True, timeout=timeout, **kw)


# -- the wheel ----------------------------------------------------------------------------
def test_the_wheel_holds_every_module_and_data_file_of_the_tree(tree_wheel):
    expected = package_files(REPO)
    shipped = wheel_files(tree_wheel)
    assert expected, "no package files found in the checkout"
    missing = sorted(expected - shipped)
    assert not missing, f"files of the tree missing from the wheel: {missing}"
    # Nothing but the four packages at the top (no tests/, benchmarks/, deploy/).
    assert {n.split("/")[0] for n in shipped} == set(PACKAGES)
    assert any(n.endswith(".lp") for n in shipped)      # the ASP encodings are package data


def test_the_dockerfile_copies_exactly_what_the_wheel_needs(tree_wheel, docker_context, tmp_path):
    copied = {src for op, a in dockerfile_instructions() if op == "COPY" for src in a.split()[:-1]}
    top = {n.split("/")[0] for n in wheel_files(tree_wheel)}
    assert copied == {"pyproject.toml", "README.md"} | top, copied
    # ...and the wheel built from that context is the wheel of the whole tree.
    assert wheel_files(build_wheel(docker_context, tmp_path)) == wheel_files(tree_wheel)


# -- the fresh venv, as a user (or the image) has it --------------------------------------
def test_every_module_imports_from_the_installed_copy(venv):
    modules = source_modules(REPO)
    script = (
        "import importlib, json, sys\n"
        "from pathlib import Path\n"
        "site = Path(sys.argv[1]).resolve()\n"
        "bad = {}\n"
        "for name in json.loads(sys.argv[2]):\n"
        "    try:\n"
        "        m = importlib.import_module(name)\n"
        "        where = Path(m.__file__).resolve()\n"
        "        if not where.is_relative_to(site):\n"
        "            bad[name] = f'imported from {where}'\n"
        "    except Exception as exc:\n"
        "        bad[name] = f'{type(exc).__name__}: {exc}'\n"
        "import planner.task_planner as tp\n"
        "if not Path(tp.ENCODING).is_file(): bad['planner/asp'] = 'encoding missing'\n"
        "print(json.dumps(bad))\n")
    proc = run_in(venv, [venv["python"], "-c", script, str(venv["site"]), json.dumps(modules)])
    assert proc.returncode == 0, proc.stderr[-3000:]
    bad = json.loads(proc.stdout.strip().splitlines()[-1])
    # A module of an optional extra (the Gymnasium view) may refuse, naming the extra that
    # installs what it needs; the image installs the core only.
    extras = set(tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"])
    named = {m: re.search(r"^ImportError: .*pip install 'tmoc-service\[(\w+)\]'", why) for m, why in bad.items()}
    assert {m: why for m, why in bad.items() if not (named[m] and named[m][1] in extras)} == {}
    assert set(bad) <= {"coordinator.integrations.gym_env", "coordinator.baselines.gym_baselines"}
    assert len(modules) > 30 and "coordinator.commands.run" in modules


def test_the_image_steps_pin_ray_default_at_the_installed_ray(venv):
    script = ("import importlib.metadata as md, ray, aiohttp\n"
              "print(ray.__version__, md.version('ray'), ray.__file__)")
    proc = run_in(venv, [venv["python"], "-c", script])
    assert proc.returncode == 0, proc.stderr[-2000:]       # aiohttp: ray[default]'s dashboard
    imported, dist, where = proc.stdout.split()
    assert imported == dist and Path(where).resolve().is_relative_to(venv["site"])
    check = run_in(venv, [venv["python"], "-m", "pip", "check"])
    assert check.returncode == 0, check.stdout


def test_tmoc_help_and_every_command_help_from_anywhere(venv):
    proc = run_in(venv, [venv["python"], "-c", "from coordinator.cli import COMMAND_MODULES as C; print(*C)"])
    commands = [m.replace("_", "-") for m in proc.stdout.split()]     # check_domain -> check-domain
    assert "run" in commands and "serve" in commands, proc.stderr
    top = run_in(venv, [venv["tmoc"], "--help"])
    assert top.returncode == 0, top.stderr
    for cmd in commands:
        assert cmd in top.stdout
        sub = run_in(venv, [venv["tmoc"], cmd, "--help"])
        assert sub.returncode == 0 and "usage: tmoc " + cmd in sub.stdout, (cmd, sub.stderr[-2000:])
    bad = run_in(venv, [venv["tmoc"], "run", "--particles", "0"])
    assert bad.returncode == 2 and "--particles" in bad.stderr and "Traceback" not in bad.stderr


def test_a_one_episode_run_from_outside_the_checkout(venv):
    out = venv["cwd"] / "one"
    proc = run_in(venv, [venv["tmoc"], "run", "--particles", "4", "--episodes", "1", "--max-steps", "6",
                         "--seed", "3", "--no-progress", "--out", str(out)], timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    result = json.loads((out / "result.json").read_text())
    assert len(result["episodes"]) == 1 and result["config"]["particles"] == 4
    assert 0 < result["episodes"][0]["actions"] <= 6
    assert (out / "curve.png").stat().st_size > 1000


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def served(venv: dict, name: str):
    """`tmoc serve` from the venv on a free port, its own database and log: yields (base URL,
    health JSON or None if it never answered, the log's path); stopped, Ray's helpers too."""
    port = _free_port()
    log = venv["cwd"] / f"{name}.log"
    with open(log, "w") as fh:
        proc = subprocess.Popen([venv["tmoc"], "serve", "--port", str(port), "--db",
                                 str(venv["cwd"] / f"{name}.sqlite"), "--log-level", "warning"],
                                cwd=venv["cwd"], env=venv["env"], stdout=fh, stderr=subprocess.STDOUT,
                                start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline, health = time.monotonic() + 120, None
        while time.monotonic() < deadline and proc.poll() is None:
            try:
                r = httpx.get(f"{base}/health", timeout=2)
                if r.status_code == 200:
                    health = r.json()
                    break
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        yield base, health, log
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(40)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)      # Ray's helpers share the group
        except (ProcessLookupError, PermissionError):
            pass


def test_tmoc_serve_answers_health(venv):
    with served(venv, "serve") as (_, health, log):
        assert health is not None, log.read_text()[-4000:]
        assert health["status"] == "ok" and health["auth"] is False


# -- a domain plugin from outside the package (issue 13) ----------------------------------
PLUGIN = REPO / "docs" / "examples" / "tmoc-toy-domain"


@pytest.fixture(scope="module")
def with_plugin(venv, tmp_path_factory) -> dict:
    """The example plugin pip-installed into the fresh venv (a copy: pip builds in place)."""
    src = tmp_path_factory.mktemp("plugin") / "tmoc-toy-domain"
    shutil.copytree(PLUGIN, src, ignore=_TREE_IGNORE)
    proc = run_in(venv, [venv["python"], "-m", "pip", "install", "-q", "--no-deps", str(src)], timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return venv


def test_the_plugin_is_found_through_its_entry_point(with_plugin):
    proc = run_in(with_plugin, [with_plugin["tmoc"], "domains", "--json"])
    assert proc.returncode == 0, proc.stderr[-2000:]
    found = json.loads(proc.stdout)["domains"]
    assert {"container", "toy_tray"} <= set(found)
    toy = found["toy_tray"]
    assert toy["source"] == "plugin (tmoc-toy-domain)" and toy["utility"]["pickup"] == 10.0
    assert toy["version"] == 1 and toy["id"] == "toy_tray-v1"
    assert toy["physics"] == "tmoc_toy_domain.physics:ToyTrayPhysics"


def test_the_plugin_passes_check_domain_with_ray_actors(with_plugin):
    proc = run_in(with_plugin, [with_plugin["tmoc"], "check-domain", "toy_tray"], timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    from coordinator.conformance import CHECKS

    assert f"toy_tray (pybullet): {len(CHECKS)}/{len(CHECKS)} checks passed" in proc.stdout
    assert "ok   y_batch" in proc.stdout          # the plugin's vectorised Y, bit for bit


def test_the_plugin_runs_one_episode(with_plugin):
    out = with_plugin["cwd"] / "toy"
    proc = run_in(with_plugin, [with_plugin["tmoc"], "run", "--domain", "toy_tray", "--particles", "4",
                                "--episodes", "1", "--max-steps", "8", "--seed", "2", "--no-progress",
                                "--out", str(out)], timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    result = json.loads((out / "result.json").read_text())
    assert result["config"]["domain"] == "toy_tray" and len(result["episodes"]) == 1
    assert result["config"]["n_blocks"] == 4          # the domain's own count (issue 39: was 8)
    assert 0 < result["episodes"][0]["actions"] <= 8


# -- a domain that is not a block world, as a plugin (issue 26) ---------------------------
CHUTE = REPO / "docs" / "examples" / "tmoc-chute-domain"


@pytest.fixture(scope="module")
def with_chute(venv, tmp_path_factory) -> dict:
    """The chute plugin pip-installed into the fresh venv (a copy: pip builds in place)."""
    src = tmp_path_factory.mktemp("chute") / "tmoc-chute-domain"
    shutil.copytree(CHUTE, src, ignore=_TREE_IGNORE)
    proc = run_in(venv, [venv["python"], "-m", "pip", "install", "-q", "--no-deps", str(src)], timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return venv


def test_the_chute_passes_check_domain_from_a_fresh_venv(with_chute):
    proc = run_in(with_chute, [with_chute["tmoc"], "check-domain", "chute"], timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    from coordinator.conformance import CHECKS

    assert f"chute (pybullet): {len(CHECKS)}/{len(CHECKS)} checks passed" in proc.stdout
    assert "5 values of friction across the prior" in proc.stdout
    found = json.loads(run_in(with_chute, [with_chute["tmoc"], "domains", "--json"]).stdout)["domains"]
    assert found["chute"]["source"] == "plugin (tmoc-chute-domain)"
    assert [p["name"] for p in found["chute"]["properties"]] == ["friction"]
    # Its probes: a train of 4 goes through at friction 0.3 and stalls at 0.7 (the cap).
    rates = {}
    for mu in (0.3, 0.7):
        proc = run_in(with_chute, [with_chute["tmoc"], "probe", "--domain", "chute", "--action", "sweep",
                                   "--truth", f"friction={mu}", "--load", "4", "--trials", "3", "--json"],
                      timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        rates[mu] = json.loads(proc.stdout)["success_rate"]
    assert rates == {0.3: 1.0, 0.7: 0.0}, rates
    # L has no size: a size is refused by name, in one line, exit 2; so is a bad friction.
    for argv, field in ((["--true-size", "0.05"], "true_size"), (["--truth", "size=0.04"], "truth.size"),
                        (["--truth", "friction=3"], "truth.friction")):
        proc = run_in(with_chute, [with_chute["tmoc"], "run", "--domain", "chute", *argv, "--out", "x"])
        lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("tmoc run: error")]
        assert proc.returncode == 2 and len(lines) == 1 and field in lines[0], proc.stderr[-2000:]


def test_the_chute_learns_its_friction_with_tmoc_run(with_chute):
    """Three episodes at friction 0.6 (a train of 5 stalls, 4 goes through): the posterior
    finds the friction and the last episode earns more than the first. Six pucks, not the
    domain's eight: the same lesson (a train of 5 or 6 stalls) at 0.4x the cost (108 s
    against 272 s on 2 cores, measured; seeds 1 and 2 end at 0.64 +- 0.03 and 0.65 +- 0.04)."""
    out = with_chute["cwd"] / "chute"
    proc = run_in(with_chute, [with_chute["tmoc"], "run", "--domain", "chute", "--truth", "friction=0.6",
                               "--particles", "8", "--episodes", "3", "--seed", "2", "--objects", "6",
                               "--no-progress", "--out", str(out)], timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    result = json.loads((out / "result.json").read_text())
    post = result["summary"]["posterior"]["friction"]
    assert abs(post["mean"] - 0.6) < 0.08 and post["std"] < 0.05, post
    u = [e["utility"] for e in result["episodes"]]
    assert u[-1] > u[0] and result["summary"]["final_size_mean"] is None, u
    assert result["config"]["n_blocks"] == 6
    assert result["summary"]["transition"]["sweep"][0] > 0.9     # a single puck always goes


def test_the_chute_runs_over_http(with_chute):
    with served(with_chute, "serve-chute") as (base, health, log):
        assert health is not None, log.read_text()[-4000:]
        bad = httpx.post(f"{base}/v1/tasks", json={"domain": "chute", "truth": {"friction": 5.0}}, timeout=30)
        assert bad.status_code == 422 and "friction" in bad.text, bad.text
        r = httpx.post(f"{base}/v1/tasks", timeout=30, json={
            "domain": "chute", "particles": 4, "episodes": 2, "max_steps": 12, "seed": 3, "n_objects": 5,
            "truth": {"friction": 0.6}, "options": {"sweep_force": 5.0}})
        assert r.status_code == 202, r.text
        task = r.json()
        deadline, view = time.monotonic() + 600, None
        while time.monotonic() < deadline:
            view = httpx.get(f"{base}/v1/tasks/{task['id']}", timeout=30).json()
            if view["status"] in ("succeeded", "failed"):
                break
            time.sleep(1.0)
        assert view["status"] == "succeeded", (view, log.read_text()[-3000:])
        assert view["spec"]["domain"] == "chute" and view["progress"]["episodes_done"] == 2
        assert view["spec"]["n_blocks"] == 5, view["spec"]       # five pucks: a train of 5 stalls
        post = view["latest"]["posterior"]["properties"]["friction"]
        assert 0.15 <= post["mean"] <= 0.75 and post["std"] < 0.17, post


# -- the smallest example domain (issue 39) ------------------------------------------------
SLIDE = REPO / "docs" / "examples" / "tmoc-slide-domain"


def test_the_slide_passes_check_domain_with_ray_actors_from_a_fresh_venv(venv, tmp_path_factory):
    """Installed, its Ray actors import it too (the checkout's tests check it in-process)."""
    src = tmp_path_factory.mktemp("slide") / "tmoc-slide-domain"
    shutil.copytree(SLIDE, src, ignore=_TREE_IGNORE)
    proc = run_in(venv, [venv["python"], "-m", "pip", "install", "-q", "--no-deps", str(src)], timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    from coordinator.conformance import CHECKS

    for engine in ("pybullet", "mujoco"):
        proc = run_in(venv, [venv["tmoc"], "check-domain", "slide", "--engine", engine], timeout=600)
        assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
        assert f"slide ({engine}): {len(CHECKS)}/{len(CHECKS)} checks passed" in proc.stdout
