"""A sweep's run files resume across a setting added since they were made (its stored
default stands in), and are refused where the setting asked differs."""
from __future__ import annotations

import json

import pytest

from coordinator.experiments.runfiles import ResumeError, jsonable, read_run
from coordinator.run_config import RunConfig


def _run_file(tmp_path, config: dict):
    path = tmp_path / "0.json"
    path.write_text(json.dumps({"config": config, "episodes": [{"utility": 1.0}], "summary": {}}))
    return path


def test_a_run_file_from_before_a_setting_resumes_with_its_stored_default(tmp_path):
    cfg = RunConfig(episodes=1, seed=4)
    dump = jsonable(cfg.model_dump())
    assert read_run(_run_file(tmp_path, dump), cfg) is not None        # today's file: as it is
    dump.pop("move_target")                                              # made before the field
    assert read_run(_run_file(tmp_path, dump), cfg) is not None          # stored default "prior"
    with pytest.raises(ResumeError, match="move_target"):
        read_run(_run_file(tmp_path, dump), cfg.model_copy(update={"move_target": "belief"}))
    with pytest.raises(ResumeError, match="seed"):
        read_run(_run_file(tmp_path, dump), cfg.model_copy(update={"seed": 5}))
