"""An arm's joint trajectory for a step's tool path (issue 41): follow the tool rows by
inverse kinematics to a tolerance, every link checked against the believed scene; where
following fails in the transit (a link in the way, a pose out of reach, a branch flip), plan
that span in joint space to another branch (a straight move, or up, across and down above the
scene, before any RRT* search); time the whole path within the joint limits (toppra),
never faster than the domain timed the tool. The step's rows are then the arm's tool path,
at the arm's times, so the particle worlds simulate what the arm will do.

This module is where the robot declarations (``sim_workers.robots``) meet the planners
(``planner.motion``), which never import each other.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np

from planner.motion import MotionPlanningError
from planner.motion.joint_space import JointPath, densify_joints, plan_joint_rrtstar, time_joint_path
from sim_workers.robots import Unreachable, robot
from sim_workers.robots.base import Arm, tool_pose
from sim_workers.robots.collision import Capsule, links_checker
from sim_workers.robots.kinematics import frames, nearest

__all__ = ["ArmPlan", "ArmPlanningError", "belief_scene_size", "contact_time", "plan_arm_step", "robot_of",
           "start_joints"]

TOLERANCE = 1e-3        # m: the arm's tool stays this near the step's tool path (issue 41's aim)
YAW_TOLERANCE = 1e-2    # rad: the fingers' turn (1 mm at a finger 0.1 m from the axis)
MAX_DEPTH = 10          # bisections of one row gap (1024 pieces: a gap of 0.5 m down to 0.5 mm)
JUMP = 0.5              # rad a joint may move in one piece below DEPTH_JUMP bisections: more is a branch flip
CHECK_STEP = 0.01       # rad between link checks along a joint segment (~8 mm of tool at full reach)
QUANTILE = 0.975        # the believed size the links clear: a tower wider than believed is cleared too
RRT_ITERATIONS = 300
TILT = 0.05             # rad the tool may tilt from pointing down in a joint-space move (~3 degrees)
# Wall-clock cap on one step's joint-space searches (each RRT* also stops at its iteration
# count and 5 s): a step with many branches to try cannot hold a session's thread for long.
# The measured slowest step took 0.48 s (benchmarks/bench_arm_motion.py; 7.7 s when RRT*
# came before the straight and over-the-top moves).
STEP_BUDGET_S = 10.0
HAND_RADIUS = 0.065     # m: a tilted gripper's capsule, its palm's half width (55 mm) plus 10 mm
# How far above the scene's highest top the tool goes to change branch (m): the tilted
# gripper's capsule radius and the 2 cm the links are cleared by elsewhere (Bullet's contact
# threshold), rounded up.
SAFE_CLEARANCE = 0.10


class ArmPlanningError(MotionPlanningError):
    """No joint trajectory for the step's tool path; the message names the row and why."""


@dataclass
class ArmPlan:
    """The arm's answer for one step: its timed joint path, the tool rows it draws (t, x, y,
    z, yaw, opening, ...) and the joints it ends at; `replanned`: points of the transit
    planned in joint space (the move to the step's first pose, where the robot stood a
    little off it, is not counted), `tilt`: the tool's largest tilt from pointing down there (rad)."""

    path: JointPath
    rows: np.ndarray
    end: np.ndarray
    source_t: np.ndarray          # per point: the time on the step's own rows it stands for
    replanned: int = 0
    tilt: float = 0.0

    def time_of(self, t_rows: float) -> float:
        """The arm's time at the last point that stands for a time <= `t_rows` of the step's rows."""
        k = np.flatnonzero(self.source_t <= t_rows + 1e-9)
        return float(self.rows[k[-1], 0]) if k.size else float(self.rows[0, 0])


