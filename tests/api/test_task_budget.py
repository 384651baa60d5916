"""The per-task budget's bookkeeping (issue 25, row 4): the time spent before a restart
counts, the server's cap bounds what a task asks for."""
from __future__ import annotations

from api.task_worker import _Budget


def test_the_server_cap_bounds_what_a_task_asks_for():
    assert _Budget(None, 60.0, None).limit == 60.0
    assert _Budget(10.0, 60.0, None).limit == 10.0
    assert _Budget(600.0, 60.0, None).limit == 60.0     # a cap lowered after it was queued


def test_time_spent_before_a_restart_counts():
    fresh = _Budget(100.0, 3600.0, {"task_runtime_s": 99.0})
    assert not fresh.over()
    fresh.t0 -= 1.1                  # 1.1 s of this run's time, on its monotonic clock
    assert fresh.over() and fresh.spent() >= 100.0
    # a checkpoint of an older version carries no time, or garbage: counted from zero
    assert _Budget(100.0, 3600.0, {}).spent() < 1.0
    assert _Budget(100.0, 3600.0, {"task_runtime_s": "x"}).spent() < 1.0
