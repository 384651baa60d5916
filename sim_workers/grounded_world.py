"""A grounded world: one physics simulation of the scene under one hypothesis L_i.

``GroundedWorld`` is what the shards, the simulated reality and the probes drive: reset to
an observed configuration under some properties, follow a trajectory, observe. What that
costs in an engine lives in its subclass (``sim_workers.engines``): ``PybulletWorld`` (the
default) owns one pybullet DIRECT client, ``MujocoWorld`` one MuJoCo model and data.
``sim_workers.engines.make_world(domain, engine="mujoco")`` builds the engine's world (the
engine hooks are abstract; ``GroundedWorld(domain, ...)`` is kept as the same factory).

Every engine keeps one guarantee: ``reset`` makes a result depend on nothing but
(configuration, properties, trajectory). pybullet's ``restoreState`` and pose resets
leave contact caches and broadphase history behind (results drift by ~1e-13 with the
world's past), so its world rebuilds the scene per reset (``resetSimulation``, ~2 ms);
MuJoCo keeps no state outside ``MjData``, so its world resets the data
(tests/sim_workers/test_determinism.py and test_engines.py check both against a fresh
process).
"""
from __future__ import annotations

import abc
from dataclasses import dataclass, replace

import numpy as np

from . import reach
from . import trajectory as tr
from .configuration import Configuration, quat_from_yaw, rotate_z, yaw_of
from .domains import Domain
from .reality_gap import as_perceived
from .robots.acting import current_arm
from .robots.motion import ArmMotion, link_boxes, link_poses

REST_LINEAR = 0.004     # m/s: below this everything counts as at rest
REST_ANGULAR = 0.04     # rad/s
REST_CHECK_EVERY = 12   # steps


@dataclass(frozen=True)
class SensorLog:
    """What a real robot's sensors report while it executes an action: the wrist
    force (N, world frame: the reaction of the constraint that carries the gripper, so
    gripper plus held load) at every physics step, and the finger opening (m)."""

    times: np.ndarray          # (S,) s, on the trajectory's clock
    wrist_force: np.ndarray    # (S, 3)
    opening: np.ndarray        # (S,)
    t_end: float               # when the trajectory ended (the rest is settling)
    commanded: np.ndarray | None = None   # (S, 5+) what the gripper was told at each step

    def window(self, t0: float, t1: float) -> np.ndarray:
        """Boolean mask of the steps with t0 < t <= t1."""
        return (self.times > t0) & (self.times <= t1)


@dataclass(frozen=True)
class Outcome:
    """What one action did in one world."""

    configuration: Configuration
    state: frozenset[str]
    measurements: np.ndarray
    steps: int


