"""The suite itself, and the Ray workers it starts, import the installed package."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(os.environ.get("TMOC_TEST_SOURCE") == "1",
                                reason="TMOC_TEST_SOURCE=1: testing the source tree on purpose")


def _outside_checkout(path: str) -> bool:
    """Not from the checkout's source folders (a venv inside the checkout, as CI's
    .ci-venv, is an installed copy)."""
    where = Path(path).resolve()
    return not any(where.is_relative_to(REPO / pkg)
                   for pkg in ("planner", "sim_workers", "coordinator", "api"))


def test_the_test_process_imports_the_installed_packages():
    import api
    import coordinator
    import planner
    import sim_workers

    for module in (api, coordinator, planner, sim_workers):
        assert _outside_checkout(module.__file__), module.__file__


@pytest.mark.slow          # starts the session's Ray
def test_ray_workers_import_the_installed_packages(ray_cluster):
    ray = ray_cluster

    @ray.remote(num_cpus=0)
    def where() -> list[str]:
        import coordinator
        import sim_workers

        return [sim_workers.__file__, coordinator.__file__]

    for path in ray.get(where.remote()):
        assert _outside_checkout(path), path
