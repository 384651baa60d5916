"""TMP-RL's grounding, learned by trial and error without a model of L (issue 37).

The paper's TMP-RL improves by trial and error: it has no physics model of the objects'
properties, but it does learn from what worked. A fixed grounding at the prior mean (what
it did before) cannot learn at all where that grasp fails (every episode at 34 mm scored
-3900). Here the grounding is a bandit: the arms are K rows of L spread over the prior (arm
k at the quantile (k + 1/2) / K of every property and block), each action kind (pickup,
stack, push, ...) keeps a Beta(1 + successes, 1 + failures) per arm, and every action uses
the arm drawn by Thompson sampling (Thompson 1933; the arm whose sampled success rate is
highest). So TMP-RL tries groundings, keeps those that succeed for that kind of action,
and converges to one that works without ever modelling why: model-free, as the paper's
baseline, and slower than TMOC, which grounds from physics. Every draw comes from the
session's generator; the counts are checkpointed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["ARMS", "GroundingBandit"]

# Arms over the prior. Seven quantiles are 4.3 mm apart on the container's 30-60 mm prior,
# inside its grasp window (a grasp works within about +-8 mm of the size), so one arm
# always grasps; more arms would cost more failed tries to find it.
ARMS = 7


@dataclass
class GroundingBandit:
    """Beta counts per (action kind, arm) over ARMS rows of L; Thompson sampling."""

    low: np.ndarray
    high: np.ndarray
    counts: dict[str, list[list[float]]] = field(default_factory=dict)   # kind -> [[s, f] per arm]

    def __post_init__(self) -> None:
        self.low = np.asarray(self.low, dtype=np.float64).reshape(-1)
        self.high = np.asarray(self.high, dtype=np.float64).reshape(-1)

    def row(self, arm: int) -> np.ndarray:
        """Arm `arm`'s row of L: every entry at the quantile (arm + 1/2) / ARMS of its prior."""
        q = (int(arm) + 0.5) / ARMS
        return self.low + q * (self.high - self.low)

    def choose(self, kind: str, rng: np.random.Generator) -> int:
        """The arm to ground an action of `kind` with (Thompson sampling)."""
        c = np.asarray(self.counts.get(kind, [[0.0, 0.0]] * ARMS), dtype=np.float64)
        return int(np.argmax(rng.beta(1.0 + c[:, 0], 1.0 + c[:, 1])))

    def observe(self, kind: str, arm: int, success: bool) -> None:
        c = self.counts.setdefault(kind, [[0.0, 0.0] for _ in range(ARMS)])
        c[int(arm)][0 if success else 1] += 1.0

    def to_dict(self) -> dict:
        return {"counts": {k: [list(map(float, a)) for a in v] for k, v in sorted(self.counts.items())}}

    @classmethod
    def from_dict(cls, data: dict | None, low: np.ndarray, high: np.ndarray) -> "GroundingBandit":
        """From `to_dict` (None, a checkpoint from before: no counts yet)."""
        counts = {} if not data else {str(k): [list(map(float, a)) for a in v] for k, v in data["counts"].items()}
        return cls(low, high, counts)
