"""Plugins that fail alone (issue 38, finding 5): an installed domain plugin whose entry
point names a module that is not installed, one that declares `version: 0`, and one whose
physics half does not import are left out with their reasons; `tmoc domains` and `tmoc
serve` work, list them as broken, and every other domain is unaffected.

The plugins are installed as pip installs them (a ``.dist-info`` with ``entry_points.txt``
on the interpreter's path), and the real `tmoc` commands and server read them."""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import httpx
import pytest

from .conftest import Server, tmoc

ENTRY_POINTS = """[tmoc.domains]
ghost = tmoc_not_installed_anywhere:DOMAIN
zero = tmoc_broken_plugins:ZERO
hollow = tmoc_broken_plugins:HOLLOW
"""

MODULE = '''ZERO = {"physics": "sim_workers.container:ContainerDomain",
        "task": "planner.container:ContainerTask", "version": 0}
HOLLOW = {"physics": "tmoc_broken_plugins_physics_gone:Physics",
          "task": "planner.container:ContainerTask", "version": 2}
'''


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("broken-plugins")
    info = root / "tmoc_broken_plugins-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: tmoc-broken-plugins\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    (root / "tmoc_broken_plugins.py").write_text(MODULE)
    return root


def _env(path: Path) -> dict:
    return dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(path), os.environ.get("PYTHONPATH")])))


def _reasons_ok(broken: dict) -> None:
    assert set(broken) == {"ghost", "zero", "hollow"}, broken
    assert "tmoc_not_installed_anywhere" in broken["ghost"]
    assert "version 0" in broken["zero"]
    assert "tmoc_broken_plugins_physics_gone" in broken["hollow"]


@pytest.mark.slow
def test_tmoc_domains_lists_the_good_ones_and_the_broken_ones(plugin_path, tmp_path):
    proc = subprocess.run([*tmoc(), "domains", "--json"], env=_env(plugin_path), cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout)
    assert {"container", "stack_and_push"} <= set(out["domains"])
    _reasons_ok(out["broken"])
    # Logged once each, with the reason, not a traceback.
    assert "Traceback" not in proc.stderr
    assert proc.stderr.count("domain plugin 'ghost' left out") == 1, proc.stderr[-3000:]
    text = subprocess.run([*tmoc(), "domains"], env=_env(plugin_path), cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert text.returncode == 0 and "ghost  (broken plugin, left out)" in text.stdout
    assert "\ncontainer  (container-v1, builtin)" in "\n" + text.stdout


@pytest.mark.timeout(300)
@pytest.mark.slow
def test_the_service_starts_and_serves_every_other_domain(plugin_path, tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", _env(plugin_path)["PYTHONPATH"])
    server = Server(tmp_path / "tasks.db").start()
    try:
        h = server.headers
        assert httpx.get(f"{server.base}/health", timeout=10).status_code == 200
        listed = httpx.get(f"{server.base}/v1/domains", headers=h, timeout=60).json()
        served = {d["name"] for d in listed["items"]}
        assert {"container", "stack_and_push"} <= served and not served & {"ghost", "zero", "hollow"}
        _reasons_ok(listed["broken"])
        refused = httpx.post(f"{server.base}/v1/tasks", headers=h, timeout=30,
                             json={"domain": "ghost", "episodes": 1})
        assert refused.status_code == 422 and "domain" in refused.text
        assert httpx.get(f"{server.base}/v1/domains/stack_and_push", headers=h, timeout=60).status_code == 200
    finally:
        server.stop()


def test_the_registry_is_read_once_per_process():
    from coordinator.domains import names
    from sim_workers import domains as registry

    assert registry._scan() is registry._scan()          # one scan, kept
    assert names() == names()
