"""The suite's two workers keep its groups (tests/conftest.py): pytest-xdist's `loadgroup`
sends a group's tests to one worker by a suffix it puts on each test's id on the worker
(`...::test@group`). pytest 9.2 keeps the id where pytest-xdist 3.8 no longer sets it: every
test became a unit of its own, the in-process Ray tests ran on both workers (two local
clusters of 2 CPUs on 2 cores) and module fixtures were built on each (the installed venv
twice, 50 s each). pyproject.toml pins pytest below 9.2; this fails if the groups are lost
again."""
from __future__ import annotations

import pytest


def _on_a_worker(request) -> None:
    if not hasattr(request.config, "workerinput") or not request.config.getvalue("loadgroup"):
        pytest.skip("in one process: no pytest-xdist worker, nothing to group")


@pytest.mark.xdist_group("tests/test_xdist_groups.py")
def test_a_test_knows_its_group_on_a_worker(request):
    _on_a_worker(request)
    here = "tests/test_xdist_groups.py"
    assert request.node.nodeid == f"{here}::test_a_test_knows_its_group_on_a_worker@{here}", request.node.nodeid


@pytest.fixture(scope="module")
def shared() -> list:
    return []


def test_a_test_sharing_a_module_fixture_runs_in_its_module_s_group(request, shared):
    _on_a_worker(request)
    here = "tests/test_xdist_groups.py"
    assert request.node.nodeid.endswith(f"@{here}"), request.node.nodeid


def test_a_test_that_shares_nothing_is_a_unit_of_its_own(request, tmp_path):
    # scheduled by itself, so that the two workers' ends stay close (tests/conftest.py)
    _on_a_worker(request)
    assert "@" not in request.node.nodeid, request.node.nodeid
