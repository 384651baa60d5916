"""Request and response models of the HTTP service (pydantic v2).

``requests``: the task and session specs (built per server, with its limits) and the
robot's observations; ``responses``: what the routes return. Both are re-exported here:
routes use ``from api import schemas as S`` and ``S.<Model>``.
"""
from .requests import (TAG_PREFIX, ConfigurationIn, InitialObservation, StepObservation, StrictCosts,
                       run_config, session_create_model, spec_body, task_spec_model)
from .responses import (TRAJECTORY_COLUMNS, BeliefSummary, BeliefView, CancelView, CurvePoint,
                        CurveView, DomainList, DomainView, EpisodeStarted, ErrorBody, FrameList,
                        FramePanel, FrameView, Health, Histogram, Joint, NextView, NodeRun,
                        ObservationResult, Progress, PurgeView, RobotJoint, RobotList, RobotView, SessionCreated,
                        SessionList, SessionStatus,
                        SessionView, StepView, TaskCreated, TaskList, TaskStatus, TaskView,
                        TransitionRow, TransitionView, WorkerHealth, ts)

__all__ = [
    "TAG_PREFIX", "ConfigurationIn", "InitialObservation", "StepObservation", "StrictCosts",
    "run_config", "session_create_model", "spec_body", "task_spec_model",
    "TRAJECTORY_COLUMNS", "BeliefSummary", "BeliefView", "CancelView", "CurvePoint", "CurveView",
    "DomainList", "DomainView", "EpisodeStarted", "ErrorBody", "FrameList", "FramePanel",
    "FrameView", "Health", "Histogram", "Joint", "NextView", "NodeRun", "ObservationResult",
    "Progress", "PurgeView", "RobotJoint", "RobotList", "RobotView", "SessionCreated", "SessionList",
    "SessionStatus", "SessionView", "StepView",
    "TaskCreated", "TaskList", "TaskStatus", "TaskView", "TransitionRow", "TransitionView",
    "WorkerHealth", "ts",
]
