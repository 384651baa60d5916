"""Response models of the HTTP service (pydantic v2): what the routes return, as published
in the OpenAPI schema."""
from __future__ import annotations

from datetime import datetime, timezone
from typing import Any, Literal

from pydantic import BaseModel, Field

TaskStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
SessionStatus = Literal["active", "finished", "closed"]

TRAJECTORY_COLUMNS = ["t", "x", "y", "z", "yaw", "opening"]


def ts(value: float | None) -> datetime | None:
    return None if value is None else datetime.fromtimestamp(value, tz=timezone.utc)


# ------------------------------------------------------------------------- responses
class ErrorBody(BaseModel):
    detail: str


class Progress(BaseModel):
    episodes_done: int
    episodes: int


class NodeRun(BaseModel):
    node_id: str = Field(description="Ray node id")
    hostname: str
    shards: int = Field(description="this task's shard actors on the node (at the start of its run)")
    particle_actions: int = Field(description="particle-actions the node simulated for this task")


class TaskView(BaseModel):
    id: str
    status: TaskStatus
    spec: dict[str, Any]
    progress: Progress
    latest: dict[str, Any] | None = Field(None, description="the last episode's record")
    cancel_requested: bool
    attempts: int = Field(description="how many times the worker started it (restarts resume)")
    error: str | None
    result: dict[str, Any] | None = Field(None, description="summary and runtime when succeeded")
    nodes: list[NodeRun] | None = Field(
        None, description="the Ray nodes that ran this task's particles: the result's "
                          "runtime.nodes when it succeeded; while it runs, as of its last episode")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    links: dict[str, str]


class CancelView(TaskView):
    detail: str


class TaskList(BaseModel):
    items: list[TaskView]
    total: int
    limit: int
    offset: int
    next_offset: int | None
    skipped: int = Field(0, description="rows of this page left out: their stored data is corrupt")


class TaskCreated(BaseModel):
    id: str
    status: TaskStatus
    location: str
    links: dict[str, str]


class Histogram(BaseModel):
    edges: list[float]
    weights: list[float]


class Joint(BaseModel):
    x_edges: list[float]
    y_edges: list[float]
    weights: list[list[float]]


class BeliefSummary(BaseModel):
    n: int
    ess: float
    mean: list[float]
    std: list[float]
    low: list[float]
    high: list[float]
    histogram: list[Histogram] = Field(description="one weighted histogram per property dimension")
    joint: Joint | None = Field(None, description="with two dimensions (size, density): their "
                                                  "joint weighted histogram, weights[i][j] for x bin i "
                                                  "(dimension 0) and y bin j (dimension 1)")
    degenerate_updates: int


class BeliefView(BaseModel):
    run_id: str
    agent: str
    episodes_done: int
    property: str = "block_size_m"
    learns_belief: bool = Field(description="false for agents that keep L at the prior (tmp_rl, toep)")
    posterior: dict[str, Any] = Field(description="size_mean, size_std (m); per dimension mean/std; "
                                                  "`properties`: {name: {mean, std, unit}} for every "
                                                  "property of L (the histogram has one entry per dimension)")
    belief: BeliefSummary | None
    true_size: float | None = None


class CurvePoint(BaseModel):
    episode: int
    utility: float
    size_mean: float | None = Field(None, description="L's size (m); null where L has no size: see `properties`")
    size_std: float | None = None
    actions: int
    delivered: int
    loads: list[int]
    properties: dict[str, dict[str, Any]] | None = Field(
        None, description="every property of L: {name: {mean, std, unit}} (e.g. size, density)")


class CurveView(BaseModel):
    run_id: str
    agent: str
    true_size: float | None
    points: list[CurvePoint]


class JointPoint(BaseModel):
    positions: list[float] = Field(description="rad, one per joint in joint_names' order")
    velocities: list[float] = Field(description="rad/s")
    accelerations: list[float] = Field(description="rad/s^2")
    time_from_start: float = Field(description="s from the step's start")


class JointTrajectory(BaseModel):
    joint_names: list[str]
    points: list[JointPoint]


