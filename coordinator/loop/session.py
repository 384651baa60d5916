"""The TMOC loop (Algorithm 1 of Ding et al. 2022) as a resumable session.

``next_step()`` returns the pending action with its pose, trajectory and expected effect;
``observe(observation)`` takes what the real world reported and does the rest of the step:
particle worlds replay the action (one Ray call per shard), the belief is reweighted and
resampled, the experience pool and T are updated, and the plan is kept or replanned. A
driver (``run_episode`` with a SimulatedReality, or the HTTP service for a real robot)
calls the two in turn. Episode accounting lives in ``coordinator.loop.episode``, the transit
to the pre-pose in ``coordinator.loop.transit``, what an observation does to the belief in
``coordinator.particle_filter`` (one ``update`` per real step); the rest is the loop's steps,
which share the session's state.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from typing import Callable, Iterator

import numpy as np

from planner.blocks.model import PlanningError
from sim_workers.configuration import Configuration
from sim_workers.properties import SIZES_VARIATION_SCALE
from sim_workers.trajectory import columns_of

from ..agents import agent_spec
from ..domains import load as load_domain, property_space
from .checkpoint import restore_session, session_checkpoint
from .episode import EpisodeStats, utility_terms
from .observer import Prediction, RunObserver, StepEvent
from .particle_worlds import predictions, simulate_rows
from ..transition.counterfactual import (REFRESH_ESS_FRACTION, Counterfactual, SnapshotStopped, ess_fraction,
                                        row_properties, simulate as simulate_counterfactual)
from ..transition.experience import ExperiencePool
from ..baselines.grounding_bandit import GroundingBandit
from ..particle_filter import Belief, ParticleFilter, RealStep, Reweighting
from ..particle_filter.belief import symbolic_log_likelihood
from ..particle_filter.likelihood import matched
from .reality import Observation
from .real_pose import real_pose
from ..run_config import AGENT_STREAM, COUNTERFACTUAL_STREAM, RunConfig, seed_stream
from .step_record import step_record
from .transit import plan_pre_pose_transit, transit_checker
from planner.motion import MotionPlanningError
from .arm_motion import belief_scene_size, contact_time, plan_arm_step, robot_of, start_joints
from .arm_trials import ArmForTrials
from sim_workers.robots import Unreachable
from sim_workers.robots.motion import ArmMotion
from ..transition.transition_model import TransitionModel, transition_table

# A property whose posterior std is still over this share of its prior's (a uniform prior:
# width / sqrt(12)) is reported `identified: false`: the data have not yet cut its plausible
# range in half.
IDENTIFIED_STD_SHARE = 0.5


class EpisodeInterrupted(Exception):
    """``run_episode`` was told to stop between two actions (a cancel or a shutdown)."""


@dataclass
class PendingStep:
    action: str
    pose: np.ndarray              # the real pose x (Y of the mode's particles; with mass in Y, + effort)
    trajectory: np.ndarray        # (T, 6) t, x, y, z, yaw, opening (+ grip_force, force_limit)
    expected: frozenset[str]      # the planned effect
    transit_end: float            # where particle worlds start: the checked transit's end, or 0
    particle_poses: np.ndarray | None = None
    unchecked_transit: bool = False   # a transit fallback: particle worlds replay it too
    # An arm's joint trajectory (a FollowJointTrajectory goal's, coordinator.loop.arm_motion)
    # and the joints it ends at; None for the floating gripper.
    joint_trajectory: dict | None = None
    end_joints: np.ndarray | None = None
    arm: ArmMotion | None = None      # the same joints as the worlds follow them (their links move)

    def to_dict(self) -> dict:
        out = {"action": self.action, "pose": self.pose.tolist(),
               "trajectory": self.trajectory.tolist(),
               "trajectory_columns": list(columns_of(self.trajectory)), "expected": sorted(self.expected)}
        if self.joint_trajectory is not None:
            out["joint_trajectory"] = self.joint_trajectory
        return out


class Session:
    """One task's learning state: belief over L, experience pool, T, and the episode."""

    def __init__(self, config: RunConfig, shard_pool=None) -> None:
        self.config = config
        self.agent = agent_spec(config.agent)
        joined = load_domain(config.domain, engine=config.engine, n_blocks=config.n_blocks, **config.options)
        self.domain = joined.physics          # scene, Y, Y^-1, measurements
        self.task = joined.task               # symbolic model, T's contexts, utility, planner
        self.n_blocks = config.n_blocks
        self.costs = utility_terms(self.task, config)
        self.shard_pool = shard_pool      # particle simulations (coordinator.distributed.fanout.ShardPool)
        self.rng = seed_stream(config.seed, AGENT_STREAM)
        # L: named properties, one value each for every block, or one per block with
        # the "sizes" variation; a row is property-major (sizes, then densities, ...).
        self.L = property_space(self.domain)
        self.per_block = bool(config.sizes_variation)
        self.dims = self.L.dims(self.n_blocks, self.per_block)
        self.low, self.high = self.L.bounds(self.n_blocks, self.per_block)
        belief = (Belief.from_prior(config.particles, self.low, self.high, self.rng)
                  if self.agent.learn_belief else None)
        # The belief with its likelihood, kernel, monitor and move window (issues 24, 37).
        self.filter = ParticleFilter(belief, Reweighting(config, self.domain.measurement_model(),
                                                         list(self.domain.learned_objects),
                                                         len(self.L.names), self.per_block), config)
        if belief is not None and config.known_properties:
            self.belief = self._point_belief(config)
        self.experience = ExperiencePool(self.task.context_of)
        # The counterfactual snapshot T uses (issue 40): before each episode's first plan, and
        # redrawn at a replan once the belief has moved from it.
        self.counterfactual: Counterfactual | None = None
        self._should_stop: Callable[[], bool] | None = None     # while run_episode drives
        self.transition = self._transition_model()
        self.episode = 0
        self.episodes: list[dict] = []
        self.particle_actions = 0
        self.particle_steps = 0
        # Episode state.
        self.observation: Observation | None = None
        self.plan: list[str] = []
        self.pending: PendingStep | None = None
        self.stats = EpisodeStats()
        self._t0 = 0.0
        # What watches the run (coordinator.loop.observer: pictures, step logs, checkpoints,
        # trackers): a view of it, never part of its state, so not checkpointed.
        self.observers: list[RunObserver] = []
        self._prediction: Prediction | None = None
        # The current episode's steps as records (coordinator.loop.step_record: what an export
        # needs), as observers got them; not checkpointed: a run resumes at an episode's start.
        self.step_records: list[dict] = []
        # TMP-RL's grounding by trial and error (its arm for the pending action, if any).
        self.bandit = GroundingBandit(self.low, self.high) if self.agent.grasp == "bandit" else None
        self._arm: tuple[str, int] | None = None
        # The robot that moves the tool (issue 41): an arm, placed where the domain stands
        # it, gets a joint trajectory per step (coordinator.loop.arm_motion); its joints
        # are the last step's end within an episode, the home branch at an episode's start.
        self.robot = robot_of(config.robot, self.domain)
        self.joints: np.ndarray | None = None
        self._refusals: dict[frozenset[str], set[str]] = {}

    @property
    def belief(self) -> Belief | None:
        """The belief over L (``self.filter``'s)."""
        return self.filter.belief

    @belief.setter
    def belief(self, value: Belief | None) -> None:
        self.filter.belief = value

    @property
    def reweighting(self) -> Reweighting:
        return self.filter.reweighting

    @property
    def recent(self) -> list[RealStep]:
        """The episode's latest real steps (the resample-move's window)."""
        return self.filter.recent

    def watch(self, observer: RunObserver) -> RunObserver:
        """Add `observer` (called after the ones already there); returns it."""
        self.observers.append(observer)
        return observer

    def _point_belief(self, config: RunConfig) -> Belief:
        """Every particle at the true properties (L given, as in the paper's real-robot
        run): reweighting cannot move it, resampling finds nothing to resample."""
        truth = self.truth_row()
        n = config.particles
        return Belief(np.tile(truth, (n, 1)), np.full(n, -np.log(n)), self.low, self.high)

    def _transition_model(self) -> TransitionModel:
        """T rebuilt from the experience pool over the domain's contexts."""
        return TransitionModel.from_experience(
            self.experience, self.n_blocks,
            sim_weight=self.config.sim_weight if self.agent.sim_experience else 0.0,
            contexts=self.task.contexts(self.n_blocks), context_fn=self.task.context_of,
            discount=self.config.sim_discount == "power_prior",
            counterfactual=self.counterfactual.counts if self.counterfactual is not None else None)

    def _refresh_counterfactual(self) -> None:
        """Before a plan: the counterfactual snapshot of the belief as it is now
        (``coordinator.transition.counterfactual``), and T rebuilt with it, at an episode's
        first plan and at a replan once the belief has moved from the snapshot's (its rows
        worth under ``REFRESH_ESS_FRACTION`` of their number as a sample of it). Only for an
        agent that learns from simulation, with a belief and worlds to ask."""
        m = self.config.counterfactual_rows
        if m < 1 or not self.agent.sim_experience or self.belief is None or self.shard_pool is None:
            return
        mean, std = self.reweighting.marginals(self.belief)
        last, refresh = self.counterfactual, 0
        if last is not None and last.episode == self.episode:
            if last.mean is None or ess_fraction(last.mean, last.std, mean, std) >= REFRESH_ESS_FRACTION:
                return
            refresh = last.refresh + 1
        # The episode's first snapshot keeps the key it always had; a redraw gets its own.
        key = (COUNTERFACTUAL_STREAM, self.episode) + ((refresh,) if refresh else ())
        k = self.n_blocks if self.per_block else 1
        self.counterfactual = simulate_counterfactual(
            self.shard_pool, self.domain, self.L.names, k, self.belief.particles, self.belief.weights,
            row_properties(self.L.names, np.asarray(mean, dtype=np.float64), k), m, self.n_blocks,
            self.task.contexts(self.n_blocks), np.random.SeedSequence(self.config.seed, spawn_key=key),
            self.episode, refresh, (mean, std), should_stop=self._should_stop, arm=self._trial_arm())
        self.stats.counterfactual_trials += self.counterfactual.trials
        self.stats.counterfactual_s += self.counterfactual.wall_s
        self.transition = self._transition_model()

    def _trial_arm(self):
        """The factory of the arm that does the counterfactual trials' actions: the run's arm
        (planned as its steps are, ``arm_trials.ArmForTrials``), or None for the floating
        gripper."""
        if self.robot is None:
            return None
        return partial(ArmForTrials, self.config.robot)

    def transition_table(self) -> list[dict]:
        """T per context, for people (``coordinator.transition.transition_model.transition_table``)."""
        return transition_table(self.transition, self.experience)

    def truth_row(self) -> np.ndarray:
        """The hidden truth as a row of L (the "sizes" variation: block 1 is 20 % larger)."""
        return self.L.truth_row(self.config.truth_values(), self.n_blocks, self.per_block,
                               {"size": SIZES_VARIATION_SCALE})

    # -- particles -----------------------------------------------------------------------
    def particle_sizes(self) -> np.ndarray:
        """(N, n_blocks) object sizes of every particle (the physics half's ``object_sizes``)."""
        return np.array([self.domain.object_sizes(self.props_of(row)) for row in self.belief.particles])

    def props_of(self, row: np.ndarray) -> dict:
        """A row of L as the domain's properties."""
        return self.domain.props_from_row(np.asarray(row, dtype=np.float64))


    def believed_props(self) -> dict:
        """The belief's mean row of L as the domain's properties."""
        return self.props_of(self.believed_row())

    def believed_row(self) -> np.ndarray:
        """The belief's weighted mean row of L (the prior's mean without a belief)."""
        if self.belief is None:
            return (self.low + self.high) / 2
        return np.asarray(self.reweighting.marginals(self.belief)[0], dtype=np.float64)

    def believed_sizes(self) -> np.ndarray:
        return np.array(self.domain.object_sizes(self.props_of(self.believed_row())), dtype=np.float64)

    # -- episode -------------------------------------------------------------------------
    def start_episode(self, observation: Observation) -> None:
        self.observation = observation
        self.plan = []
        self.pending = None
        self.stats = EpisodeStats()
        self.step_records = []
        self.filter.start_episode()
        self.joints = None
        self._refusals: dict[frozenset[str], set[str]] = {}    # state -> actions the arm could not do
        self._t0 = time.perf_counter()

    @property
    def state(self) -> frozenset[str]:
        return self.observation.state

    def episode_done(self) -> bool:
        return (self.task.is_goal(self.state) or self.stats.actions >= self.config.max_steps
                or self.stats.dead_end is not None)

    def _replan_or_end(self) -> None:
        """Replan; a state from which the planner finds no way to the goal (a block caught
        in the fingers with the container at goal, say) ends the episode there, recorded
        as `dead_end`, instead of failing the run or the robot session."""
        try:
            self._replan()
        except PlanningError as exc:
            self.plan = []
            self.stats.dead_end = str(exc)[:200]

    def _replan(self) -> None:
        self._refresh_counterfactual()
        t0 = time.perf_counter()
        costs = self.costs
        T = self.transition.to_planner()
        if self.config.tie_break == "evidence" and "trials" in self.task.transition_extras:
            T["trials"] = self.transition.trial_counts()     # ties broken by evidence
        if self.agent.planner == "satisficing":
            plan = self.task.satisficing(self.state, rng=self.rng, transition=T, costs=costs)
        else:
            # Objects resting on others go first (the physics half's `take_first`); passed
            # only when there are any, so a task half without the keyword still plans.
            take_first = getattr(self.domain, "take_first", None)   # (a half registered, not derived)
            first = take_first(self.observation.configuration) if take_first else ()
            plan = self.task.plan(self.state, T, costs, **({"first": first} if first else {}))
        self.plan = list(plan.actions)
        self.stats.plans.append(list(plan.loads))
        self.stats.planning_s += time.perf_counter() - t0

    def _real_pose(self, config: Configuration, action: str) -> tuple[np.ndarray, np.ndarray | None]:
        """Step 2 of the loop: the real pose x and (for TMOC) each particle's x_i
        (``coordinator.loop.real_pose.real_pose``)."""
        return real_pose(self, config, action)

    def action_belief(self, action: str) -> tuple[Belief, np.ndarray]:
        """The belief as `action` sees it and the columns of L it concerns: with weights per
        block, the particles under its block's weights (``Reweighting.action_view``), else
        the belief itself and every column."""
        log_w, cols = self.reweighting.action_view(self.belief, action)
        if log_w is self.belief.log_weights:
            return self.belief, cols
        return Belief(self.belief.particles, log_w, self.belief.low, self.belief.high), cols

    def _transit(self, config: Configuration, pre: np.ndarray) -> np.ndarray | None:
        """A collision-free path to the pre-pose among the observed obstacles
        (``coordinator.loop.transit``) with the believed sizes. None: every strategy failed, the
        action uses the domain's default transit unchecked, and the episode record counts
        the fallback."""
        t0 = time.perf_counter()
        try:
            sizes = self.believed_sizes()
            plan = plan_pre_pose_transit(self.domain, config, pre, sizes, self._held_size(sizes),
                                         seed=lambda: int(self.rng.integers(2**31)))
        finally:
            self.stats.planning_s += time.perf_counter() - t0
        if plan.fallback is not None:
            self.stats.transit_fallbacks.append(plan.fallback[:200])
        return plan.path

    def _held_size(self, sizes: np.ndarray) -> float:
        """The believed size of the block in the hand (0: the hand is empty)."""
        names = list(self.domain.learned_objects)
        held = self.domain.held_object(self.state)
        return float(sizes[names.index(held)]) if held in names else 0.0

    def next_step(self) -> PendingStep | None:
        """The next action with its pose, trajectory and expected effect (None: episode over)."""
        if self.pending is not None:
            return self.pending
        if self.episode_done():
            return None
        if not self.plan:
            self._replan_or_end()
            if self.stats.dead_end is not None:
                return None
        action = self.plan[0]
        if action in self._refusals.get(self.state, ()):      # the arm could not, from here
            self.plan = []
            self.stats.dead_end = next(w for w in reversed(self.stats.arm_refusals)
                                       if w.startswith(f"the arm cannot {action}:"))
            return None
        config = self.observation.configuration
        x, xs = self._real_pose(config, action)
        pre = self.domain.pre_pose(config, action, x)
        transit = self._transit(config, pre)
        traj = self.domain.action_trajectory(config, action, x, transit)
        # Particle worlds skip a checked transit (free space); an unchecked one may touch
        # something, so they replay the whole trajectory from its start, as the robot moved.
        t_pre = 0.0 if transit is None else self.domain.transit_end_time(config, action, x, transit)
        expected = self.task.apply(self.state, action)
        step = PendingStep(action, x, traj, expected, t_pre, xs, unchecked_transit=transit is None)
        if self.robot is not None and not self._arm_step(config, step):
            return self.next_step()            # replanned around it, or the episode ended
        self.pending = step
        return self.pending

    def _arm_step(self, config: Configuration, step: PendingStep) -> bool:
        """Give `step` the arm's joint trajectory and its tool rows (``plan_arm_step``);
        False, with the episode ended as a dead end naming why, when the arm cannot."""
        t0 = time.perf_counter()
        try:
            # The links clear the belief's quantile (they are not the domain's); the gripper is
            # checked as the domain's own transit checks it, at the believed sizes: the
            # transit's end is a pose a few mm from what the action handles, in the
            # conservative scene it would already touch it.
            sizes, believed = self.clearance_sizes(), self.believed_sizes()
            obstacles = self.domain.obstacles(config, sizes)
            measured = self.observation.joint_positions
            start = self.joints if measured is None else measured       # what the arm reports wins
            if start is None:
                start = start_joints(self.robot, config.robot, obstacles)
            elif np.abs(self.robot.tool(start)[:3, 3] - config.robot[:3]).max() > 1e-3:
                start = self.robot.joints_for(*config.robot[:4], start)     # where the tool got to
            opening = float(np.max(step.trajectory[:, 5]))
            plan = plan_arm_step(self.robot, step.trajectory, obstacles, start=start,
                                 seed=int(self.rng.integers(2**31)), transit_end=step.transit_end,
                                 tool_valid=transit_checker(self.domain, config, believed, self._held_size(believed),
                                                            opening),
                                 contact_from=contact_time(step.trajectory, step.pose, step.transit_end),
                                 held=self._held_size(sizes))
        except (MotionPlanningError, Unreachable) as exc:      # ArmPlanningError included
            self._refused(step, f"the arm cannot {step.action}: {exc}"[:200])
            return False
        finally:
            self.stats.planning_s += time.perf_counter() - t0
        step.transit_end = plan.time_of(step.transit_end) if step.transit_end else 0.0
        step.trajectory = plan.rows
        step.joint_trajectory = plan.path.goal(self.robot.joint_names)
        step.end_joints = plan.end
        step.arm = ArmMotion(self.robot.name, getattr(self.domain, "robot_base", None), plan.path.t, plan.path.q)
        return True

    def _refused(self, step: PendingStep, why: str) -> None:
        """The arm cannot do `step` from here: to T a failed attempt of the action in this
        context (nothing moved: the state is as before), accounted as a failed action, and
        the plan made again. An arm that cannot push a tower of 8 from its base teaches T
        that such a push fails for this robot, so the next plans build lower towers, where a
        dead end taught nothing and every episode planned it again. The same action planned
        again from the same state (the planner has nothing better) ends the episode as a
        dead end naming why."""
        state, action = self.state, step.action
        self._refusals.setdefault(state, set()).add(action)
        self.stats.arm_refusals.append(why)
        self.experience.add_real(state, action, state, step.expected)
        self.transition = self._transition_model()
        self._account(state, step, state, False)
        self.plan = []
        if not self.episode_done():
            self._replan_or_end()

    def clearance_sizes(self) -> np.ndarray:
        """Per object, the size an arm's links clear: the belief's QUANTILE (so a tower wider
        than believed is cleared too); the believed sizes without a belief."""
        if self.belief is None:
            return self.believed_sizes()
        sizes, w = self.particle_sizes(), self.belief.weights
        return np.array([belief_scene_size(sizes[:, k], w) for k in range(sizes.shape[1])])

    def observe(self, observation: Observation) -> dict:
        """Steps 3-6 of the loop for the pending action, given the real outcome."""
        step = self.pending
        if step is None:
            raise RuntimeError("observe() without a pending step")
        before = self.observation
        success = observation.state == step.expected
        report = {"action": step.action, "success": success, "state": sorted(observation.state)}
        if self.belief is not None and self.shard_pool is not None:
            report.update(self._reweight(before, step, observation))
        if self._arm is not None:
            self.bandit.observe(*self._arm, success)
            self._arm = None
        if step.end_joints is not None:
            self.joints = step.end_joints
        self.experience.add_real(before.state, step.action, observation.state, step.expected)
        self.transition = self._transition_model()
        self._account(before.state, step, observation.state, success)
        record = step_record(
            episode=self.episode, step=self.stats.actions - 1, action=step.action, pose=step.pose,
            trajectory=step.trajectory, before=before, after=observation, expected=step.expected,
            success=success, belief=self.posterior(), object_names=list(self.domain.object_names),
            channels=[c["name"] for c in self.domain.measurement_channels()], transit_end=step.transit_end)
        self.step_records.append(record)
        event = StepEvent(self.episode, self.stats.actions - 1, step.action, step.expected, observation,
                          success, record, self._prediction)
        self._prediction = None
        for observer in list(self.observers):
            observer.on_step(self, event)
        self.observation = observation
        self.pending = None
        if success:
            self.plan.pop(0)
        else:
            self.plan = []       # step 6: replan from what was observed (now: it may end the episode)
            if not self.episode_done():
                self._replan_or_end()
        if self.episode_done():
            report["episode"] = self._finish_episode()
        return report

    def _reweight(self, before: Observation, step: PendingStep, observation: Observation) -> dict:
        # The wire carries rows of L (N, D); each shard expands a row with the domain.
        sizes = np.ascontiguousarray(self.belief.particles)
        start = before.configuration.to_array()
        if self.config.likelihood == "replay":
            res = self._simulate_rows(start, sizes, step.action, step.trajectory, step.transit_end, arm=step.arm)
        else:  # "paper": each particle runs its own trajectory to its own pose x_i
            trajs = np.array([self.domain.action_trajectory(before.configuration, step.action, xi)
                              for xi in step.particle_poses])
            t_pre = np.array([0.0 if step.unchecked_transit else
                              self.domain.transit_end_time(before.configuration, step.action, xi)
                              for xi in step.particle_poses])
            res = self._simulate_rows(start, sizes, step.action, trajs, t_pre)
        if step.unchecked_transit:
            self.stats.replayed_fallback()
        self.particle_actions += res["particle_actions"]
        self.particle_steps += res["particle_steps"]
        loglik = self._symbolic_loglik(step, observation.state, res["states"])
        samples = self._samples(res, loglik)
        if samples > 1:             # the worlds disagreed: the outcome is a chance, sampled
            sampled = self._simulate_rows(start, sizes, step.action, step.trajectory, step.transit_end,
                                          arm=step.arm, samples=samples, first=res)
            self.particle_actions += sampled["particle_actions"] - res["particle_actions"]     # the new ones
            self.particle_steps += sampled["particle_steps"] - res["particle_steps"]
            res = sampled
        nodes = [(lw, self._symbolic_loglik(step, observation.state, r["states"]), r["measurements"])
                 for lw, r in res["perception"]] if res.get("perception") else None
        if any(o.wants_predictions for o in self.observers):   # before the update: the weights that predicted
            self._prediction = self._predicted(step, observation.state, res, sizes)
        # Simulated experience counts each world by how plausible it was before this real
        # outcome was absorbed (the paper adds the worlds' outcomes, then weighs them; with the
        # weights after, the real outcome was counted twice, issue 37).
        prior_weights = self.action_belief(step.action)[0].weights
        real = RealStep(start, step.action, step.trajectory, step.transit_end, step.expected,
                        observation.state, np.asarray(observation.measurements, dtype=np.float64), step.arm,
                        samples)
        update = self.filter.update(real, loglik, res["measurements"], self.rng,
                                    self._simulate_rows, self._symbolic_loglik, nodes)
        self.particle_actions += update.simulated
        if self.agent.sim_experience:      # weighted by how plausible each is for this action
            parts = res.get("perception") or [(0.0, res)]     # and by each perception node's weight
            self.experience.add_simulated(before.state, step.action,
                                          [st for _, r in parts for st in r["states"]], step.expected,
                                          np.concatenate([np.exp(lw) * prior_weights for lw, _ in parts]))
        self.stats.particle_counts.append(len(sizes))
        self.stats.count_update(update.informative, update.injected)
        return update.report()

    def _samples(self, res: dict, loglik: np.ndarray) -> int:
        """How many perceptions to weigh a replayed step at (``perception_samples``): more
        than one only where the worlds at the perceived start disagreed among themselves
        and no quadrature integrates the step already (docs/LOOP.md, "An outcome is a
        sample"); a step every world replayed alike moves no weight between them."""
        k = self.config.perception_samples
        if k <= 1 or res.get("perception") or self.config.likelihood != "replay":
            return 1
        agreed = matched(loglik, self.config.error_rate)
        return k if agreed.any() and not agreed.all() else 1

    def _simulate_rows(self, start: np.ndarray, rows: np.ndarray, action: str, trajectory, start_time,
                       arm: ArmMotion | None = None, samples: int = 1, first: dict | None = None) -> dict:
        """The particle worlds as the filter sees them (a callable; its time is physics):
        ``coordinator.loop.particle_worlds.simulate_rows`` on the session's shard pool."""
        t0 = time.perf_counter()
        out = simulate_rows(self.shard_pool, self.domain, self.config, start, rows, action, trajectory,
                            start_time, arm=arm, samples=samples, first=first)
        self.stats.physics_s += time.perf_counter() - t0
        return out

    def _predicted(self, step: PendingStep, observed: frozenset[str], res: dict, rows: np.ndarray) -> Prediction:
        """The particles' predictions of this action, for its picture (copies; reads only)."""
        return predictions(self.config.match, step.expected, observed, res, self.belief.weights, rows)

    def _symbolic_loglik(self, step: PendingStep | RealStep, observed: frozenset[str],
                         predicted: list) -> np.ndarray:
        """p(s' | s_i'), a match model with a small error rate.

        `match="success"` (default) compares whether the action had its planned effect in
        the real world and in particle i; `match="state"` compares the whole symbolic state
        (the paper's literal reading), which also scores chaotic detail such as which of
        eight blocks fell off a pile, and made the belief collapse on noise in our runs.
        """
        if self.config.match == "state":
            return symbolic_log_likelihood(observed, predicted, self.config.error_rate)
        ok = frozenset({"success"})
        flag = lambda s: ok if s == step.expected else frozenset()
        return symbolic_log_likelihood(flag(observed), [flag(s) for s in predicted], self.config.error_rate)

    def _account(self, state, step: PendingStep, next_state, success: bool) -> None:
        self.stats.account(self.costs, self.task, state, step.action, next_state, success)

    def posterior(self) -> dict:
        """size_mean/size_std (over the size dimensions), the raw per-dimension mean and
        std, and ``properties``: {name: {mean, std, unit, identified}} for every property of
        L; ``identified`` is false while the std is still over IDENTIFIED_STD_SHARE of the
        prior's (the channels have not pinned it down: read the mean as a guess; always
        without a belief, whose mean is the prior's), and the
        measurement channels' likelihood sigma (``measurement_sigma``, sensor widened by
        the measured model error)."""
        k = self.n_blocks if self.per_block else 1
        if self.belief is None:
            mean, std = self.believed_row(), np.zeros(self.dims)
        else:
            mean, std = self.reweighting.marginals(self.belief)
        prior_std = (self.high - self.low) / np.sqrt(12.0)
        props = {name: {"mean": float(np.mean(mean[j * k:(j + 1) * k])),
                        "std": float(np.mean(std[j * k:(j + 1) * k])), "unit": unit,
                        "identified": self.belief is not None and bool(np.all(
                            std[j * k:(j + 1) * k] <= IDENTIFIED_STD_SHARE * prior_std[j * k:(j + 1) * k]))}
                 for j, (name, unit) in enumerate(zip(self.L.names, self.L.units))}
        # The size's summary under its own keys, for a domain whose L has one (both built-ins).
        out = {"size_mean": props["size"]["mean"], "size_std": props["size"]["std"]} if "size" in props else {}
        if self.belief is not None:
            out.update(mean=[float(v) for v in mean], std=[float(v) for v in std],
                       measurement_sigma=[float(v) for v in self.reweighting.sigma()])
        out["properties"] = props
        return out

    def _finish_episode(self) -> dict:
        s = self.stats
        s.wall_s = time.perf_counter() - self._t0
        record = s.record(self.episode, self.posterior(),
                          float(self.belief.ess()) if self.belief is not None else None)
        self.episodes.append(record)
        self.episode += 1
        for observer in list(self.observers):     # at the boundary: a checkpoint is possible
            observer.on_episode(self, record)
        return record

    @contextmanager
    def using_shard_pool(self, shard_pool) -> Iterator["Session"]:
        """Simulate particles on `shard_pool` inside the block, then go back to the previous
        one (the service lends a shared pool to a session for one call at a time)."""
        previous, self.shard_pool = self.shard_pool, shard_pool
        try:
            yield self
        finally:
            self.shard_pool = previous

    # -- checkpoints -----------------------------------------------------------------------
    def to_checkpoint(self) -> dict:
        """The whole learning state at an episode boundary, JSON-able
        (``coordinator.loop.checkpoint``)."""
        return session_checkpoint(self)

    @classmethod
    def from_checkpoint(cls, data: dict, shard_pool=None) -> "Session":
        """The session `data` (``to_checkpoint``'s) was taken from, ready for its next episode."""
        return restore_session(cls, data, shard_pool)

    def run_episode(self, reality, reality_rng: np.random.Generator,
                    should_stop: Callable[[], bool] | None = None) -> dict:
        """Drive one episode against `reality` (SimulatedReality or anything alike).
        `should_stop` is polled before each action: True raises EpisodeInterrupted (the
        episode is dropped; the session stays at its last episode boundary's checkpoint)."""
        self.start_episode(reality.start_episode(reality_rng))
        # A counterfactual snapshot polls the stop too, wherever a plan is made: before an
        # action (`next_step`) and at the replan after a failure (`observe`).
        self._should_stop = should_stop
        try:
            return self._drive(reality, should_stop)
        except SnapshotStopped as exc:
            raise EpisodeInterrupted(f"episode {self.episode}: {exc}") from None
        finally:
            self._should_stop = None

    def _drive(self, reality, should_stop: Callable[[], bool] | None) -> dict:
        """``run_episode``'s loop: act, observe, until the episode's record."""
        while True:
            if should_stop is not None and should_stop():
                raise EpisodeInterrupted(f"episode {self.episode} stopped after {self.stats.actions} actions")
            step = self.next_step()
            if step is None:          # done before acting (e.g. nothing left to deliver)
                return self._finish_episode()
            # an arm's joints go to the reality too (its links move in the simulated one)
            obs = (reality.execute(step.trajectory, step.action) if step.arm is None
                   else reality.execute(step.trajectory, step.action, arm=step.arm))
            report = self.observe(obs)
            if "episode" in report:
                return report["episode"]
