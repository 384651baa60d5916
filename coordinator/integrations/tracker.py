"""Experiment-tracker hooks (issue 28): `tmoc run --log-to tensorboard:DIR`.

Per episode, as TensorBoard scalars: utility, failed actions, actions, the particle count
per action (mean), each property of L's posterior mean and std, and T per context
(``T/<action>/<k>``); the posterior of each property of L as a histogram of the particles
weighted by the belief. The event files are TensorBoard's own format, written with its
writer (no TensorFlow): `tensorboard --logdir DIR` shows them, and any tool that reads
TensorBoard logs (its ``EventAccumulator``, MLflow's and W&B's importers) reads them.

The optional extra ``tmoc-service[tracker]`` installs TensorBoard.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..loop.observer import RunObserver

SCHEMES = ("tensorboard",)


class TrackerError(ValueError):
    """A --log-to value that cannot be used (names what is wrong)."""


def parse_log_to(value: str) -> tuple[str, Path]:
    """``"tensorboard:DIR"`` -> ("tensorboard", Path(DIR)); TrackerError otherwise."""
    scheme, sep, where = str(value).partition(":")
    if not sep or scheme not in SCHEMES or not where.strip():
        raise TrackerError(f"expected {'|'.join(SCHEMES)}:DIR, got {value!r}")
    return scheme, Path(where)


def open_tracker(value: str, run_name: str = "") -> "TensorBoardLog":
    """The tracker a --log-to value names (TrackerError if its library is missing)."""
    _, where = parse_log_to(value)
    try:
        return TensorBoardLog(where / run_name if run_name else where)
    except ImportError:
        raise TrackerError("tensorboard is not installed: pip install 'tmoc-service[tracker]'") from None


class TensorBoardLog(RunObserver):
    """One run's event file in `logdir`: an observer of the run (``on_episode``)."""

    def __init__(self, logdir: Path) -> None:
        from tensorboard.summary.writer.event_file_writer import EventFileWriter

        Path(logdir).mkdir(parents=True, exist_ok=True)
        self.logdir = Path(logdir)
        self._writer = EventFileWriter(str(logdir))

    def episode(self, record: dict, session) -> None:
        """Log one finished episode (``on_episode``'s record and the session)."""
        step = int(record["episode"])
        counts = record.get("particles_per_action") or []
        scalars = {"utility": record["utility"], "failures": sum(record["failures"].values()),
                   "actions": record["actions"], "delivered": record.get("delivered", 0)}
        if counts:
            scalars["particles_per_action"] = float(np.mean(counts))
        for name, p in record["posterior"].get("properties", {}).items():
            scalars[f"posterior/{name}/mean"] = p["mean"]
            scalars[f"posterior/{name}/std"] = p["std"]
        for row in session.transition_table():
            scalars[f"T/{row['action']}/{row['context']}"] = row["p"]
        self._scalars(step, scalars)
        if session.belief is not None:
            k = session.n_blocks if session.per_block else 1
            w = np.exp(session.belief.log_weights - np.max(session.belief.log_weights))
            for j, name in enumerate(session.L.names):
                values = session.belief.particles[:, j * k:(j + 1) * k].mean(axis=1)
                self._histogram(step, f"posterior/{name}", values, w)
        self._writer.flush()

    def on_episode(self, session, record: dict) -> None:
        self.episode(record, session)

    def _scalars(self, step: int, values: dict) -> None:
        from tensorboard.compat.proto.event_pb2 import Event
        from tensorboard.compat.proto.summary_pb2 import Summary

        summary = Summary(value=[Summary.Value(tag=t, simple_value=float(v)) for t, v in values.items()])
        self._writer.add_event(Event(wall_time=time.time(), step=step, summary=summary))

    def _histogram(self, step: int, tag: str, values: np.ndarray, weights: np.ndarray, bins: int = 30) -> None:
        from tensorboard.compat.proto.event_pb2 import Event
        from tensorboard.compat.proto.summary_pb2 import HistogramProto, Summary

        values = np.asarray(values, dtype=np.float64)
        weights = np.asarray(weights, dtype=np.float64) / np.sum(weights) * len(values)
        lo, hi = float(values.min()), float(values.max())
        edges = np.linspace(lo, hi if hi > lo else lo + 1e-9, bins + 1)
        counts, _ = np.histogram(values, bins=edges, weights=weights)
        hist = HistogramProto(min=lo, max=hi, num=float(weights.sum()), sum=float(np.dot(weights, values)),
                              sum_squares=float(np.dot(weights, values ** 2)),
                              bucket_limit=[float(e) for e in edges[1:]], bucket=[float(c) for c in counts])
        summary = Summary(value=[Summary.Value(tag=tag, histo=hist)])
        self._writer.add_event(Event(wall_time=time.time(), step=step, summary=summary))

    def close(self) -> None:
        """Flush and close the event file (again: nothing; the run closes its observers)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None