def contact_time(rows: np.ndarray, key: np.ndarray, after: float = 0.0) -> float | None:
    """The time of the first row at or after `after` whose tool point is the key pose's
    (x, y, z): where the action starts handling things; None if no row is."""
    rows = np.asarray(rows, dtype=np.float64)
    hit = np.flatnonzero((rows[:, 0] >= after - 1e-9)
                         & (np.abs(rows[:, 1:4] - np.asarray(key, dtype=np.float64)[:3]).max(axis=1) < 1e-9))
    return float(rows[hit[0], 0]) if hit.size else None


def robot_of(name: str, physics) -> Arm | None:
    """The run's robot as the session drives it: an arm placed at the domain's
    ``robot_base``, or None for the floating gripper (the tool rows are its commands)."""
    bot = robot(name)
    if not isinstance(bot, Arm):
        return None
    base = getattr(physics, "robot_base", None)
    if base is None:
        raise ArmPlanningError(f"robot {name!r}: the domain declares no robot_base, so the arm has "
                               "nowhere to stand (docs/DOMAINS.md)")
    return bot.placed(base)


def start_joints(arm: Arm, pose: np.ndarray, obstacles: list) -> np.ndarray:
    """The joints an episode starts from for the tool at `pose` (x, y, z, yaw): of the
    inverse's branches within the limits and clear of the scene, the one with the elbow
    highest (the elbow-up posture of pick and place: the upper arm and forearm stay above
    what the hand works on), each angle on the turn nearest the arm's home."""
    clear = links_checker(arm, obstacles)
    best, best_z = None, -math.inf
    for branch in arm.branches(tool_pose(*pose[:4]), float(arm.home[5])):
        try:
            q = nearest(branch[None, :], arm.home, arm.low, arm.high)
        except Unreachable:
            continue
        z = float((arm.base @ frames(arm.dh, q)[1])[2, 3])        # the elbow: link frame 2's origin
        if clear(q) and z > best_z:
            best, best_z = q, z
    if best is None:
        raise ArmPlanningError(f"no branch of the arm reaches {np.round(pose[:4], 4).tolist()} clear of the scene")
    return best


def belief_scene_size(particles: np.ndarray, weights: np.ndarray, q: float = QUANTILE) -> float:
    """The weighted `q`-quantile of the believed sizes (one column): what the links clear."""
    x = np.asarray(particles, dtype=np.float64).reshape(-1)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    order = np.argsort(x)
    c = np.cumsum(w[order]) / w.sum()
    return float(x[order][min(int(np.searchsorted(c, q)), len(x) - 1)])


