"""A context that fails in reality only (issue 24): the particle worlds keep predicting
success there, yet T follows the real outcomes and the planner stops using the context
within an episode. Real pybullet, clingo and the session's two-CPU Ray."""
from __future__ import annotations

import numpy as np
import pytest

from coordinator.loop.reality import ContextFailure
from coordinator.run_config import RunConfig
from coordinator.loop.runner import run

@pytest.mark.usefixtures("ray_cluster")
@pytest.mark.slow
@pytest.mark.timeout(600)       # 33 s measured on 2 loaded cores
def test_a_reality_only_failure_is_learned_within_an_episode():
    # Four blocks, stacks onto two or more fail in reality only: the optimum is 2 + 2.
    cfg = RunConfig(agent="tmoc", n_blocks=4, particles=8, episodes=2, seed=3, max_steps=40,
                    particle_budget="fixed", reality_fail="stack:2", counterfactual_rows=0)   # the paper's loop
    result = run(cfg)
    first, second = result["episodes"]
    assert first["plans"][0] == [4]                       # the optimistic start tries one trip
    assert first["failures"].get("stack", 0) >= 1         # ... and meets the gap
    assert max(first["plans"][-1]) <= 2                   # replanned within episode 1
    assert all(max(p) <= 2 for p in second["plans"]) and not second["failures"], second
    assert second["delivered"] == 4
    T = result["summary"]["transition"]
    # The gap stands out: a real stack onto 0 or 1 blocks can still fail by chance in the
    # noisy reality (one of five onto 1 at this seed with the kernel from the ESS), so the
    # contexts below keep a high T, not exactly 1.
    assert T["stack"][2] < 0.5 and min(T["stack"][:2]) > 0.8, T["stack"]


def test_context_failure_parses_and_applies():
    f = ContextFailure.parse("stack:3")
    assert f.applies(("stack", 3)) and f.applies(("stack", 7))
    assert not f.applies(("stack", 2)) and not f.applies(("push", 3)) and not f.applies(None)
    assert ContextFailure.parse("push").applies(("push", 1))
    for bad in ("stack:x", "3:stack", "", "stack:-1"):
        with pytest.raises(ValueError, match="ACTION:K"):
            ContextFailure.parse(bad)
    assert RunConfig(reality_fail="stack:9").reality_fail == "stack:9"     # never applies
    with pytest.raises(ValueError, match="not an action with T contexts"):
        RunConfig(reality_fail="jump:1")
    assert np.isclose(RunConfig(reality_fail="stack:2").n_blocks, 8)