class GroundedWorld(abc.ABC):
    """One physics simulation of `domain`'s scene in one engine (``engine``: pybullet or
    mujoco; None: the domain's ``engine``, else the default).

    With ``leave_out`` (particle worlds: ``sim_workers.shard.Shard``), the first action after
    a reset, if its kind is one of the domain's ``leave_out_actions``, runs without the
    bodies it cannot reach (``sim_workers.reach``; pybullet only, where contacts with far
    bodies cost most of a step), guarded: if a kept body comes near a left-out one, the
    action is run again in the full world. After such an action the world needs a reset; a
    world that runs several actions in a row (the simulated robot of
    ``coordinator.loop.reality``, the physics tests) is built without ``leave_out``.
    """

    engine = ""
    # Whether worlds of this engine may step at once on threads of one process: true where
    # the engine's stepping calls release the GIL and share no state between worlds
    # (``sim_workers.shard.Shard``'s ``threads``).
    steps_in_threads = False

    def __new__(cls, domain: Domain, *, leave_out: bool = False, engine: str | None = None):
        # ``GroundedWorld(domain)`` is the spelling plugins and scripts were written with; it
        # resolves the engine's subclass as ``sim_workers.engines.make_world`` (the factory
        # the service calls) does. An engine's subclass is built directly.
        if cls is GroundedWorld:
            from .engines.registry import world_class
            cls = world_class(engine or domain.engine)
        return super().__new__(cls)

    def __init__(self, domain: Domain, *, leave_out: bool = False, engine: str | None = None) -> None:
        self.domain = domain
        self.props: dict | None = None
        self.leave_out = leave_out
        self._placed: Configuration | None = None      # as reset placed it (for a re-run)
        self._absent: dict[int, np.ndarray] = {}       # object index -> its pose, left out
        self._fresh = False                            # no action since the last reset
        self.reruns = 0                                # actions the guard sent to the full world
        self.settle_s = float(domain.settle_s)
        self._links_track = None                       # an arm's link poses per step of the action
        self._link_cache = None                        # (motion, times key, poses) of the last one
        self._connect()

    # -- what an engine provides ---------------------------------------------------------
    @abc.abstractmethod
    def _connect(self) -> None:
        """Open the engine (called once, by the constructor)."""
        ...

    @abc.abstractmethod
    def close(self) -> None:
        ...

    @abc.abstractmethod
    def _rebuild(self, props: dict) -> None:
        """The scene under `props`, as if built in a fresh process."""
        ...

    @abc.abstractmethod
    def _apply(self, config: Configuration) -> None:
        """Put the objects and the gripper at `config`, at rest."""
        ...

    @abc.abstractmethod
    def _set_gripper(self, target: np.ndarray, reset: bool = False) -> None:
        """Command the gripper to `target` (x, y, z, yaw, opening[, grip_force, force_limit]).

        Without the effort entries the scene's fixed grip force and wrist limit apply. A
        force limit below the scene's is a force-limited motion (a push): the arm then
        carries the gripper's own weight by gravity compensation, as an arm controller
        does, so that the limit caps what the wrist exerts on the world."""
        ...

    @abc.abstractmethod
    def observe(self) -> Configuration:
        """The current configuration (gripper tool point, opening, object poses)."""
        ...

    @abc.abstractmethod
    def at_rest(self) -> bool:
        ...

    @abc.abstractmethod
    def _step(self) -> None:
        ...

    @abc.abstractmethod
    def _wrist_force(self) -> tuple[float, float, float]:
        """What carries the gripper exerts on it (N, world frame): gripper plus load."""
        ...

    @abc.abstractmethod
    def _opening(self) -> float:
        ...

    @abc.abstractmethod
    def _tool_position(self) -> np.ndarray:
        """Where the tool point is (x, y, z)."""
        ...

    @abc.abstractmethod
    def _commanded_tool(self) -> np.ndarray:
        """Where the tool point was last commanded to (x, y, z)."""
        ...

    def _leave_out(self, targets: np.ndarray, link_boxes: np.ndarray | None = None):
        """Remove the objects the action cannot reach (nor an arm's links, whose boxes at
        every step are `link_boxes`); a guard, or None (nothing left out)."""
        return None

    def _with_links(self, links: tuple) -> None:
        """Make the scene hold an arm's link capsules `links` (``sim_workers.robots.collision
        .Capsule``; () for none) as kinematic bodies that collide with the movable objects
        (not with the gripper, which the arm carries, nor with the fixtures)."""
        if links:
            raise NotImplementedError(f"engine {self.engine!r}: an arm's links are not built")

    def _place_links(self, positions: np.ndarray, quaternions: np.ndarray) -> None:
        """Put the link capsules at world centres (L, 3) and quaternions (L, 4; x, y, z, w)."""
        raise NotImplementedError

    # -- lifecycle ---------------------------------------------------------------------
    def __enter__(self) -> "GroundedWorld":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- state ---------------------------------------------------------------------------
    def reset(self, config: Configuration, props: dict, *, place: bool = True) -> Configuration:
        """Rebuild the scene under `props` and put it in `config` (re-grounded if `place`)."""
        props = self.domain.properties(props)
        self._rebuild(props)
        self.props = props
        placed = self.domain.place(config, props) if place else config
        self._absent = {}
        self._apply(placed)
        self._placed, self._fresh = placed, True
        return placed

    def symbolic_state(self) -> frozenset[str]:
        return self.domain.symbolic_state(self.observe())

    # -- acting -------------------------------------------------------------------------
    def skip_to(self, trajectory: np.ndarray, start_time: float) -> None:
        """Jump the gripper (and what it holds) to the trajectory's pose at `start_time`.

        Used to skip the free-space transit, which touches nothing, in particle worlds.
        """
        now = self.observe()
        target = tr.sample(trajectory, np.array([start_time]))[0]
        # the protocol's word for what the hand holds (issue 39: not the block worlds' atom)
        holding = self.domain.held_object(self.domain.symbolic_state(now))
        held = [i for i, a in enumerate(self.domain.object_names) if a == holding]
        objects = now.objects.copy()
        dyaw = target[3] - now.robot[3]
        for i in held:
            rel = rotate_z(objects[i, :2] - now.robot[:2], dyaw)
            objects[i, :2] = target[:2] + rel
            objects[i, 2] += target[2] - now.robot[2]
            objects[i, 3:] = quat_from_yaw(yaw_of(objects[i, 3:]) + dyaw)
        robot = target[:5].copy()     # the pose; efforts are commands, not configuration
        robot[4] = now.robot[4]
        self._apply(Configuration(robot, objects))

    def execute(self, trajectory: np.ndarray, action: str, *, start_time: float = 0.0,
                max_settle_s: float | None = None, arm: ArmMotion | None = None) -> Outcome:
        """Follow `trajectory` (t, x, y, z, yaw, opening) then let the scene settle.

        Simulated time is bounded by the trajectory's end plus the settle time; it stops
        early once every object is at rest after the trajectory has ended. With `arm` (an
        arm's joints over the same clock: ``sim_workers.robots.motion.ArmMotion``) the arm's
        links move with it as kinematic bodies that push what they meet; a body a link's
        sweep comes near is never left out.
        """
        traj = tr.validate(trajectory)
        if self.props is None:
            raise RuntimeError("world: reset() before execute()")
        if self._absent:
            raise RuntimeError("world: bodies were left out of the last action; reset() first")
        bot = arm.arm() if arm is not None else None
        self._with_links(bot.links if bot is not None else ())
        reduce = self.leave_out and self._fresh and self._leaves_out(action)
        self._fresh = False
        if start_time > 0.0:
            self.skip_to(traj, start_time)
        dt = self.time_step
        t_end = float(traj[-1, 0])
        settle = self.settle_s if max_settle_s is None else max_settle_s
        times = start_time + dt * np.arange(1, int(np.ceil((t_end - start_time + settle) / dt)) + 1)
        targets = tr.sample(traj, times)
        self._links_track = None
        if bot is not None:
            pos, quat, moved = self._link_track(arm, bot, start_time, times)
            self._place_links(pos[0], quat[0])
            self._links_track = (pos[1:], quat[1:], moved)
        watch = self._leave_out(targets, None if bot is None else link_boxes(bot, pos, quat)) if reduce else None
        outcome, steps = self._run(action, times, targets, t_end, watch)
        if outcome is None:
            # Something came near a left-out body: the same action in the full world,
            # rebuilt exactly as reset() built it (bit-identical to a world without leave_out).
            self.reruns += 1
            self.reset(self._placed, self.props, place=False)
            self._fresh = False
            if bot is not None:
                self._with_links(bot.links)
                self._place_links(pos[0], quat[0])
            if start_time > 0.0:
                self.skip_to(traj, start_time)
            outcome, more = self._run(action, times, targets, t_end, None)
            outcome = replace(outcome, steps=steps + more)
        return outcome

    def _link_track(self, arm: ArmMotion, bot, start_time: float, times: np.ndarray):
        """The links' poses at `start_time` and at each step's time, and whether they moved
        at each step; kept for the next call with the same motion and times (a shard's
        batch runs one motion for every particle)."""
        key = (start_time, len(times), float(times[0]) if len(times) else 0.0)
        cached = self._link_cache
        if cached is not None and cached[0] is arm and cached[1] == key:
            return cached[2]
        pos, quat = link_poses(bot, arm.at(np.concatenate([[start_time], times])))
        moved = np.any(pos[1:] != pos[:-1], axis=(1, 2)) | np.any(quat[1:] != quat[:-1], axis=(1, 2))
        self._link_cache = (arm, key, (pos, quat, moved))
        return pos, quat, moved

    def _leaves_out(self, action: str) -> bool:
        """Whether the domain leaves bodies out of this kind of action (its
        ``leave_out_actions``, chosen by measurement: where the saved contacts outweigh the
        guard's cost)."""
        return action.partition("(")[0] in self.domain.leave_out_actions

    def _run(self, action: str, times: np.ndarray, targets: np.ndarray, t_end: float,
             watch) -> tuple[Outcome | None, int]:
        """Step through `targets`; (None, steps) as soon as `watch` trips."""
        steps = 0
        # A domain that reads sensors during the action says so; the others pay nothing.
        logging = bool(self.domain.logs_sensors) and bool(self.domain.senses(action))
        force, opening = [], []
        guarded = targets.shape[1] > 6 and bool(np.any(targets[:, 6] < self.domain.base_max_force))
        was_guarded, offset = False, np.zeros(3)
        links = self._links_track
        for k, (t, target) in enumerate(zip(times, targets)):
            if guarded:
                target, was_guarded, offset = self._guard(target, was_guarded, offset)
            self._set_gripper(target)
            if links is not None and links[2][k]:
                self._place_links(links[0][k], links[1][k])
            self._step()
            steps += 1
            if logging:
                force.append(self._wrist_force())
                opening.append(self._opening())
            if watch is not None and k % reach.GUARD_EVERY == 0 and watch.tripped():
                return None, steps
            if t > t_end and k % REST_CHECK_EVERY == 0 and self.at_rest():
                break
        return self._finish(action, times, targets, t_end, steps,
                            (force, opening) if logging else None), steps

    def _finish(self, action: str, times: np.ndarray, targets: np.ndarray, t_end: float,
                steps: int, logged: tuple | None) -> Outcome:
        """The outcome after `steps` steps: the observed configuration, its symbolic state
        and the domain's measurements (from the sensor log when `logged` = (wrist forces,
        openings) per step)."""
        config = self.observe()
        after = self.domain.after_action(config, action)
        if after is not config:
            self._apply(after)
            config = after
        if logged is not None:
            force, opening = logged
            log = SensorLog(times[:steps].copy(), np.array(force, dtype=np.float64).reshape(-1, 3),
                            np.array(opening, dtype=np.float64).reshape(-1), t_end,
                            targets[:steps].copy())
            meas = self.domain.measurements(config, log, action)
        else:
            meas = self.domain.measurements(config)
        return Outcome(config, self.domain.symbolic_state(config), meas, steps)

    def _guard(self, target: np.ndarray, was_guarded: bool, offset: np.ndarray):
        """A force-limited (guarded) segment ends where the gripper got to, not where its
        reference went: the rest of the trajectory is shifted by the gap at that moment,
        as a robot continues from where a guarded move stopped (else the full wrist force
        would snap the gripper to the reference and through whatever held it back)."""
        now_guarded = target[6] < self.domain.base_max_force
        if was_guarded and not now_guarded:
            offset = self._tool_position() - self._commanded_tool()
        if np.any(offset):
            target = target.copy()
            target[:3] += offset
        return target, now_guarded, offset


