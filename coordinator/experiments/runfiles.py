"""Run files: one finished run is ``DIR/runs/<setting>/<r>.json``, a running one's latest
checkpoint ``<r>.partial.json``.

Resume. A run file holds the run's full config; with ``--resume`` a file whose config is
the one asked for is reused as is (nothing finished is recomputed), one whose config
differs is refused (``ResumeError``). Every file is written atomically (a temporary file,
then ``os.replace``), so a torn write is never read as a run.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..run_config import RunConfig, stored_run_config
from .spec import Setting, Spec


def jsonable(obj):
    """`obj` as it reads back from JSON (tuples become lists, keys strings)."""
    return json.loads(json.dumps(obj))


def run_path(out: Path, setting: Setting, r: int, partial: bool = False) -> Path:
    """Where run `r` of `setting` is kept (its checkpoint with `partial`)."""
    return Path(out) / "runs" / setting.key / (f"{r}.partial.json" if partial else f"{r}.json")


def write_atomic(path: Path, text: str) -> None:
    """Write `text` to `path` so that a reader sees the old file or the new one, never half."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)
class ResumeError(ValueError):
    """An existing run file cannot be used for this call (the message says why)."""


def _config_diff(stored: dict, wanted: dict) -> str:
    keys = sorted(k for k in set(stored) | set(wanted) if stored.get(k) != wanted.get(k))
    return ", ".join(f"{k}={stored.get(k)!r} (asked {wanted.get(k)!r})" for k in keys)


# What a checkpoint needs to be continued (coordinator.loop.session.Session.from_checkpoint).
CHECKPOINT_KEYS = frozenset({"version", "config", "belief", "experience", "rng", "episode", "episodes",
                             "particle_actions", "particle_steps"})


def _well_formed(data: dict, config: RunConfig) -> bool:
    """Whether a run file holds what resuming reads: a finished run every episode of
    `config` (a dict each, with its utility) and a summary; a partial one a checkpoint at
    an episode boundary short of the last (issue 25: `[]`, `{}`, or a run one episode
    short, was reused as finished or failed with a traceback)."""
    if "checkpoint" in data:
        ck = data["checkpoint"]
        sess = ck.get("session") if isinstance(ck, dict) else None
        return (isinstance(sess, dict) and CHECKPOINT_KEYS <= set(sess) and "reality_rng" in ck
                and isinstance(sess["episode"], int) and 0 < sess["episode"] < config.episodes
                and isinstance(sess["episodes"], list) and len(sess["episodes"]) == sess["episode"])
    eps = data.get("episodes")
    return (isinstance(eps, list) and len(eps) == config.episodes
            and all(isinstance(e, dict) and isinstance(e.get("utility"), (int, float)) for e in eps)
            and isinstance(data.get("summary"), dict))


def _as_now(stored) -> dict | None:
    """A run file's config as today's RunConfig reads it: a field added since it was made
    takes what such a file ran with (``stored_run_config``), so a sweep resumes across the
    addition of a setting whose stored default is what it asks for."""
    if not isinstance(stored, dict):
        return stored
    try:
        return jsonable(stored_run_config(stored).model_dump())
    except (ValueError, TypeError):
        return stored


def read_run(path: Path, config: RunConfig) -> dict | None:
    """A finished or partial run file if its config is `config`; ResumeError if it was made
    with another config; None if unreadable or not a whole run (a torn write, a file
    edited by hand: recomputed)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict):
        return None
    wanted = jsonable(config.model_dump())
    stored = _as_now(data.get("config"))
    if stored != wanted:
        raise ResumeError(f"{path} was made with other settings: "
                          f"{_config_diff(stored or {}, wanted)}")
    return data if _well_formed(data, config) else None


def existing_runs(out: Path, spec: Spec) -> list[Path]:
    """Every finished or partial run file of `spec` in `out`."""
    return [p for s in spec.settings for p in sorted((Path(out) / "runs" / s.key).glob("*.json"))]


def store_run(out: Path, spec: Spec, k: int, r: int, config: RunConfig, result: dict) -> None:
    """Keep a finished run as its run file (and drop its checkpoint)."""
    setting = spec.settings[k]
    record = {"experiment": spec.name, "setting": setting.key, "label": setting.label, "run": r,
              "seed": config.seed, "config": jsonable(config.model_dump()),
              "episodes": result["episodes"], "summary": result["summary"],
              "runtime": result["runtime"]}
    write_atomic(run_path(out, setting, r), json.dumps(record))
    part = run_path(out, setting, r, partial=True)
    if part.exists():
        part.unlink()


def store_checkpoint(out: Path, setting: Setting, r: int, config: RunConfig, checkpoint: dict) -> None:
    """Keep a running run's latest checkpoint, unless the run has finished meanwhile."""
    if not run_path(out, setting, r).exists():
        write_atomic(run_path(out, setting, r, partial=True),
                     json.dumps({"config": jsonable(config.model_dump()), "checkpoint": checkpoint}))