def _pose_error(arm: Arm, q: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    t = arm.tool(q)
    want = tool_pose(*target)
    pos = float(np.linalg.norm(t[:3, 3] - want[:3, 3]))
    yaw = math.atan2(t[1, 0], t[0, 0]) - math.atan2(want[1, 0], want[0, 0])
    return pos, abs((yaw + math.pi) % (2 * math.pi) - math.pi)


def _mid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The tool pose halfway (x, y, z linear; yaw the short way; the rest linear)."""
    m = 0.5 * (a + b)
    m[3] = a[3] + 0.5 * ((b[3] - a[3] + math.pi) % (2 * math.pi) - math.pi)
    return m


def _follow(arm: Arm, qa: np.ndarray, qb: np.ndarray, ra: np.ndarray, rb: np.ndarray, depth: int = 0) -> list:
    """Joint waypoints after `qa` up to `qb` whose joint-linear pieces keep the tool within
    TOLERANCE of the straight tool segment `ra`-`rb` (rows x, y, z, yaw, ...); [(q, row)]."""
    rm = _mid(ra, rb)
    qm_lin = 0.5 * (qa + qb)
    pos, yaw = _pose_error(arm, qm_lin, rm[:4])
    if pos <= TOLERANCE and yaw <= YAW_TOLERANCE:
        return [(qb, rb)]
    if depth >= MAX_DEPTH:
        raise ArmPlanningError(f"the arm cannot follow the tool path near {np.round(rm[:4], 4).tolist()} "
                               f"to {TOLERANCE * 1000:g} mm")
    qm = arm.joints_for(*rm[:4], qa)
    if depth >= 3 and max(np.abs(qm - qa).max(), np.abs(qb - qm).max()) > JUMP:
        raise ArmPlanningError(f"the arm flips branch near {np.round(rm[:4], 4).tolist()}")
    return _follow(arm, qa, qm, ra, rm, depth + 1) + _follow(arm, qm, qb, rm, rb, depth + 1)


def _segments_clear(qs: np.ndarray, is_valid) -> int | None:
    """The first piece index whose densified joint segment meets a link collision, else None."""
    for i in range(len(qs) - 1):
        if not all(is_valid(q) for q in densify_joints(qs[i:i + 2], CHECK_STEP)[1:]):
            return i
    return None


def _tool_rows(arm: Arm, qs: np.ndarray, extra: np.ndarray) -> tuple[np.ndarray, float]:
    """Rows (x, y, z, yaw, extra...) of the tool at joints `qs`, and the largest tilt."""
    out, tilt = [], 0.0
    for q, e in zip(qs, extra):
        t = arm.tool(q)
        tilt = max(tilt, math.acos(max(-1.0, min(1.0, -float(t[2, 2])))))
        out.append([*t[:3, 3], math.atan2(t[1, 0], t[0, 0]), *e])
    return np.array(out), tilt


class _Path:
    """Joint waypoints under construction, with the tool rows they stand for."""

    def __init__(self, q: np.ndarray, row: np.ndarray) -> None:
        self.qs, self.rs, self.dts, self.src = [q], [row[1:]], [], [row[0]]

    def add(self, qs, rs, dts, src) -> None:
        self.qs += list(qs)
        self.rs += list(rs)
        self.dts += list(dts)
        self.src += list(src)

    def extend(self, other: "_Path") -> None:
        self.add(other.qs[1:], other.rs[1:], other.dts, other.src[1:])


def _why(links, piece_qs: np.ndarray, blocked: int) -> str:
    hit = next((links.contact(q) for q in densify_joints(piece_qs[blocked:blocked + 2], CHECK_STEP)
                if not links(q)), None)
    if hit is None:
        return "a link meets the believed scene"
    return f"the {hit[0]} meets " + ("the table" if hit[1] < 0 else f"obstacle {hit[1]}")


def _follow_rows(arm: Arm, rows: np.ndarray, q: np.ndarray, scene, table, contact_from) -> _Path:
    """Follow every row from joints `q` (at rows[0]); ArmPlanningError names the first
    gap that cannot be followed or meets the scene."""
    path = _Path(q, rows[0])
    for i in range(len(rows) - 1):
        qa = path.qs[-1]
        links = scene if contact_from is None or rows[i + 1, 0] <= contact_from + 1e-9 else table
        try:
            qb = arm.joints_for(*rows[i + 1, 1:5], qa)
            piece = _follow(arm, qa, qb, rows[i, 1:], rows[i + 1, 1:])
        except (Unreachable, ArmPlanningError) as exc:
            raise ArmPlanningError(f"rows {i}-{i + 1} ({np.round(rows[i + 1, 1:5], 4).tolist()}): {exc}") from None
        piece_qs = np.array([qa] + [p[0] for p in piece])
        blocked = _segments_clear(piece_qs, links)
        if blocked is not None:
            raise ArmPlanningError(f"rows {i}-{i + 1} ({np.round(rows[i + 1, 1:5], 4).tolist()}): "
                                   + _why(links, piece_qs, blocked))
        dt = (rows[i + 1, 0] - rows[i, 0]) / len(piece)
        path.add([p[0] for p in piece], [p[1] for p in piece], [dt] * len(piece),
                 rows[i, 0] + dt * np.arange(1, len(piece) + 1))
    return path


def _clear_head(arm: Arm, rows: np.ndarray, q0: np.ndarray, j: int, hand, scene, table, contact_from):
    """The rows 0..k followed from `q0` up to the first k <= j where the hand is clear (a
    step may start with the fingers at a block: up first), and k; (None, 0) if none is."""
    if hand(q0):
        return _Path(q0, rows[0]), 0
    for k in range(1, j + 1):
        try:
            head = _follow_rows(arm, rows[:k + 1], q0, scene, table, contact_from)
        except ArmPlanningError:
            return None, 0
        if hand(head.qs[-1]):
            return head, k
    return None, 0


def _branches_at(arm: Arm, row: np.ndarray, near: np.ndarray) -> list[np.ndarray]:
    """Every branch of the inverse at a row's tool pose within the limits, each on the turn
    nearest `near`, nearest first."""
    out = []
    for branch in arm.branches(tool_pose(*row[1:5]), float(near[5])):
        try:
            out.append(nearest(branch[None, :], near, arm.low, arm.high))
        except Unreachable:
            continue
    return sorted(out, key=lambda q: (float(np.abs(q - near).max()), float(np.abs(q - near).sum())))


def _candidates(arm: Arm, row: np.ndarray, near: np.ndarray) -> list[np.ndarray]:
    """Every branch at a row's tool pose within the limits, nearest `near` first (each on
    the turn of its joints nearest `near`), then each on the turns nearest the arm's home
    where those differ. Joints wound a turn away over an episode (a pan at 6.1 rad) leave a
    motion no room before their limits (+-2 pi), so a push from there flips branch; a
    transit is where to unwind them."""
    out: list[np.ndarray] = []
    for around in (near, arm.home):
        out += [q for q in _branches_at(arm, row, around) if not any(np.allclose(q, seen) for seen in out)]
    return out


def plan_arm_step(arm: Arm, rows: np.ndarray, obstacles: list, *, start: np.ndarray, seed: int,
                  transit_end: float | None = None, tool_valid=None,
                  contact_from: float | None = None, held: float = 0.0) -> ArmPlan:
    """The arm's plan for a step's tool `rows` (T, 6+): t, x, y, z, yaw, opening (and the
    efforts), from joints `start`, every link clear of `obstacles` (boxes as a domain's
    ``obstacles`` at the believed sizes).

    The rows are followed from the branch nearest `start`. Where that fails and the rows up
    to `transit_end` (s) are a transit, the transit is planned in joint space instead
    (RRT*), to the first branch at its end, nearest first, from which the rest of the rows
    can be followed: the gripper (and what it holds) checked at the tool's pose by
    `tool_valid(q4)` (the domain's transit check) while the tool points down; an empty hand
    (`held` 0) may tilt on the way, a capsule round the gripper then checked instead. From
    `contact_from` (s: the key pose, where the action starts moving what it handles: a
    pushed tray and its pile, a lifted block) the scene as observed is no longer the scene,
    so the links are checked against the table alone there. Raises ArmPlanningError when
    no plan exists."""
    deadline = time.perf_counter() + STEP_BUDGET_S
    rows = np.asarray(rows, dtype=np.float64)
    scene = links_checker(arm, obstacles)
    table = links_checker(arm, [])
    hand = _hand_checker(arm, obstacles, scene, tool_valid, held)
    start = np.asarray(start, dtype=np.float64)
    try:
        q0 = arm.joints_for(*rows[0, 1:5], start)
    except Unreachable as exc:
        raise ArmPlanningError(f"row 0 ({np.round(rows[0, 1:5], 4).tolist()}): {exc}") from None
    path = _Path(start, rows[0])
    if np.abs(q0 - start).max() > 1e-6:
        # To the step's first pose from where the arm stands (the tool a little off it, or
        # on another turn of a joint): a joint move checked for the links alone, since the
        # fingers may start at what the last action left them touching.
        bridge = _bridge(arm, table, start, q0, seed, deadline)
        n = len(bridge) - 1
        path.add(bridge[1:], [rows[0, 1:]] * n, [0.0] * n, [rows[0, 0]] * n)
    replanned = 0
    try:
        path.extend(_follow_rows(arm, rows, q0, scene, table, contact_from))
    except ArmPlanningError as followed:
        ends = np.flatnonzero(rows[:, 0] <= transit_end + 1e-9) if transit_end else np.zeros(0, dtype=int)
        j = int(ends[-1]) if ends.size else 0
        # The rows after j followed from another branch at row j, reached in joint space:
        # the transit's end where the step has a transit, else the step's first row.
        head, k = _clear_head(arm, rows, q0, j, hand, scene, table, contact_from)
        if head is None:
            raise followed from None
        reasons: list[str] = []
        found = _reach_a_branch(arm, rows, q0, head.qs[-1], j, hand, scene, table, contact_from,
                                seed + j, deadline, reasons, _safe_height(obstacles))
        if found is None:
            tried = "; ".join(dict.fromkeys(reasons)) or "no other branch within the limits"
            raise ArmPlanningError(f"{followed} (and from the other branches at row {j}: {tried})"[:400]) from None
        bridge, rest = found
        n = len(bridge) - 1
        path.extend(head)
        path.add(bridge[1:], [rows[j, 1:]] * n, [0.0] * n, [rows[k, 0]] * (n - 1) + [rows[j, 0]])
        path.extend(rest)
        replanned = n
    qs_arr = np.array(path.qs)
    timed = time_joint_path(qs_arr, np.array([jt.max_velocity for jt in arm.joints]),
                            np.full(len(arm.joints), arm.acceleration), nominal_dt=np.array(path.dts))
    tool, tilt = _tool_rows(arm, qs_arr, np.array(path.rs)[:, 4:])
    out = np.column_stack([timed.t + rows[0, 0], tool])
    return ArmPlan(timed, out, qs_arr[-1], np.array(path.src), replanned, tilt if replanned else 0.0)


def _reach_a_branch(arm: Arm, rows: np.ndarray, q0: np.ndarray, qa: np.ndarray, j: int, hand, scene, table,
                    contact_from, seed: int, deadline: float, reasons: list[str], safe_z: float):
    """(bridge, the rest's path): a branch at row `j` from which the rest of the rows can be
    followed, and a joint path to it from `qa`; None, with `reasons`, if there is none.

    The cheap moves come first, over every candidate, before any search: the straight joint
    segment; then up, across and down (``_over_the_top``: the tool lifted above everything
    in the scene on its branch, the arm reconfigured up there, lowered on the new branch),
    what an industrial cell does to change its wrist or shoulder; only then RRT*, nearest
    first. A search that fails costs up to 5 s of the step's 10, and a wrist flip a
    lift makes free must not wait behind two failed reconfigurations near a tower."""
    ready = []
    for qj in _candidates(arm, rows[j], qa):
        if j == 0 and np.abs(qj - q0).max() < 1e-6:
            continue                          # the branch that failed
        hit = scene.contact(qj)
        if hit is not None:
            reasons.append(f"the {hit[0]} meets " + ("the table" if hit[1] < 0 else f"obstacle {hit[1]}"))
            continue
        try:
            rest = _follow_rows(arm, rows[j:], qj, scene, table, contact_from)
        except ArmPlanningError as exc:
            reasons.append(str(exc).split(": ", 1)[-1])
            continue
        if _clear(hand, np.stack([qa, qj])):
            return densify_joints(np.stack([qa, qj]), 0.05), rest
        ready.append((qj, rest))
    for qj, rest in ready:
        via = _over_the_top(arm, qa, qj, safe_z)
        if via is not None and _clear(hand, via):
            return densify_joints(via, 0.05), rest
    for qj, rest in ready:
        try:
            return _bridge(arm, hand, qa, qj, seed, deadline), rest
        except ArmPlanningError as exc:
            reasons.append(str(exc).split(": ", 1)[-1])
    return None


def _clear(is_valid, waypoints: np.ndarray) -> bool:
    """Whether every joint segment between the waypoints is valid, checked every CHECK_STEP."""
    return all(is_valid(q) for q in densify_joints(waypoints, CHECK_STEP)[1:])


def _safe_height(obstacles: list) -> float:
    """A tool height above everything in the scene (m): the highest obstacle's top (a box's
    corners at its rotation) and SAFE_CLEARANCE."""
    tops = [float(c[2] + np.abs(np.asarray(r)[2]) @ np.asarray(h)) for c, h, r in obstacles]
    return max(tops, default=0.0) + SAFE_CLEARANCE


def _over_the_top(arm: Arm, qa: np.ndarray, qb: np.ndarray, safe_z: float) -> np.ndarray | None:
    """Joint waypoints from `qa` to `qb` (both with the tool pointing down) through the same
    tool points lifted to `safe_z`, each lift on its own branch: (4, 6), or None where a lifted
    pose is out of reach."""
    lifted = []
    for q in (qa, qb):
        t = arm.tool(q)
        try:
            lifted.append(arm.joints_for(t[0, 3], t[1, 3], max(safe_z, float(t[2, 3])),
                                         math.atan2(t[1, 0], t[0, 0]), q))
        except Unreachable:
            return None
    return np.stack([qa, lifted[0], lifted[1], qb])


def _hand_checker(arm: Arm, obstacles: list, links, tool_valid, held: float):
    """is_valid(q) for a joint-space move: the links clear, and the gripper clear. Pointing
    down (within TILT) the gripper and what it holds are checked at the tool's pose by
    `tool_valid(x, y, z, yaw)` (the domain's transit check). An empty hand may tilt on the
    way (the particle worlds skip a checked transit: nothing is touched in free space): it
    is then a capsule of HAND_RADIUS from the flange to the fingertips. A held block (side
    `held` > 0) keeps the tool pointing down: it must stay upright."""
    tool_end = float(arm.flange_to_tool[2, 3])
    hand = links_checker(_with_hand(arm, tool_end), obstacles)

    def is_valid(q: np.ndarray) -> bool:
        if not links(q):
            return False
        t = arm.tool(q)
        if -float(t[2, 2]) >= math.cos(TILT):
            return tool_valid is None or bool(tool_valid(np.array([*t[:3, 3], math.atan2(t[1, 0], t[0, 0])])))
        return held <= 0.0 and hand(q)
    return is_valid


def _with_hand(arm: Arm, tool_end: float) -> Arm:
    """The arm with its gripper as one more link: a capsule from the flange to the fingertips."""
    out = copy.copy(arm)
    out.links = tuple(arm.links) + (Capsule("hand", 6, (0.0, 0.0, 0.0), (0.0, 0.0, tool_end), HAND_RADIUS),)
    return out


def _bridge(arm: Arm, is_valid, qa: np.ndarray, qb: np.ndarray, seed: int, deadline: float) -> np.ndarray:
    """A joint-space path from `qa` to `qb` (RRT*, straight first: between two poses of
    one wrist branch pointing down the straight joint segment keeps the tool down, since
    the wrist's second joint stays put and the three parallel axes' sum moves linearly).
    Refused once the step's `deadline` (perf_counter seconds) has passed."""
    left = deadline - time.perf_counter()
    if left <= 0.0:
        raise ArmPlanningError(f"joint-space transit: the step's planning budget of {STEP_BUDGET_S:g} s is spent")
    try:
        return plan_joint_rrtstar(qa, qb, is_valid, arm.low, arm.high, seed=seed, iterations=RRT_ITERATIONS,
                                  resolution=0.05, validity_resolution=CHECK_STEP, time_limit_s=min(5.0, left))
    except MotionPlanningError as exc:
        raise ArmPlanningError(f"joint-space transit: {exc}") from None
