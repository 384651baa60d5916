"""Step 2 of the loop when the belief is split: which real pose x to try (issue 37).

Each particle i has its own pose x_i = Y(L_i). A unimodal belief takes the weighted mean of
its mode's x_i (``belief.mode_mask``). A belief split into modes has no pose every particle
agrees on, and the heaviest mode's pose can fail over and over: a failed grasp at mode A
moves the weight to mode B, a failed grasp at B moves it back, and no pose between them
(which would have succeeded for the truth) is ever tried. So the candidates are the pose
of every mode (up to ``MAX_MODES``, by weight) and the weighted mean of all poses, each is
run in every particle world, and the real pose is the candidate whose predicted success,
sum_i w_i [x succeeds in world i], is highest: the decision that maximises the belief's
expected success of the action (ties: the heaviest mode's, today's rule). A belief whose
mode holds every particle has one candidate and pays no simulation, unless the domain
offers Y's alternatives for the action (``pose_alternatives``: a cube's other grasp when
a neighbour is within the fingers' reach): then the chosen pose is simulated, and where
some world predicts it fails, each alternative too (issue 40's "Y's alternatives are
simulated, not ruled out").

With an arm, a candidate the arm cannot reach (no branch of the inverse within the joint
limits, at the key pose or the pre-pose) is predicted to fail in every world
(``reach_gated``) and is never simulated; the mode rule takes its mode among the particles
whose own pose the arm reaches (issue 41).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from sim_workers.configuration import Configuration
from sim_workers.robots import Unreachable

from ..particle_filter.belief import Belief, heaviest_class, mode_mask

__all__ = ["MAX_MODES", "pose_candidates", "choose_pose", "reach_gated", "real_pose", "mode_scale"]

# Modes whose poses are candidates. Each costs N particle-actions per real action while the
# belief is split; beyond three the remaining weight of a 16-32 particle belief is a few
# particles, whose pose the mean candidate already leans towards.
MAX_MODES = 3

# Candidate poses closer than this (every component, m or rad) are one candidate.
SAME_POSE = 1e-6


def _weighted_pose(particles: np.ndarray, log_w: np.ndarray, poses: np.ndarray, keep: np.ndarray) -> np.ndarray:
    sub = Belief(particles[keep], log_w[keep], np.min(particles, axis=0) - 1.0, np.max(particles, axis=0) + 1.0)
    return sub.weighted_mean(poses[keep], angular=(3,))


def pose_candidates(particles: np.ndarray, weights: np.ndarray, poses: np.ndarray, classes: np.ndarray,
                    bandwidth: float, scale: np.ndarray) -> list[np.ndarray]:
    """The poses worth trying: each mode's (heaviest first, one pose class each), then the
    weighted mean of every particle's pose; near-duplicates dropped. One entry when the
    heaviest mode holds every particle."""
    p = np.asarray(particles, dtype=np.float64).reshape(len(particles), -1)
    w = np.asarray(weights, dtype=np.float64)
    log_w = np.log(np.maximum(w, 1e-300))
    left = w > 0
    out: list[np.ndarray] = []
    for _ in range(MAX_MODES):
        if not left.any():
            break
        keep = np.zeros(len(p), dtype=bool)
        idx = np.flatnonzero(left)
        keep[idx] = mode_mask(p[idx], w[idx], bandwidth, scale=scale)
        keep = heaviest_class(classes, w, keep)
        out.append(_weighted_pose(p, log_w, poses, keep))
        left &= ~keep
        if len(out) == 1 and not left.any():
            return out                       # one mode holds every particle
    out.append(_weighted_pose(p, log_w, poses, w > 0))
    unique: list[np.ndarray] = []
    for x in out:
        if all(np.max(np.abs(x - u)) > SAME_POSE for u in unique):
            unique.append(x)
    return unique


def choose_pose(candidates: list[np.ndarray], success: Callable[..., np.ndarray],
                weights: np.ndarray,
                alternatives: Callable[[np.ndarray], list[np.ndarray]] | None = None) -> np.ndarray:
    """The candidate with the highest predicted success sum_i w_i success(x)_i (the first
    of equals: the heaviest mode's). `success(x)` is (N,) in [0, 1], from the worlds.

    `alternatives(x)`: Y's other poses for the chosen candidate x (``pose_alternatives``:
    a cube's other grasp). They are judged the same way, after the candidates, and only
    while x is not predicted to succeed in every world (then nothing can beat it, and the
    first of equals keeps Y's own pose); one replaces x only if strictly better. An
    alternative is run first in the worlds where x may fail (`success(alt, rows)`: those
    rows only): it can gain only there, so where it gains nothing the rest is not run."""
    if len(candidates) == 1 and alternatives is None:
        return candidates[0]
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    results = [np.asarray(success(x), dtype=np.float64) for x in candidates]
    scores = np.array([float(w @ r) for r in results])
    best = int(np.flatnonzero(scores >= scores.max() - 1e-9)[0])
    chosen, held = candidates[best], results[best]
    if alternatives is None:
        return chosen
    for alt in alternatives(chosen):
        unsure = np.flatnonzero(held < 1.0 - 1e-12)
        if unsure.size == 0:
            break                                   # x succeeds in every world: unbeatable
        there = np.asarray(success(alt, unsure), dtype=np.float64)
        gain = float(w[unsure] @ (there - held[unsure]))
        if gain <= 1e-9:
            continue
        sure = np.flatnonzero(held >= 1.0 - 1e-12)
        here = np.asarray(success(alt, sure), dtype=np.float64) if sure.size else np.zeros(0)
        if gain - float(w[sure] @ (held[sure] - here)) > 1e-9:
            full = np.empty_like(held)
            full[unsure], full[sure] = there, here
            chosen, held = alt, full
    return chosen


def reach_gated(success: Callable[..., np.ndarray], reaches: Callable[[np.ndarray], bool] | None,
                n: int) -> Callable[..., np.ndarray]:
    """`success` where the robot can reach the pose, and 0 in every world where it cannot
    (issue 41: a pose no branch of the arm's inverse reaches within the joint limits is not
    offered): an unreachable candidate or alternative then never beats a reachable one, and
    costs no simulation. `reaches` None: every pose is reachable (the floating gripper)."""
    if reaches is None:
        return success

    def gated(x: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        if reaches(x):
            return success(x, rows) if rows is not None else success(x)
        return np.zeros(n if rows is None else len(rows))
    return gated


def arm_reaches(session, config: Configuration, action: str) -> Callable[[np.ndarray], bool] | None:
    """Whether the session's arm reaches a candidate key pose of `action` and its pre-pose
    (some branch of the inverse within the joint limits: ``Arm.joints_for``); None for the
    floating gripper, which reaches everywhere."""
    arm = getattr(session, "robot", None)
    if arm is None:
        return None
    domain = session.domain

    def reaches(x: np.ndarray) -> bool:
        try:
            for pose in (x, domain.pre_pose(config, action, x)):
                arm.joints_for(*np.asarray(pose, dtype=np.float64)[:4])
        except Unreachable:
            return False
        return True
    return reaches


def _reachable_rows(reaches: Callable[[np.ndarray], bool] | None, poses: np.ndarray) -> np.ndarray:
    """Per particle, whether the arm reaches its own pose x_i (all True without an arm, or
    where it reaches none: then the arm's step names the infeasibility)."""
    if reaches is None:
        return np.ones(len(poses), dtype=bool)
    ok = np.array([reaches(x) for x in poses], dtype=bool)
    return ok if ok.any() else np.ones(len(poses), dtype=bool)


# ----------------------------------------------------------------------------- the session's step 2
def real_pose(session, config: Configuration, action: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Step 2 of the loop for `session`'s agent: the real pose x and (for TMOC) each
    particle's x_i. Reads the session's belief, domain and settings; a bandit's or a random
    grasp's draw comes from its generator."""
    mode = session.agent.grasp
    if mode == "belief":
        poses = session.domain.action_poses(session.belief.particles, config, action)
        view, cols = session.action_belief(action)
        rule = session.config.pose_rule
        if rule == "mean":                       # the paper: weighted mean of all x_i
            return view.weighted_mean(poses, angular=(3,)), poses
        if rule == "success" and session.shard_pool is not None:
            return _most_successful_pose(session, config, action, view, cols, poses), poses
        # the mode among the particles whose pose the arm reaches (issue 41; all without one)
        reach = _reachable_rows(arm_reaches(session, config, action), poses)
        keep = mode_mask(view.particles[:, cols], view.weights * reach, session.config.mode_bandwidth,
                         scale=mode_scale(session.low, session.high)[cols]) & reach
        keep = heaviest_class(session.domain.pose_classes(view.particles, config, action), view.weights, keep)
        sub = Belief(view.particles[keep], view.log_weights[keep], view.low, view.high)
        return sub.weighted_mean(poses[keep], angular=(3,)), poses
    if mode == "bandit":
        kind = action.partition("(")[0].strip()
        arm = session.bandit.choose(kind, session.rng)
        session._arm = (kind, arm)
        return session.domain.action_pose(session.props_of(session.bandit.row(arm)), config, action), None
    if mode == "random" and action.partition("(")[0].strip() in session.domain.grasp_actions:
        L, n = session.L, session.n_blocks
        if len(L.names) == 1:
            s = session.rng.uniform(float(L.low[0]), float(L.high[0]), n)
        else:   # every property of every block drawn from its prior
            low, high = L.bounds(n, True)
            s = session.rng.uniform(low, high)
        return session.domain.action_pose(session.props_of(s), config, action), None
    return session.domain.action_pose(session.believed_props(), config, action), None


def mode_scale(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Per-dimension scale for the pose mode: each property's prior width over the size's,
    so the bandwidth stays in metres of size and a kg/m^3 counts as its share of the density
    prior (a metre and a kg/m^3 are not one Euclidean space)."""
    width = high - low
    return width / width[0]


def _most_successful_pose(session, config: Configuration, action: str, view: Belief,
                          cols: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """The candidate pose (each mode's, and the mean's) that the particle worlds predict
    succeeds for most of the belief's weight; with ``pose_alternatives``, Y's other poses of
    the action (the domain's) judged too."""
    domain = session.domain
    classes = domain.pose_classes(view.particles, config, action)
    reaches = arm_reaches(session, config, action)
    cands = pose_candidates(view.particles[:, cols], view.weights, poses, classes,
                            session.config.mode_bandwidth, mode_scale(session.low, session.high)[cols])
    if len(cands) == 1 and not session.config.pose_alternatives and (reaches is None or reaches(cands[0])):
        return cands[0]
    expected = session.task.apply(session.state, action)
    start = config.to_array()

    def success(x: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        traj = domain.action_trajectory(config, action, x)
        t_pre = domain.transit_end_time(config, action, x)
        sub = view.particles if rows is None else view.particles[rows]
        res = session._simulate_rows(start, np.ascontiguousarray(sub), action, traj, t_pre)
        session.particle_actions += res["particle_actions"]
        session.particle_steps += res["particle_steps"]
        # Each world's chance of success over the perception error (its nodes), so a
        # pose with clearance beats one that grasps only where perception is exact.
        return sum(np.exp(lw) * np.array([s == expected for s in r["states"]], dtype=np.float64)
                   for lw, r in res.get("perception") or [(0.0, res)])

    alternatives = None
    if session.config.pose_alternatives:
        def alternatives(x: np.ndarray) -> list[np.ndarray]:
            return domain.pose_alternatives(config, action, x, view.particles)
        if len(cands) == 1 and not alternatives(cands[0]):
            return cands[0]             # nothing for the worlds to judge: no simulation
    if len(cands) == 1 and alternatives is None:
        return cands[0]                 # unreachable, and nothing else: the arm's step says why
    return choose_pose(cands, reach_gated(success, reaches, len(view.particles)), view.weights, alternatives)
