"""The "real world" of a task behind one interface.

`SimulatedReality` is a grounded world with hidden true properties and a configurable
reality gap (friction and placement jitter), reporting what noisy sensors would (sensor and
perception noise, ``SensorNoise``); an external robot implements the same `Reality`
protocol (the HTTP service wires it to a robot that posts observations).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from sim_workers.configuration import Configuration
from sim_workers.engines import make_world
from sim_workers.grounded_world import GroundedWorld
from sim_workers.robots.motion import ArmMotion
from sim_workers.robots.servo import follow
from sim_workers.reality_gap import (RealityGap, SensorNoise, action_jitter, executed, jitter_planar,
                                     jittered_domain, noisy_readings, perceived_planar)


@dataclass(frozen=True)
class Observation:
    """What the real world reports after an action."""

    configuration: Configuration
    state: frozenset[str]
    measurements: np.ndarray
    # An arm's measured joint positions (rad), when the robot reports them (issue 41): the
    # next step's joint trajectory starts from them.
    joint_positions: np.ndarray | None = None


class Reality(Protocol):
    def start_episode(self, rng: np.random.Generator) -> Observation: ...
    # an arm's run also gets `arm=` (its joints: sim_workers.robots.motion.ArmMotion)
    def execute(self, trajectory: np.ndarray, action: str) -> Observation: ...


@dataclass(frozen=True)
class ContextFailure:
    """A reality gap the particle worlds cannot know (issue 24): every action `action` in a
    T context >= `from_context` fails in this reality only. After the action the object it
    acted on (its first argument naming an object) is back where the episode started it,
    as if it had slipped and been put back; the measurements are the action's own.

    >>> ContextFailure.parse("stack:3")
    ContextFailure(action='stack', from_context=3)
    """

    action: str
    from_context: int = 0

    @classmethod
    def parse(cls, text: str) -> "ContextFailure":
        """``"ACTION:K"`` (or ``"ACTION"``: every context) -> ContextFailure; ValueError if malformed."""
        name, _, k = str(text).partition(":")
        if not name.isidentifier() or (k and not k.isdigit()):
            raise ValueError(f"expected ACTION:K, e.g. stack:3 (got {text!r})")
        return cls(name, int(k) if k else 0)

    def applies(self, context: tuple[str, int] | None) -> bool:
        return context is not None and context[0] == self.action and int(context[1]) >= self.from_context


class SimulatedReality:
    """A grounded world holding the hidden truth, perturbed per episode by the reality gap.

    ``failure`` with ``context_fn`` (the task's ``context_of``) adds a ``ContextFailure``.

    ``noise`` (default ``SensorNoise()``: on) is what its sensors add (issue 37). The world
    holds and goes on from the TRUE state (and a ``ContextFailure`` reads the true state);
    only the returned ``Observation`` is perceived: its configuration has the movable
    objects' (``jittered_objects``) planar positions perceived with noise, its state is Y^-1
    of that configuration, the channels ``measurement_channels()`` lists with sigma None
    and not ``sensed`` are read off that configuration (the domain's ``measurements``: the
    block positions of the built-ins; a sensed one needs the action's sensor log and stays
    as simulated), and the channels with a sigma get their sensor noise
    (``noisy_readings``). A weighed channel is noised on its simulated reading, not re-read
    from the perceived configuration (the chute example's puck x: its own sigma, not
    perception's). ``SensorNoise.NONE``: the exact readings of before, bit for bit.

    With an arm (``execute``'s `arm`: the step's joints), the reality is a simulated arm
    of that robot: a position-controlled arm in MuJoCo (``sim_workers.robots.servo``)
    tracks the joints from where it stands, with the lag and overshoot of a real joint
    controller; its tool draws the rows the world's gripper follows, its links move through
    the scene, and it reports the joints it measured (``Observation.joint_positions``). The
    execution jitter scales the joints' clock as it does the rows' (before the tracking).
    """

    def __init__(self, domain_name: str, domain_options: dict, true_properties: dict,
                 gap: RealityGap = RealityGap(), failure: ContextFailure | None = None,  # noqa: B008 (frozen)
                 context_fn: Callable | None = None,
                 noise: SensorNoise = SensorNoise()) -> None:  # noqa: B008 (frozen)
        if failure is not None and context_fn is None:
            raise ValueError("failure: needs the task's context_fn")
        self.domain_name = domain_name
        self.options = dict(domain_options)
        self.truth = true_properties
        self.gap = gap
        self.noise = noise
        self.failure, self.context_fn = failure, context_fn
        self.world: GroundedWorld | None = None
        self._domain = None
        self._start: Configuration | None = None
        self._state: frozenset[str] = frozenset()
        self._exec_rng = None
        self._noise_rngs: tuple[np.random.Generator, np.random.Generator] | None = None
        self._joints: np.ndarray | None = None      # a simulated arm's measured joints
        self._payload = 0.0                         # and the gripper's mass it carries (kg)

    def start_episode(self, rng: np.random.Generator) -> Observation:
        domain = jittered_domain(rng, self.gap.friction, domain=self.domain_name, **self.options)
        if self.world is not None:
            self.world.close()
        self.world = make_world(domain)
        config = domain.initial_configuration(self.truth)
        # The domain's movable objects are placed with jitter (a fixture it names stays put).
        objects = jitter_planar(rng, config.objects, domain.jittered_objects,
                                self.gap.placement_m, self.gap.yaw_rad)
        placed = self.world.reset(Configuration(config.robot, objects), self.truth)
        self._domain, self._start = domain, placed
        # The arm's own timing varies action to action; a child stream, so the episode's
        # draws above (and a domain without the jitter) are as before.
        jitters = domain.execution_jitter.values()
        self._exec_rng = rng.spawn(1)[0] if any(j > 0 for j in jitters) else None
        # The sensors' noise: a child stream spawned after the execution jitter's (which keeps
        # its stream), split into perception's and the measurements', so that either setting
        # leaves the other's draws as they are. None spawned without noise: runs as before.
        self._noise_rngs = None if self.noise.exact else tuple(rng.spawn(1)[0].spawn(2))
        self._state = domain.symbolic_state(placed)     # the true state (reality's own)
        self._joints = None                             # the arm starts on its first step's plan
        gripper = domain.scene_description(domain.properties(self.truth)).gripper
        self._payload = gripper.palm_mass + 2 * gripper.finger_mass      # what a simulated arm carries
        return self._observed(placed, self._state, domain.measurements(placed), "")

    def execute(self, trajectory: np.ndarray, action: str, arm: ArmMotion | None = None) -> Observation:
        if self._exec_rng is not None:
            planned = trajectory
            trajectory = executed(trajectory, action, self._exec_rng, action_jitter(self._domain, action))
            if arm is not None and trajectory is not planned:       # the arm's joints on the same clock
                arm = ArmMotion(arm.robot, arm.base, np.interp(arm.times, planned[:, 0], trajectory[:, 0]),
                                arm.joints)
        if arm is not None:
            trajectory, arm = follow(trajectory, arm, self._joints, self._payload)
            self._joints = arm.joints[-1].copy()
        out = self.world.execute(trajectory, action, arm=arm)
        config, state = out.configuration, out.state
        if self.failure is not None and self.failure.applies(self.context_fn(self._state, action)):
            config = self._put_back(config, action)
            state = self._domain.symbolic_state(config)
        self._state = state
        obs = self._observed(config, state, out.measurements, action)
        if arm is not None:
            obs = Observation(obs.configuration, obs.state, obs.measurements, self._joints.copy())
        return obs

    def _observed(self, config: Configuration, state: frozenset[str], measurements: np.ndarray,
                  action: str) -> Observation:
        """The Observation the robot reports of the true `config` (see the class doc)."""
        if self._noise_rngs is None:
            return Observation(config, state, measurements)
        perception_rng, sensor_rng = self._noise_rngs
        domain, noise = self._domain, self.noise
        m = np.array(measurements, dtype=np.float64, copy=True)
        channels = domain.measurement_channels()
        if not noise.perceives_exactly:
            objects = perceived_planar(perception_rng, config.objects, domain.jittered_objects,
                                       noise.perception_m)
            config = Configuration(config.robot.copy(), objects)
            # Y^-1 of what the robot perceives. Its thresholds are centimetres (at init: 2 cm
            # of the start slot; a tower's blocks 2 cm apart in the plane; in the tray 4 mm
            # past the inner walls), so 2 mm moves no atom at an episode's start (20 seeds of
            # both domains), nor in 638 observations of whole tmp_rl episodes (measured); a
            # block within millimetres of a boundary (the tray's walls) can read as across it.
            state = domain.symbolic_state(config)
            derived = [int(c["index"]) for c in channels if c["sigma"] is None and not c.get("sensed")]
            if derived:
                m[derived] = np.asarray(domain.measurements(config, None, action), dtype=np.float64)[derived]
        weighed = [c for c in channels if c["sigma"] is not None]
        if weighed and not noise.measures_exactly:
            idx = [int(c["index"]) for c in weighed]
            m[idx] = noisy_readings(sensor_rng, m[idx], [float(c["sigma"]) for c in weighed], noise)
        return Observation(config, state, m)

    def _put_back(self, config: Configuration, action: str) -> Configuration:
        """`config` with the action's object back at its episode-start pose (world rebuilt)."""
        names = list(self._domain.object_names)
        args = [a.strip() for a in action.partition("(")[2].rstrip(")").split(",")]
        row = next((names.index(a) for a in args if a in names), None)
        if row is None:
            return config
        objects = config.objects.copy()
        objects[row] = self._start.objects[row]
        robot = config.robot.copy()
        return self.world.reset(Configuration(robot, objects), self.truth, place=False)

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None
