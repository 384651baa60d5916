"""Session-wide fixtures: one real local Ray cluster of two CPUs for the whole test run."""
from __future__ import annotations

import os

import pytest

# Ray's dashboard and usage reporting are dead weight (and try the network) in tests.
os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_DEDUP_LOGS", "0")


@pytest.fixture(scope="session")
def ray_cluster():
    """A real `ray.init(num_cpus=2)`, shared by every test that asks for it."""
    import ray

    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR",
                 log_to_driver=False)
    yield ray
    ray.shutdown()
