"""A Gymnasium view of every registered domain (issue 28): the domain's simulated reality
as an environment, for the tools that consume Gymnasium (RLlib, Stable Baselines3,
``gymnasium.utils.env_checker.check_env``).

Importing this module registers one id per domain of the registry, ``tmoc/NAME-vN`` (N the
domain's version: the ids move with the versioned registry), so that::

    env = gymnasium.make("coordinator.integrations.gym_env:tmoc/container-v1", n_blocks=4)

- **The world** is the domain's ``SimulatedReality`` holding a hidden truth, a row of L:
  the one given (``truth=``), else drawn from L's uniform prior at every reset, from the
  env's seeded generator.
- **An action** is ``{"action": k, "grounding": row}``: the k-th grounded symbolic action
  (``task.grounded_actions``; ``info["action_mask"]`` marks those whose preconditions hold)
  and the row of L that Y grounds it with (the continuous parameters TMOC's belief would
  set: an agent can learn the grounding too). The robot moves to the action's pre-pose by
  the loop's checked transit and runs Y's trajectory, as a TMOC session does.
- **The reward** is the domain's utility terms, as a run accounts them: minus the action's
  cost, minus ``fail`` when the outcome is not the action's symbolic effect, plus the
  domain's reward terms (deliveries). An action whose preconditions do not hold moves
  nothing and counts as failed.
- **Observations**: ``configuration`` (the observed configuration, ``Configuration``'s
  flat array) and ``state`` (one bit per atom of ``task.atoms``), as the reality's noisy
  sensors report them (issue 37: ``sensor_noise``, ``sensor_bias``, ``sensor_tails`` and
  ``perception_sigma``, RunConfig's fields and defaults; 0, 0, "gaussian", 0: exact
  readings). The episode terminates at the goal or at a dead end (no action applies:
  ``info["dead_end"]``) and is truncated after ``max_steps`` actions.

Needs the ``gym`` extra (``pip install 'tmoc-service[gym]'``).
"""
from __future__ import annotations

from typing import Any

import numpy as np

try:
    import gymnasium as gym
    from gymnasium import spaces
except ImportError as exc:  # pragma: no cover - exercised without the extra
    raise ImportError("the Gymnasium view needs gymnasium: pip install 'tmoc-service[gym]'") from exc

from sim_workers.configuration import Configuration

from sim_workers.reality_gap import SensorNoise

from ..domains import load, names, spec
from ..loop.reality import SimulatedReality
from ..loop.transit import plan_pre_pose_transit

NAMESPACE = "tmoc"
DEFAULT_MAX_STEPS = 60          # RunConfig's max_steps