class StepView(BaseModel):
    episode: int
    step: int
    step_id: str | None = Field(None, description="echo it as the observation's `step_id`")
    action: str
    pose: list[float]
    trajectory: list[list[float]]
    trajectory_columns: list[str] = Field(
        TRAJECTORY_COLUMNS, description="the trajectory's columns: t (s), x, y, z (m), yaw (rad), "
        "opening (m); with mass in Y also grip_force (N per finger) and force_limit (N the wrist "
        "may exert beyond carrying the gripper; below the scene's default, a guarded move: the "
        "rest of the trajectory continues from where the gripper got to)")
    expected: list[str] = Field(description="the planned symbolic state after the action")
    joint_trajectory: JointTrajectory | None = Field(None, description=(
        "an arm's joint trajectory for this step, in the shape of a control_msgs/FollowJointTrajectory "
        "goal's trajectory (null for the floating gripper); the trajectory rows above are its tool path "
        "at its times (GET /v1/robots/{name} has the kinematics to check it)"))


class SessionView(BaseModel):
    id: str
    status: SessionStatus
    spec: dict[str, Any]
    episodes: int
    episodes_done: int
    in_episode: bool
    step: int = Field(description="actions observed in the current episode")
    pending: StepView | None
    posterior: dict[str, Any] | None
    latest: dict[str, Any] | None = Field(None, description="the last finished episode's record")
    last_observation: dict[str, Any] | None = Field(
        None, description="the last accepted observation: step_id, action, success, configuration, "
                          "state, measurements")
    created_at: datetime
    updated_at: datetime
    links: dict[str, str]


class SessionList(BaseModel):
    items: list[SessionView]
    total: int
    limit: int
    offset: int
    next_offset: int | None
    skipped: int = Field(0, description="rows of this page left out: their stored data is corrupt")


class SessionCreated(SessionView):
    next: StepView | None = Field(None, description="the first pending step, if an episode started")


class NextView(BaseModel):
    session_id: str
    episode: int
    in_episode: bool
    pending: StepView | None = Field(None, description="the action to execute; null when the "
                                                       "episode is over")


class ObservationResult(BaseModel):
    session_id: str
    report: dict[str, Any] = Field(description="action, success, observed state; ess and "
                                               "resampled when the belief learns, with the "
                                               "update's information (KL, nats), whether a "
                                               "particle explained the outcome, and the rows "
                                               "redrawn from the prior (injected)")
    episode_done: bool
    episode: dict[str, Any] | None = Field(None, description="the episode's record when it ended")
    next: StepView | None
    posterior: dict[str, Any]


class EpisodeStarted(BaseModel):
    session_id: str
    episode: int
    next: StepView | None


class WorkerHealth(BaseModel):
    state: Literal["idle", "running", "retrying", "stalled", "dead", "stopped"]
    ok: bool
    last_error: str | None = Field(None, description="the last storage or bookkeeping error")
    consecutive_errors: int
    last_beat_s: float = Field(description="seconds since the task worker last showed progress")


class Health(BaseModel):
    status: Literal["ok", "degraded"] = Field(description="`degraded` (HTTP 503) when the task "
                                                          "worker is dead, stalled or retrying")
    version: str
    ray: str
    queued: int
    running: str | None = Field(description="the running task's id (null without a token "
                                            "when the server has one)")
    auth: bool
    worker: WorkerHealth


class DomainView(BaseModel):
    """A registered domain, as `tmoc domains --json` shows it."""

    name: str
    description: str
    source: str = Field(description="builtin, or plugin (<distribution>)")
    physics: str
    task: str
    objects: list[str]
    n_blocks: int = Field(description="the domain's default object count (old name of n_objects)")
    n_objects: int = Field(description="the domain's default object count: a task or session "
                                       "without `n_objects` has this many")
    properties: list[dict[str, Any]] = Field(description="L: name, unit, prior, default truth")
    measurements: dict[str, Any]
    actions: list[str]
    contexts: list[list[Any]] = Field(description="T's contexts: [action, integer]")
    utility: dict[str, float]
    probe_actions: list[str]
    robot_base: list[float] | None = Field(None, description=(
        "where an arm's base stands in this scene: x, y, z (m), yaw (rad) in the world frame; its world pose "
        "replaces the robot's `base` (GET /v1/robots); null: the robot's own"))


class DomainList(BaseModel):
    items: list[DomainView]
    total: int
    broken: dict[str, str] = Field(default_factory=dict, description=(
        "installed domain plugins left out, with why (they do not load, validate or import)"))


class RobotJoint(BaseModel):
    name: str
    low: float | None = Field(description="lowest position (rad, or m for a prismatic axis); null: unbounded")
    high: float | None = Field(description="highest position; null: unbounded")
    max_velocity: float | None = Field(description="per second; null: none declared")
    max_acceleration: float | None = Field(description="per second squared; null: the maker publishes none")