def act(world: GroundedWorld, domain, config: Configuration, believed: dict, action: str,
        run_as=None):
    """Run `action` with Y at the believed properties, as the robot does: the free-space
    transit is skipped unless the hand carries an object, which may shift in the fingers
    on the way (issue 24: T*'s probes judged stacks of 58 mm cubes teleported into place,
    while the robot's, carried, pivoted in the fingers and failed). `run_as(traj, action)`
    gives the trajectory a real arm runs instead of the planned one (its retimed start of
    the action follows). Inside a probe trial with an arm (``robots.acting.arm_moves``) the
    arm plans the action and the world moves its links along. Inside a probe trial with a
    perception (``reality_gap.trial_perception``) the action is planned from the perceived
    configuration, as the loop's robot plans it, and run in the true one."""
    seen = as_perceived(domain, config)
    key = domain.action_pose(believed, seen, action)
    traj = domain.action_trajectory(seen, action, key)
    carried = domain.held_object(domain.symbolic_state(seen)) is not None
    start = 0.0 if carried else domain.transit_end_time(seen, action, key)
    arm = current_arm()
    motion = None
    if arm is not None:            # an arm does the trial's actions (robots.acting)
        traj, start, motion = arm.plan(domain, seen, believed, action, traj, start, key)
    if run_as is not None:
        planned, traj = traj, run_as(traj, action)
        start = float(np.interp(start, planned[:, 0], traj[:, 0]))
        if motion is not None:     # the arm's joints on the executed clock
            motion = ArmMotion(motion.robot, motion.base, np.interp(motion.times, planned[:, 0], traj[:, 0]),
                               motion.joints)
    if motion is not None:
        traj, motion = arm.track(domain, believed, traj, motion)
    return world.execute(traj, action, start_time=start, arm=motion)