class TmocEnv(gym.Env):
    """One domain's simulated reality as a Gymnasium environment (see the module's doc)."""

    metadata = {"render_modes": []}

    def __init__(self, domain: str = "container", *, n_blocks: int | None = None,
                 options: dict | None = None, truth=None, max_steps: int = DEFAULT_MAX_STEPS,
                 engine: str | None = None, sensor_noise: float = SensorNoise.scale,
                 sensor_bias: float = SensorNoise.bias, sensor_tails: str = SensorNoise.tails,
                 perception_sigma: float = SensorNoise.perception_m) -> None:
        opts = dict(options or {})
        if n_blocks is not None:
            opts["n_blocks"] = int(n_blocks)
        if engine is not None:
            opts["engine"] = engine
        if int(max_steps) < 1:
            raise ValueError(f"max_steps: {max_steps} must be at least 1")
        # The reality's sensors (RunConfig's fields of the same names); ValueError if invalid.
        self.noise = SensorNoise(scale=float(sensor_noise), bias=float(sensor_bias), tails=sensor_tails,
                                 perception_m=float(perception_sigma))
        d = load(domain, **opts)
        self.domain_name, self.options = d.name, opts
        self.physics, self.task = d.physics, d.task
        self.n_blocks = d.n_blocks
        self.max_steps = int(max_steps)
        L = self.physics.L
        self.low, self.high = np.asarray(L.low, dtype=np.float64), np.asarray(L.high, dtype=np.float64)
        self.fixed_truth = None if truth is None else self._row(truth, "truth")
        self.actions = tuple(self.task.grounded_actions(self.n_blocks))
        self.atoms = tuple(self.task.atoms(self.n_blocks))
        self._atom_index = {a: i for i, a in enumerate(self.atoms)}
        size = len(self.physics.initial_configuration(self.physics.true_properties()).to_array())
        self.action_space = spaces.Dict({
            "action": spaces.Discrete(len(self.actions)),
            "grounding": spaces.Box(self.low, self.high, dtype=np.float64),
        })
        self.observation_space = spaces.Dict({
            "configuration": spaces.Box(-np.inf, np.inf, (size,), dtype=np.float64),
            "state": spaces.MultiBinary(len(self.atoms)),
        })
        self.costs = dict(self.task.default_costs)
        self.reality: SimulatedReality | None = None
        self.truth_row: np.ndarray | None = None
        self._obs = None
        self._steps = 0

    # -- helpers -------------------------------------------------------------------------
    def _row(self, row, field: str) -> np.ndarray:
        row = np.asarray(row, dtype=np.float64).reshape(-1)
        if row.shape != self.low.shape or not np.all(np.isfinite(row)):
            raise ValueError(f"{field}: expected {len(self.low)} finite values (one per property of L: "
                             f"{', '.join(self.physics.L.names)}), got {row.tolist()}")
        return row

    def prior_mean(self) -> np.ndarray:
        """The middle of L's prior: the grounding of an agent that knows nothing."""
        return (self.low + self.high) / 2.0

    def action_mask(self, state: frozenset[str] | None = None) -> np.ndarray:
        """1 for each grounded action whose preconditions hold in `state` (default: now)."""
        state = self._obs.state if state is None else state
        return np.array([self._applicable(state, a) for a in self.actions], dtype=np.int8)

    def _applicable(self, state: frozenset[str], action: str) -> bool:
        try:
            self.task.apply(state, action)
        except ValueError:
            return False
        return True

    def _observation(self) -> dict:
        bits = np.zeros(len(self.atoms), dtype=np.int8)
        for atom in self._obs.state:
            i = self._atom_index.get(atom)
            if i is not None:
                bits[i] = 1
        return {"configuration": self._obs.configuration.to_array().astype(np.float64), "state": bits}

    def _info(self, **more) -> dict:
        """The action mask, the symbolic state as text and the measurements: a channel that
        did not measure (NaN in the loop) reads 0 with ``measured`` False, so that equal
        outcomes compare equal."""
        m = np.array(self._obs.measurements, dtype=np.float64)
        measured = np.isfinite(m)
        return {"action_mask": self.action_mask(), "state": sorted(self._obs.state),
                "measurements": np.where(measured, m, 0.0), "measured": measured, **more}

    # -- the Gymnasium API ---------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        self.truth_row = self.fixed_truth if self.fixed_truth is not None else rng.uniform(self.low, self.high)
        if self.reality is not None:
            self.reality.close()
        # The reality is built like a run's: its own engine option included.
        self.reality = SimulatedReality(self.domain_name, self.options, self.physics.props_from_row(self.truth_row),
                                        noise=self.noise)
        self._obs = self.reality.start_episode(rng.spawn(1)[0])
        self._steps = 0
        return self._observation(), self._info()

    def step(self, action: dict[str, Any]):
        if self._obs is None:
            raise RuntimeError("step() before reset()")
        k = int(action["action"])
        if not 0 <= k < len(self.actions):
            raise ValueError(f"action: {k} is not in 0..{len(self.actions) - 1}")
        name = self.actions[k]
        row = np.clip(self._row(action["grounding"], "grounding"), self.low, self.high)
        before = self._obs.state
        try:
            expected = self.task.apply(before, name)
        except ValueError:
            expected = None
        if expected is None:
            success, after = False, before          # nothing moves: a failed action
        else:
            self._obs = self.reality.execute(self._trajectory(name, row), name)
            after = self._obs.state
            success = after == expected
        kind = name.split("(", 1)[0]
        reward = -float(self.costs[kind]) - (0.0 if success else float(self.costs["fail"]))
        terms, _ = self.task.step_reward(before, name, after, self.costs)
        reward += float(terms)
        self._steps += 1
        info = self._info(success=success, applicable=expected is not None, action_name=name)
        # A state no action applies in (e.g. the container's: a block held while the
        # container stands at the goal) ends the episode, as it ends the loop's.
        dead_end = not info["action_mask"].any()
        terminated = bool(self.task.is_goal(after)) or bool(dead_end)
        truncated = not terminated and self._steps >= self.max_steps
        info["dead_end"] = bool(dead_end) and not self.task.is_goal(after)
        return self._observation(), reward, terminated, truncated, info

    def _trajectory(self, action: str, row: np.ndarray) -> np.ndarray:
        """Y's trajectory for `action` grounded by `row`, with the loop's checked transit."""
        config: Configuration = self._obs.configuration
        props = self.physics.props_from_row(row)
        pose = self.physics.action_pose(props, config, action)
        pre = self.physics.pre_pose(config, action, pose)
        sizes = np.asarray(self.physics.object_sizes(props), dtype=np.float64)
        held = self.physics.held_object(self._obs.state)
        names_ = list(self.physics.learned_objects)
        held_size = float(sizes[names_.index(held)]) if held in names_ else 0.0
        transit = plan_pre_pose_transit(self.physics, config, pre, sizes, held_size,
                                        seed=lambda: int(self.np_random.integers(2**31))).path
        return self.physics.action_trajectory(config, action, pose, transit)

    def close(self) -> None:
        if self.reality is not None:
            self.reality.close()
            self.reality = None


def env_id(name: str) -> str:
    """The Gymnasium id of domain `name`: ``tmoc/NAME-vN``."""
    s = spec(name)
    return f"{NAMESPACE}/{s.name}-v{s.version}"


def register_all() -> list[str]:
    """Register every domain of the registry (built-in and installed plugins); their ids."""
    ids = []
    for name in names():
        i = env_id(name)
        if i not in gym.registry:
            gym.register(id=i, entry_point=TmocEnv, kwargs={"domain": name})
        ids.append(i)
    return ids


register_all()