class RobotLink(BaseModel):
    name: str
    frame: int = Field(description="0: the base frame; 1-6: the Denavit-Hartenberg link frames (6: the flange)")
    a: list[float] = Field(description="one end of the capsule's axis in that frame (m)")
    b: list[float] = Field(description="the other end (m)")
    radius: float = Field(description="m")


class RobotView(BaseModel):
    name: str
    kind: str = Field(description="floating (the tool point is commanded directly) or arm")
    description: str
    joints: list[RobotJoint]
    dh: dict[str, float] | None = Field(None, description=(
        "an arm's standard Denavit-Hartenberg parameters (m): d1, a2, a3, d4, d5, d6; link i's frame is "
        "Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i) after link i-1's"))
    dh_alpha: list[float] | None = Field(None, description="the twists alpha_1..6 (rad)")
    base: list[list[float]] | None = Field(None, description="4 x 4 world pose of the arm's base frame")
    flange_to_tool: list[list[float]] | None = Field(None, description=(
        "4 x 4 pose of the tool point (the fingertip centre) in the flange's frame: the tool's world pose is "
        "base @ forward(q) @ flange_to_tool"))
    home: list[float] | None = Field(None, description="the arm's home joint positions (rad)")
    links: list[RobotLink] | None = Field(None, description=(
        "an arm's collision shapes: capsules in its link frames, checked against the believed scene"))
    trajectory_acceleration: float | None = Field(None, description=(
        "the joint acceleration (rad/s^2) the service times an arm's trajectories with"))
    link_masses: list[float] | None = Field(None, description=(
        "an arm's link masses (kg) per joint frame 1-6, as its maker publishes them (the simulated arm's)"))
    joint_torques: list[float] | None = Field(None, description=(
        "an arm's joint torque limits (N m), as its maker publishes them (the simulated arm's)"))


class RobotList(BaseModel):
    items: list[RobotView]
    total: int
    broken: dict[str, str] = Field(default_factory=dict, description=(
        "installed robot plugins left out, with why (they do not load or are not robots)"))


# ------------------------------------------------------------------------- dashboard views
class FramePanel(BaseModel):
    label: str = Field(description="real, heaviest, matched or did not match")
    title: str
    particle: int | None = None
    weight: float | None = Field(None, description="the particle's weight before the action's update")
    size_mm: float | None = None
    matched: bool | None = Field(None, description="its predicted outcome matched the real one "
                                                   "(as the likelihood judged it)")
    success: bool | None = Field(None, description="the action had its planned effect in this world")


class FrameView(BaseModel):
    name: str = Field(description="e003-end (episode 3's end) or e003-s007 (its action 7 failed)")
    kind: Literal["episode_end", "failed_action"]
    episode: int
    step: int | None
    action: str | None
    panels: list[FramePanel] = Field(description="left to right in the PNG")
    bytes: int
    created_at: datetime
    url: str


class FrameList(BaseModel):
    run_id: str
    items: list[FrameView] = Field(description="oldest first")
    total: int
    max_frames: int = Field(description="frames kept per task (the oldest go first); --max-frames")


class TransitionRow(BaseModel):
    action: str
    context: int
    p: float = Field(description="T: the probability that the action succeeds in this context")
    successes: float = Field(description="weighted successes T is estimated from (real + simulated)")
    trials: float
    real_successes: float
    real_trials: float
    sim_discount: float | None = Field(None, description="the share of the simulated counts T uses in "
                                                         "this context (1: reality agrees with the particle "
                                                         "worlds so far; near 0: it contradicts them); "
                                                         "null without simulated counts")
    counterfactual_discount: float | None = Field(
        None, description="the share of the counterfactual snapshot's counts T uses in this action's "
                          "contexts (one power prior per action; counterfactual_rows): 1 before any real "
                          "outcome contradicts the worlds; null without a snapshot")


class TransitionView(BaseModel):
    run_id: str
    episodes_done: int
    rows: list[TransitionRow] = Field(description="one per context, in the domain's order (the "
                                                  "optimistic prior before the first episode)")


class PurgeView(BaseModel):
    id: str
    status: str = Field(description="the task's or session's status when it was purged")
    purged: dict[str, int] = Field(description="rows deleted per stored table")
