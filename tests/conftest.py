"""Session-wide set-up: the suite tests the *installed* distribution, on one real local Ray.

Why the checkout is kept off ``sys.path``: a suite that imports ``./coordinator`` passes
while the wheel a user installs lacks ``coordinator.commands`` (it happened: 404 green
tests, a broken ``tmoc``). pytest runs with ``--import-mode=importlib`` (pyproject.toml),
which adds no test directory to ``sys.path``; ``python -m pytest`` still adds the working
directory, so it is removed here, before any test module imports the packages, and the
session refuses to start if ``coordinator`` would still come from the checkout (an
editable install, say). Set ``TMOC_TEST_SOURCE=1`` to run against the source tree on
purpose (a developer's inner loop with ``pip install -e .``); CI never does.
"""
from __future__ import annotations

import importlib.util
import os
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("planner", "sim_workers", "coordinator", "api")

# Ray's dashboard and usage reporting are dead weight (and try the network) in tests.
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_DEDUP_LOGS", "0")


def _in_checkout(path: str) -> bool:
    try:
        return Path(path or ".").resolve() == REPO
    except OSError:
        return False


if os.environ.get("TMOC_TEST_SOURCE") != "1":
    sys.path[:] = [p for p in sys.path if not _in_checkout(p)]


def installed_origin(package: str) -> Path:
    """Where `package` is imported from (its directory), without importing it."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(f"{package} is not installed: run pip install '.[test]'")
    return Path(list(spec.submodule_search_locations)[0]).resolve()


def pytest_configure(config: pytest.Config) -> None:
    # pytest-xdist declares it; declared here too for a run without it (--strict-markers).
    config.addinivalue_line("markers", "xdist_group(name): the tests a pytest-xdist worker runs together")
    if os.environ.get("TMOC_TEST_SOURCE") == "1":
        return
    for package in PACKAGES:
        try:
            origin = installed_origin(package)
        except ModuleNotFoundError as exc:
            pytest.exit(str(exc), returncode=4)
        if origin == REPO / package:         # the source folder (a venv in the checkout is fine)
            pytest.exit(f"{package} would be imported from the checkout ({origin}), not from an "
                        "installed wheel: run pip install '.[test]' (not -e), or set "
                        "TMOC_TEST_SOURCE=1 to test the source tree on purpose", returncode=4)


@pytest.fixture(scope="session")
def neutral_cwd(tmp_path_factory) -> Path:
    """A working directory outside the checkout, for subprocesses and Ray's driver.

    Ray adds the driver's working directory to every worker's ``sys.path``; started from
    the repository root, actors would import the source tree, not the installed package.
    """
    return tmp_path_factory.mktemp("cwd")


# -- two workers (pytest-xdist), one Ray ------------------------------------------------
# The suite runs on two pytest-xdist workers (`-n 2`, with pyproject's --dist loadgroup). A
# group's tests run on one worker. Every module whose tests use the in-process Ray (the
# `ray_cluster` fixture) is one group, so the session still has one local cluster; the
# installed-product modules are one group (they share the wheel); any other module whose
# tests share a fixture wider than a test (module- or session-scoped: a server, a venv, a
# run) is a group of its own, so that the fixture is built once. The remaining tests share
# nothing and are scheduled one by one, which keeps the two workers' ends close. The Ray
# group is scheduled first: it is the longest unit.
RAY_GROUP = "ray"


def _shares_a_fixture(item: pytest.Item) -> bool:
    """Whether the test uses one of the suite's fixtures that outlives a test (pytest's
    own, such as tmp_path_factory, cost nothing to have on both workers)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return True
    return any(d.scope != "function" and d.baseid
               for defs in info.name2fixturedefs.values() for d in defs)


def _group(item: pytest.Item, ray_modules: set[str]) -> str | None:
    module = item.nodeid.split("::")[0]
    if module in ray_modules:
        return RAY_GROUP
    if module.startswith("tests/installed/"):
        return "installed"
    return module if _shares_a_fixture(item) else None


def _group_of(item: pytest.Item) -> str | None:
    mark = item.get_closest_marker("xdist_group")
    return mark.args[0] if mark is not None else None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    ray_modules = {it.nodeid.split("::")[0] for it in items if "ray_cluster" in it.fixturenames}
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            group = _group(item, ray_modules)
            if group is not None:
                item.add_marker(pytest.mark.xdist_group(group))
    if hasattr(config, "workerinput"):          # a pytest-xdist worker: the longest unit first
        items.sort(key=lambda it: _group_of(it) != RAY_GROUP)


def _ray_is_up() -> bool:
    ray = sys.modules.get("ray")
    return bool(ray is not None and ray.is_initialized())


@pytest.fixture(autouse=True)
def _ray_only_through_the_fixture(request):
    """A test that starts Ray in-process without asking for `ray_cluster` fails: it would
    start a second cluster on the other worker, and outside the fixture's neutral working
    directory Ray's workers could import the checkout instead of the installed package."""
    before = _ray_is_up()
    yield
    if not before and _ray_is_up() and "ray_cluster" not in request.fixturenames:
        pytest.fail(f"{request.node.nodeid} started Ray in-process without the ray_cluster "
                    "fixture: add @pytest.mark.usefixtures('ray_cluster')", pytrace=False)


@pytest.fixture(scope="session")
def ray_cluster(neutral_cwd):
    """A real `ray.init(num_cpus=2)`, shared by every test that asks for it."""
    import ray

    if not ray.is_initialized():
        here = os.getcwd()
        os.chdir(neutral_cwd)          # what Ray puts on the workers' sys.path
        try:
            # address "local": our own cluster, never one already running on the machine
            ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR",
                     log_to_driver=False)
        finally:
            os.chdir(here)
    yield ray
    ray.shutdown()


def tmoc_command() -> list[str]:
    """The installed console script `tmoc` (what a user runs), beside this interpreter."""
    script = Path(sys.executable).with_name("tmoc")
    return [str(script)] if script.exists() else [sys.executable, "-m", "coordinator.cli"]


def subprocess_cwd() -> str:
    """A directory outside the checkout for a subprocess (so `-m`/cwd cannot import it)."""
    return tempfile.gettempdir()
