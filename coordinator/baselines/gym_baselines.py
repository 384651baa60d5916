"""A learner that knows nothing of TMOC, run on the Gymnasium view (``coordinator.integrations.gym_env``):
tabular Q-learning over symbolic states, every action grounded at one fixed row of L (the
prior's mean unless told), epsilon-greedy among the actions the mask allows. It is the
yardstick docs/RESULTS.md sets TMOC against ("A Gymnasium agent on the same truth").
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np


@dataclass
class QRun:
    """What a Q-learning run did: the return of every learning episode and the table."""

    returns: list[float] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    reached_goal: list[bool] = field(default_factory=list)
    table: dict = field(default_factory=dict)


def _key(obs: dict) -> bytes:
    return np.asarray(obs["state"], dtype=np.int8).tobytes()


def tabular_q(env, episodes: int, rng: np.random.Generator, *, seed: int = 0, alpha: float = 0.5,
              gamma: float = 1.0, epsilon: float = 0.2, grounding=None, greedy: bool = False,
              table: dict | None = None) -> QRun:
    """Q-learning on `env` for `episodes` episodes (episode e resets with seed + e).

    Values start at 0 (optimistic: every reward of these domains but a delivery is a cost),
    so untried actions are tried. With `greedy` the table only acts (no exploration, no
    update): the policy it learnt, evaluated."""
    base = env.unwrapped
    row = base.prior_mean() if grounding is None else np.asarray(grounding, dtype=np.float64)
    n = len(base.actions)
    q = defaultdict(lambda: np.zeros(n))
    if table:
        q.update({k: v.copy() for k, v in table.items()})
    run = QRun()
    for e in range(int(episodes)):
        obs, info = env.reset(seed=seed + e)
        total, steps, done, goal = 0.0, 0, False, False
        while not done:
            s, valid = _key(obs), np.flatnonzero(info["action_mask"])
            if len(valid) == 0:
                break
            if not greedy and rng.random() < epsilon:
                a = int(rng.choice(valid))
            else:
                a = int(valid[np.argmax(q[s][valid])])
            obs, r, terminated, truncated, info = env.step({"action": a, "grounding": row})
            total, steps = total + r, steps + 1
            if not greedy:
                nxt = np.flatnonzero(info["action_mask"])
                future = 0.0 if terminated or len(nxt) == 0 else gamma * float(np.max(q[_key(obs)][nxt]))
                q[s][a] += alpha * (r + future - q[s][a])
            done, goal = terminated or truncated, terminated
        run.returns.append(total)
        run.steps.append(steps)
        run.reached_goal.append(goal)
    run.table = dict(q)
    return run
