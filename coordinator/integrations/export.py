"""Step records as MCAP (issue 28): what a run, a task or a robot session did, per step, in
a format robotics tools read.

MCAP rather than a LeRobot dataset: MCAP is ROS 2's default bag storage and what Foxglove,
the system-identification tools of Isaac Sim and MuJoCo Playground read, and it is
self-describing (every channel carries its JSON schema) and indexed, so a reader needs
nothing of ours. A LeRobot dataset is built for fixed-rate streams of images and joint
states feeding policy training (parquet plus videos, torch and the Hugging Face stack to
read it); a TMOC step is one symbolic action with a trajectory, two configurations, a few
measurements and a belief, which that layout would flatten into frames.

Channels (JSON messages, ``jsonschema`` schemas), log time the moment the step was
observed:

- ``/tmoc/step``: episode, step, action, key pose, configurations before and after (with
  the objects' names), symbolic states before and after and the expected one, success,
  the measurements (null where a channel did not measure) and the belief's summary.
- ``/tmoc/trajectory``: the commanded trajectory of that step (its columns and points).
- ``/tmoc/episode``: each finished episode's record (utility, failures, loads, posterior).

A metadata record ``tmoc`` carries the source (run, task or session), its domain and its
configuration.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import BinaryIO, Iterable

from ..loop.step_record import STEPS_FILE

PROFILE = "tmoc"
STEP_TOPIC, TRAJECTORY_TOPIC, EPISODE_TOPIC = "/tmoc/step", "/tmoc/trajectory", "/tmoc/episode"

_NUMS = {"type": "array", "items": {"type": ["number", "null"]}}
_ATOMS = {"type": "array", "items": {"type": "string"}}
STEP_SCHEMA = {
    "title": "tmoc.Step", "type": "object",
    "properties": {
        "episode": {"type": "integer"}, "step": {"type": "integer"}, "action": {"type": "string"},
        "pose": _NUMS, "objects": _ATOMS,
        "configuration_before": _NUMS, "configuration_after": _NUMS,
        "state_before": _ATOMS, "state_after": _ATOMS, "expected": _ATOMS,
        "success": {"type": "boolean"}, "measurement_channels": _ATOMS, "measurements": _NUMS,
        "belief": {"type": "object"},
    },
    "required": ["episode", "step", "action", "configuration_before", "configuration_after",
                 "state_after", "success", "measurements"],
}
TRAJECTORY_SCHEMA = {
    "title": "tmoc.Trajectory", "type": "object",
    "properties": {"episode": {"type": "integer"}, "step": {"type": "integer"}, "action": {"type": "string"},
                   "columns": _ATOMS, "points": {"type": "array", "items": _NUMS}},
    "required": ["episode", "step", "columns", "points"],
}
EPISODE_SCHEMA = {"title": "tmoc.Episode", "type": "object",
                  "properties": {"episode": {"type": "integer"}, "utility": {"type": "number"}},
                  "required": ["episode"]}


class ExportError(ValueError):
    """Nothing to export from a source, or a source that is not one."""


def _ns(seconds: float) -> int:
    return max(0, int(round(float(seconds) * 1e9)))


def write_mcap(out: BinaryIO, steps: Iterable[dict], episodes: Iterable[dict], meta: dict) -> dict:
    """Write `steps` (``coordinator.loop.step_record`` dicts) and `episodes` (episode records)
    to `out` as MCAP; `meta` (source, domain, config) as its ``tmoc`` metadata. Returns
    the message counts per topic."""
    from mcap.writer import Writer

    w = Writer(out)
    w.start(profile=PROFILE, library="tmoc-service")
    chans = {}
    for topic, schema in ((STEP_TOPIC, STEP_SCHEMA), (TRAJECTORY_TOPIC, TRAJECTORY_SCHEMA),
                          (EPISODE_TOPIC, EPISODE_SCHEMA)):
        sid = w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
        chans[topic] = w.register_channel(topic, "json", sid)
    w.add_metadata("tmoc", {k: v if isinstance(v, str) else json.dumps(v) for k, v in meta.items()})
    counts = {STEP_TOPIC: 0, TRAJECTORY_TOPIC: 0, EPISODE_TOPIC: 0}
    last = {}                        # episode -> the log time of its last step

    def put(topic: str, t: int, message: dict) -> None:
        w.add_message(chans[topic], log_time=t, publish_time=t, sequence=counts[topic],
                      data=json.dumps(message, separators=(",", ":")).encode())
        counts[topic] += 1

    for rec in steps:
        t = _ns(rec.get("time", 0.0))
        last[rec["episode"]] = t
        traj = rec.get("trajectory") or {"columns": [], "points": []}
        put(STEP_TOPIC, t, {k: v for k, v in rec.items() if k not in ("trajectory", "time", "version")})
        put(TRAJECTORY_TOPIC, t, {"episode": rec["episode"], "step": rec["step"], "action": rec["action"],
                                  "columns": traj["columns"], "points": traj["points"]})
    for record in episodes:
        put(EPISODE_TOPIC, last.get(record.get("episode"), 0), record)
    w.finish()
    return counts


def _json(text: str, where: str):
    try:
        return json.loads(text)
    except ValueError as exc:
        raise ExportError(f"{where}: not JSON ({exc})") from None


def _step_problem(rec) -> str | None:
    """Why a step record cannot be exported (None: it can)."""
    if not isinstance(rec, dict):
        return "not an object"
    for key, kind in (("episode", int), ("step", int), ("action", str)):
        if not isinstance(rec.get(key), kind) or isinstance(rec.get(key), bool):
            return f"no {key!r} ({kind.__name__})"
    traj = rec.get("trajectory")
    if traj is not None and not (isinstance(traj, dict) and isinstance(traj.get("columns"), list)
                                 and isinstance(traj.get("points"), list)):
        return "'trajectory' is not {columns: [...], points: [...]}"
    if not isinstance(rec.get("time", 0.0), (int, float)) or isinstance(rec.get("time"), bool):
        return "'time' is not a number"
    return None


def read_run(run_dir: str | Path) -> tuple[list[dict], list[dict], dict]:
    """(steps, episodes, meta) of a ``tmoc run`` output directory; ExportError naming what
    is missing or malformed (the file, and the line of a step record), never a traceback."""
    d = Path(run_dir)
    result, steps = d / "result.json", d / STEPS_FILE
    if not d.is_dir():
        raise ExportError(f"{run_dir}: not a directory (a `tmoc run --out` directory)")
    if not result.is_file() or not steps.is_file():
        missing = result.name if not result.is_file() else steps.name
        raise ExportError(f"{run_dir}: no {missing} (a `tmoc run --out` directory of this version)")
    try:
        result_text = result.read_text(encoding="utf-8")
        steps_text = steps.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ExportError(f"{run_dir}: unreadable ({exc})") from None
    data = _json(result_text, str(result))
    if not isinstance(data, dict):
        raise ExportError(f"{result}: not a JSON object")
    config, episodes = data.get("config", {}), data.get("episodes", [])
    if not isinstance(config, dict):
        raise ExportError(f"{result}: 'config' is not an object")
    if not isinstance(episodes, list) or not all(isinstance(e, dict) for e in episodes):
        raise ExportError(f"{result}: 'episodes' is not a list of objects")
    records = []
    for n, line in enumerate(steps_text.splitlines(), start=1):
        if not line.strip():
            continue
        rec = _json(line, f"{steps}, line {n}")
        why = _step_problem(rec)
        if why is not None:
            raise ExportError(f"{steps}, line {n}: a step record with {why}" if why.startswith("no ")
                              else f"{steps}, line {n}: {why}")
        records.append(rec)
    meta = {"source": "run", "domain": str(config.get("domain", "")), "config": config}
    return records, list(episodes), meta


def export_run(run_dir: str | Path, out_path: str | Path) -> dict:
    """A run directory as an MCAP file at `out_path`; the message counts."""
    steps, episodes, meta = read_run(run_dir)
    with open(out_path, "wb") as f:
        return write_mcap(f, steps, episodes, meta)
