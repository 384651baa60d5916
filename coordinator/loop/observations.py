"""A robot's observation (as JSON) read into an :class:`~coordinator.loop.reality.Observation`
of a scene, checked against that scene's domain.

The HTTP service calls these for an external robot; a message names the field that does
not fit, so the client can be told exactly what to fix (``ObservationError.field``).
"""
from __future__ import annotations

import numpy as np

from sim_workers.configuration import Configuration

from ..domains import measurement_channels
from .reality import Observation

class ObservationError(ValueError):
    """The observation does not fit the scene; `field` names the offending part."""

    def __init__(self, message: str, field: str) -> None:
        super().__init__(message)
        self.field = field


def parse_observation(physics, task, n_blocks: int, body: dict, robot=None) -> tuple[Observation, dict]:
    """The Observation of `body` ({configuration: {robot, objects}, state?, measurements?})
    in the scene of `physics` (the domain's physics half) and `task` (its task half), and
    its canonical JSON form (what is stored and replayed). A missing state is derived from
    the configuration, missing measurements are measured from it; `joint_positions`, an
    arm's measured joints, are checked against `robot` (the session's arm; None: the floating
    gripper, which has none to report). Raises ObservationError."""
    config = _configuration(physics, body["configuration"])
    state = _state(physics, task, n_blocks, config, body.get("state"))
    meas = _measurements(physics, config, body.get("measurements"))
    canonical = {"configuration": config.to_dict(), "state": sorted(state),
                 "measurements": [None if np.isnan(v) else float(v) for v in meas]}
    joints = _joints(robot, body.get("joint_positions"))
    if joints is not None:
        canonical["joint_positions"] = joints.tolist()
    return Observation(config, frozenset(state), meas, joints), canonical


def from_canonical(d: dict) -> Observation:
    """The Observation of a stored canonical form (see parse_observation)."""
    joints = d.get("joint_positions")
    return Observation(Configuration.from_dict(d["configuration"]), frozenset(d["state"]),
                       np.array([np.nan if v is None else v for v in d["measurements"]], dtype=float),
                       None if joints is None else np.array(joints, dtype=float))


def _joints(robot, values: list | None) -> np.ndarray | None:
    """An arm's measured joint positions, checked against its joints and limits."""
    if values is None:
        return None
    if robot is None:
        raise ObservationError("joint_positions: this session's robot is the floating gripper, which has "
                               "no joints to report (create the session with an arm, e.g. robot ur5e)",
                               "joint_positions")
    q = np.array(values, dtype=float)
    if q.shape != (len(robot.joints),):
        raise ObservationError(f"joint_positions: {q.size} values, the {robot.name} has {len(robot.joints)} "
                               f"joints ({', '.join(robot.joint_names)})", "joint_positions")
    out = np.flatnonzero((q < robot.low - 1e-6) | (q > robot.high + 1e-6))
    if out.size:
        j = robot.joints[int(out[0])]
        raise ObservationError(f"joint_positions: {j.name} = {q[out[0]]:.4g} rad is outside its limits "
                               f"[{j.low:.4g}, {j.high:.4g}]", "joint_positions")
    return q


def _configuration(physics, conf: dict) -> Configuration:
    n_objects = len(physics.object_names)
    if len(conf["objects"]) != n_objects:
        raise ObservationError(
            f"configuration.objects: {len(conf['objects'])} rows, this scene has {n_objects} "
            f"objects ({', '.join(physics.object_names)})", "configuration.objects")
    for i, row in enumerate(conf["objects"]):
        norm = float(np.linalg.norm(row[3:]))
        if abs(norm - 1.0) > 1e-2:
            raise ObservationError(f"configuration.objects[{i}]: quaternion norm {norm:.4g}, "
                                   "expected a unit quaternion (x, y, z, w)", "configuration.objects")
    return Configuration(np.array(conf["robot"], dtype=float), np.array(conf["objects"], dtype=float))


def _state(physics, task, n_blocks: int, config: Configuration, atoms: list | None):
    if atoms is None:
        return physics.symbolic_state(config)
    try:
        state = task.parse_state(atoms)
    except ValueError as exc:
        raise ObservationError(f"state: {exc}", "state") from None
    blocks = task.blocks(state)
    if len(blocks) != n_blocks:
        raise ObservationError(f"state: names {len(blocks)} blocks, this scene has {n_blocks}",
                               "state")
    return state


def _measurements(physics, config: Configuration, values: list | None) -> np.ndarray:
    derived = physics.measurements(config)
    if values is None:
        return derived
    # null: a channel the robot did not measure (e.g. the held weight after a stack)
    meas = np.array([np.nan if v is None else v for v in values], dtype=float)
    # Channels a robot does not report at the end (e.g. a client written before the held
    # weight and grasp width existed) are not measured: NaN, never a guess.
    # (channels read from the sensors during an action, issue 14: last in the vector)
    n_sensed = sum(1 for c in measurement_channels(physics) if c.get("sensed"))
    if derived.size - n_sensed <= meas.size < derived.size:
        meas = np.concatenate([meas, np.full(derived.size - meas.size, np.nan)])
    if meas.shape != derived.shape:
        names = ", ".join(c["name"] for c in measurement_channels(physics))
        raise ObservationError(f"measurements: {meas.size} values, expected {derived.size} "
                               f"({names})", "measurements")
    return meas


__all__ = ["ObservationError", "from_canonical", "parse_observation"]
