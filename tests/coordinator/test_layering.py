"""The layering contract (pyproject.toml [tool.importlinter]) holds for the packages the
suite imports, and it catches an arrow added the wrong way.

api -> coordinator -> (planner | sim_workers): a module may import from its own layer and
the layers below; planner and sim_workers never import each other; the one exception is
``coordinator.commands.serve -> api`` (``tmoc serve`` starts the HTTP service). import-linter
(a ``test`` extra) reads the contract; it runs in a subprocess whose working directory is
put first on ``sys.path`` by the linter, so the tree it checks is chosen by that directory.
"""
from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("importlinter", reason="import-linter is a test extra: pip install '.[test]'")

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("api", "coordinator", "planner", "sim_workers")
CONTRACT = "api -> coordinator -> (planner | sim_workers)"

# Runs the linter and says where it found each package (the run must check what we mean).
_RUN = """
import importlib.util, sys
from importlinter.cli import lint_imports
for p in {packages!r}:
    print("ORIGIN", p, list(importlib.util.find_spec(p).submodule_search_locations)[0])
sys.exit(lint_imports(config_filename={config!r}, no_cache=True))
"""


def _origin(package: str) -> Path:
    return Path(list(importlib.util.find_spec(package).submodule_search_locations)[0]).resolve()


def _lint(cwd: Path, pythonpath: str | None) -> tuple[int, str, dict[str, Path]]:
    """Exit code, output and the packages' origins of one `lint-imports` run from `cwd`."""
    config = cwd / "importlinter.toml"
    shutil.copyfile(REPO / "pyproject.toml", config)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if pythonpath:
        env["PYTHONPATH"] = pythonpath
    proc = subprocess.run([sys.executable, "-c", _RUN.format(packages=PACKAGES, config=str(config))],
                          cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    out = proc.stdout + proc.stderr
    origins = {line.split()[1]: Path(line.split()[2]).resolve()
               for line in proc.stdout.splitlines() if line.startswith("ORIGIN ")}
    return proc.returncode, out, origins


def test_the_packages_the_suite_imports_keep_the_layering(tmp_path):
    """Linted where the suite imports from: the installed wheel (TMOC_TEST_SOURCE=1: the
    PYTHONPATH the session was started with)."""
    code, out, origins = _lint(tmp_path, os.environ.get("PYTHONPATH"))
    assert origins == {p: _origin(p) for p in PACKAGES}, out
    assert code == 0 and f"{CONTRACT} KEPT" in out, out
    assert "api imports neither sim_workers nor planner KEPT" in out, out


@pytest.fixture(scope="module")
def tree_copy(tmp_path_factory) -> Path:
    """The four packages as the suite imports them, copied (sources only) to a tmp dir."""
    root = tmp_path_factory.mktemp("layers")
    for p in PACKAGES:
        shutil.copytree(_origin(p), root / p, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    return root


WRONG_WAY = [
    ("planner/container/symbolic.py", "import coordinator", "planner is not allowed to import coordinator"),
    ("coordinator/loop/session.py", "import api", "coordinator is not allowed to import api"),
    ("sim_workers/probe.py", "from planner import symbolic", "sim_workers is not allowed to import planner"),
    ("planner/container/__init__.py", "import sim_workers.domains", "planner is not allowed to import sim_workers"),
]
ACROSS_THE_KIT = [
    ("sim_workers/stack_and_push/scene.py", "from sim_workers.container import scene",
     "a domain imports no other domain"),
    ("planner/stack_and_push/__init__.py", "from planner.container import model",
     "a domain imports no other domain"),
    ("coordinator/loop/session.py", "from planner.container import TASK", "the service imports no domain"),
    ("sim_workers/probe.py", "from sim_workers.container import probes", "the service imports no domain"),
    ("api/task_worker.py", "from sim_workers.engines import installed", "api imports neither sim_workers nor planner"),
]


def _with_imports(tree_copy: Path, tmp_path: Path, arrows: list[tuple[str, str, str]], why: str) -> Path:
    """A copy of the tree with each arrow's import appended to its module."""
    root = tmp_path / "tree"
    shutil.copytree(tree_copy, root)
    for module, added, _ in arrows:
        path = root / module
        path.write_text(path.read_text() + f"\n{added}  # {why}\n")
    return root


def _importer(module: str) -> str:
    return module[:-3].replace("/", ".").removesuffix(".__init__")


def test_an_arrow_the_wrong_way_breaks_the_contract(tree_copy, tmp_path):
    """Imports against the layering, appended to a copy (one linter run for all of them:
    it reports every illegal import): the contract is reported broken, naming the layers
    and each importing module."""
    root = _with_imports(tree_copy, tmp_path, WRONG_WAY, "against the layering")
    code, out, origins = _lint(root, str(root))
    assert origins["coordinator"] == (root / "coordinator").resolve(), out
    assert code == 1 and f"{CONTRACT} BROKEN" in out, out
    for module, _, message in WRONG_WAY:
        assert message in out and f"- {_importer(module)} -> " in out, (module, out)


def test_a_domain_import_across_the_kit_breaks_its_contract(tree_copy, tmp_path):
    """The built-in domains are siblings over the shared kits, and the loop, the API and the
    generic physics reach a domain only through the registry (issue 26): each import
    against either is reported, and the layering still holds."""
    root = _with_imports(tree_copy, tmp_path, ACROSS_THE_KIT, "against the domain kit")
    code, out, _ = _lint(root, str(root))
    assert code == 1 and f"{CONTRACT} KEPT" in out, out
    for module, added, contract in ACROSS_THE_KIT:
        assert f"{contract} BROKEN" in out, (contract, out)
        assert f"{_importer(module)} -> {added.split()[1]}" in out, (module, out)
