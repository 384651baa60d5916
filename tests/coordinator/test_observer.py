"""One observer mechanism (issue 39): whatever watches a run (pictures, step logs, checkpoints,
TensorBoard) is a ``RunObserver`` in the session's list, called after each step and each
episode and closed at the end; a watched run is the unwatched run, bit for bit."""
from __future__ import annotations

import json

import pytest

from coordinator.distributed.fanout import ShardPool
from coordinator.integrations.frames import FrameRecorder
from coordinator.integrations.tracker import TensorBoardLog
from coordinator.loop.observer import EpisodeCallback, RunObserver, StepEvent, StepLog
from coordinator.loop.runner import run
from coordinator.run_config import RunConfig


class Counting(RunObserver):
    def __init__(self, wants: bool) -> None:
        self.wants_predictions = wants
        self.events: list[tuple[str, object]] = []

    def on_step(self, session, event: StepEvent) -> None:
        self.events.append(("step", event))

    def on_episode(self, session, record: dict) -> None:
        # at the boundary: a checkpoint can be taken from here
        self.events.append(("episode", (record, session.to_checkpoint()["episode"])))

    def close(self) -> None:
        self.events.append(("close", None))


def _run(observers=(), on_episode=None) -> dict:
    cfg = RunConfig(particles=4, episodes=2, max_steps=2, seed=5, particle_budget="fixed", n_objects=2,
                    counterfactual_rows=0)     # what observers see, not T's prior
    pool = ShardPool(cfg.domain, {"n_blocks": cfg.n_blocks}, n_shards=0)
    try:
        return run(cfg, pool=pool, observers=observers, on_episode=on_episode)
    finally:
        pool.close()


def _results(result: dict) -> str:
    keep = [{k: v for k, v in e.items() if not k.endswith("_s")} for e in result["episodes"]]
    return json.dumps([keep, result["summary"]], sort_keys=True)


@pytest.fixture(scope="module")
def watched():
    """A run watched by an observer that asks for predictions, one that does not, a step log
    and an on_episode callback."""
    sees, blind, log, callbacks = Counting(True), Counting(False), StepLog(), []
    result = _run([sees, blind, log], on_episode=lambda rec, s, ck: callbacks.append((rec["episode"], ck)))
    return result, sees, blind, log, callbacks


def test_every_observer_sees_every_step_and_episode_in_order_and_is_closed(watched):
    result, plain, sees, log, callbacks = watched
    n_steps = sum(e["actions"] for e in result["episodes"])
    for obs in (plain, sees):
        kinds = [k for k, _ in obs.events]
        assert kinds.count("step") == n_steps > 0
        assert kinds.count("episode") == 2 and kinds[-1] == "close" and kinds.count("close") == 1
        # the episode's steps come before its end; the checkpoint is at the next episode
        first_end = kinds.index("episode")
        assert first_end == result["episodes"][0]["actions"]
        ends = [payload for k, payload in obs.events if k == "episode"]
        assert [(rec["episode"], at) for rec, at in ends] == [(0, 1), (1, 2)]
    steps = [e for k, e in plain.events if k == "step"]
    assert [(e.episode, e.step) for e in steps][:2] == [(0, 0), (0, 1)]
    assert all(e.record["action"] == e.action and e.record["success"] == e.success for e in steps)
    # the step log holds exactly what the observers were handed, episode by episode
    assert log.records == [e.record for e in steps]
    # the on_episode callback is one of them: a resumable checkpoint after every episode
    assert [ep for ep, _ in callbacks] == [0, 1]
    assert all({"session", "reality_rng", "nodes"} <= set(ck) for _, ck in callbacks)


def test_predictions_only_where_an_observer_asks_and_a_watched_run_is_the_unwatched_run(watched):
    result, sees, _, _, _ = watched
    steps = [e for k, e in sees.events if k == "step"]
    assert all(e.prediction is not None and len(e.prediction.weights) == 4 for e in steps)
    assert FrameRecorder.wants_predictions and not RunObserver.wants_predictions
    assert not TensorBoardLog.wants_predictions
    blind = Counting(False)
    assert _results(_run([blind])) == _results(result)
    assert all(e.prediction is None for k, e in blind.events if k == "step")


def test_an_episode_callback_adds_the_driver_s_state_to_the_session_s_checkpoint():
    got = []

    class FakeSession:
        def to_checkpoint(self):
            return {"episode": 3}

    EpisodeCallback(lambda rec, s, ck: got.append(ck), lambda: {"reality_rng": 7}).on_episode(FakeSession(), {})
    assert got == [{"session": {"episode": 3}, "reality_rng": 7}]
