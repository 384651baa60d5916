"""What watches a run: one observer mechanism (issue 39).

A run is watched for its step records (``tmoc export``, the task store), its pictures
(``coordinator.integrations.frames``), its per-episode checkpoints and progress (``tmoc run``,
experiments, the service's task worker) and its scalars (TensorBoard). Each of these is a
:class:`RunObserver` in the session's ``observers`` list; the session calls every observer's
``on_step`` after each real step and ``on_episode`` after each episode, in the order they
were added, and the driver calls ``close`` when the run ends. An observer reads the session
and never changes its state or draws from its generators, so a watched run has exactly the
episodes of an unwatched one.

``runner.run(on_episode=fn)`` is an :class:`EpisodeCallback` over the same list, and
``Session.step_records`` is the current episode's records as observers got them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .reality import Observation

# The session calls its observers, so they see it as `Session` without importing it (the
# session module imports this one).
Session = Any

__all__ = ["Prediction", "StepEvent", "RunObserver", "EpisodeCallback", "StepLog"]


@dataclass(frozen=True)
class Prediction:
    """What the particles predicted for one action: their end configurations (B, 5 + 7M),
    symbolic outcomes, weights *before* the action's update, whether each matched the real
    outcome (as the likelihood judged it) and their properties (rows of L)."""

    configurations: np.ndarray
    states: list
    weights: np.ndarray
    matched: np.ndarray
    rows: np.ndarray


@dataclass(frozen=True)
class StepEvent:
    """One real step, after the belief, the experience pool and T have taken it in."""

    episode: int
    step: int                       # 0-based within the episode
    action: str
    expected: frozenset[str]        # the planned effect
    observation: Observation      # what the robot observed after the action
    success: bool
    record: dict                    # the step record (coordinator.loop.step_record)
    prediction: Prediction | None   # the particles' predictions, for observers that ask for them


class RunObserver:
    """Base of everything that watches a run; every hook does nothing by default.

    Set ``wants_predictions`` to receive each step's particle predictions
    (``StepEvent.prediction``): the session copies them only when an observer asks."""

    wants_predictions: bool = False

    def on_step(self, session: Session, event: StepEvent) -> None:
        """After each real step."""

    def on_episode(self, session: Session, record: dict) -> None:
        """After each episode, at the episode boundary (``session.to_checkpoint()`` works)."""

    def close(self) -> None:
        """The run is over (or stopped); release what the observer holds."""


class EpisodeCallback(RunObserver):
    """``fn(record, session, checkpoint)`` after every episode, with a checkpoint from which
    ``runner.run(config, resume=checkpoint)`` continues exactly there: the session's own and
    what the driver adds (`extras()`: the reality's generator, the nodes' tally)."""

    def __init__(self, fn: Callable[[dict, Session, dict], None],
                 extras: Callable[[], dict] | None = None) -> None:
        self.fn, self.extras = fn, extras

    def on_episode(self, session: Session, record: dict) -> None:
        checkpoint = {"session": session.to_checkpoint(), **(self.extras() if self.extras else {})}
        self.fn(record, session, checkpoint)


class StepLog(RunObserver):
    """The run's step records an episode at a time: ``records`` holds every finished
    episode's (after `records` given, from a resumed run), and ``write(records)`` gets each
    episode's as it ends. A partial episode's records are not kept: a run resumes at an
    episode's start and would take those steps again."""

    def __init__(self, write: Callable[[list[dict]], None] | None = None,
                 records: list[dict] | None = None) -> None:
        self.records: list[dict] = list(records or [])
        self.write = write
        self._episode: list[dict] = []

    def on_step(self, session: Session, event: StepEvent) -> None:
        self._episode.append(event.record)

    def on_episode(self, session: Session, record: dict) -> None:
        done, self._episode = self._episode, []
        self.records.extend(done)
        if self.write is not None:
            self.write(done)
