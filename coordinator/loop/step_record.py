"""What one step of the loop leaves behind for the tools that read robot data (issue 28):
the action, the trajectory the robot was commanded, the observed configurations before
and after, the measurements, the outcome and the belief's summary after the update.

``Session.observe`` makes one per real step; ``tmoc run`` streams them to
``OUT/steps.jsonl``, the service keeps them per task and session, and
``coordinator.integrations.export`` writes them as MCAP. Plain JSON-able values (NaN, a channel that
did not measure, as null), so that a record survives any store unchanged.
"""
from __future__ import annotations

import math
import time

import numpy as np

from sim_workers.trajectory import columns_of

RECORD_VERSION = 1
STEPS_FILE = "steps.jsonl"      # a run directory's step records, one JSON object a line


def _floats(values) -> list:
    return [None if not math.isfinite(v) else float(v) for v in np.asarray(values, dtype=np.float64).reshape(-1)]


def step_record(*, episode: int, step: int, action: str, pose: np.ndarray, trajectory: np.ndarray,
                before, after, expected: frozenset[str], success: bool, belief: dict,
                object_names: list[str], channels: list[str], transit_end: float = 0.0) -> dict:
    """One step as a JSON-able dict (`before`/`after`: observations with configuration,
    state and measurements; `belief`: ``Session.posterior()`` after the update;
    `transit_end`: where the particle worlds started the trajectory, the checked transit's
    end or 0, what an offline re-filter needs to replay the step as the session did)."""
    return {
        "version": RECORD_VERSION,
        "time": time.time(),
        "episode": int(episode),
        "step": int(step),
        "action": action,
        "pose": _floats(pose),
        "trajectory": {"columns": list(columns_of(trajectory)),
                       "points": [_floats(row) for row in np.asarray(trajectory)]},
        "transit_end": float(transit_end),
        "objects": list(object_names),
        "configuration_before": _floats(before.configuration.to_array()),
        "configuration_after": _floats(after.configuration.to_array()),
        "state_before": sorted(before.state),
        "state_after": sorted(after.state),
        "expected": sorted(expected),
        "success": bool(success),
        "measurement_channels": list(channels),
        "measurements": _floats(after.measurements),
        "belief": belief,
    }
