"""Scene pictures (issue 16 item 2): stored with the task (at most --max-frames, the newest
kept), served as PNG, and they change nothing in a run's results; `tmoc run --frames`
writes them next to result.json. T per context over HTTP."""
from __future__ import annotations

import io
import json
import subprocess

import numpy as np
import pytest

from .conftest import Server, tmoc, wait_for

# Slow: real tasks on a served Ray. Timeout: a served task's wait and the `tmoc run --frames` subprocess may take 600 s.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(720)]

# Six blocks of 45 mm: episode 1 fails a push and two stacks (the failed action's picture),
# in 29 s a run rather than 40 s with eight (measured with `tmoc run`).
SPEC = {"particles": 4, "episodes": 2, "n_blocks": 6, "seed": 1, "max_steps": 40}


def _png_size(png: bytes) -> tuple[int, int]:
    import matplotlib.image as mpimg

    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    h, w = mpimg.imread(io.BytesIO(png), format="png").shape[:2]
    return w, h


def _without_timings(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not k.endswith("_s")} for r in records]


def test_frames_are_bounded_served_as_png_and_change_no_result(tmp_path):
    srv = Server(tmp_path / "frames.sqlite", "--max-frames", "2", "--max-particles", "8").start()
    try:
        with srv.client(timeout=60) as c:
            with_frames = c.post("/v1/tasks", json=SPEC).json()["id"]
            without = c.post("/v1/tasks", json={**SPEC, "frames": False}).json()["id"]
            # before the first episode: T at its optimistic prior
            prior = c.get(f"/v1/tasks/{with_frames}/transition").json()
            assert prior["episodes_done"] == 0 and {r["p"] for r in prior["rows"]} == {1.0}
            for t in (with_frames, without):
                wait_for(lambda: c.get(f"/v1/tasks/{t}").json()["status"] == "succeeded", 600, what=t)  # noqa: B023
            listed = c.get(f"/v1/tasks/{with_frames}/frames").json()
            assert listed["max_frames"] == 2 and listed["total"] == 2          # the bound holds
            names = [f["name"] for f in listed["items"]]
            assert names[-1] == "e001-end", names                               # the newest kept
            assert c.get(f"/v1/tasks/{without}/frames").json()["total"] == 0
            for f in listed["items"]:
                png = c.get(f["url"])
                assert png.status_code == 200 and png.headers["content-type"] == "image/png"
                assert len(png.content) == f["bytes"] < 256 * 1024
                w, h = _png_size(png.content)
                assert w == 320 * len(f["panels"]) and 240 < h <= 300
            assert c.get(f"/v1/tasks/{with_frames}/frames/e009-end.png").status_code == 404
            bad = c.get(f"/v1/tasks/{with_frames}/frames/..%2Fsecret.png")
            assert bad.status_code in (404, 422)
            assert c.get(f"/v1/tasks/{with_frames}/frames/x.png").status_code == 422
            assert c.get("/v1/tasks/t_nope/frames").status_code == 404
            # pictures change nothing: the same seed gives the same episodes with and without
            a = c.get(f"/v1/tasks/{with_frames}/episodes").json()
            b = c.get(f"/v1/tasks/{without}/episodes").json()
            assert _without_timings(a) == _without_timings(b)
            assert a[0]["failures"], a[0]       # the case with a failed action's picture
            # T per context after the run: the counts the planner's T comes from, for a
            # context the robot failed in (which one depends on the planner's choices)
            trans = c.get(f"/v1/tasks/{with_frames}/transition").json()
            failed = [r for r in trans["rows"] if r["real_trials"] >= 1 and r["p"] < 1.0]
            assert failed, trans["rows"]
            for row in failed:
                assert abs(row["p"] - (row["successes"] + 1) / (row["trials"] + 1)) < 1e-9, row
    finally:
        srv.stop()
    assert "Traceback" not in srv.log(), srv.log()


def test_tmoc_run_frames_writes_pictures_next_to_the_result(tmp_path):
    config = tmp_path / "run.json"
    config.write_text(json.dumps({"n_blocks": 6, "particles": 4, "episodes": 1, "seed": 1,
                                  "counterfactual_rows": 0}))   # as SPEC on the test server
    out = tmp_path / "out"
    proc = subprocess.run([*tmoc(), "run", "--config", str(config), "--frames", "--no-progress",
                           "--out", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads((out / "result.json").read_text())
    index = json.loads((out / "frames" / "index.json").read_text())
    names = [m["name"] for m in index]
    assert "e000-end" in names
    failed = [m for m in index if m["kind"] == "failed_action"]
    assert len(failed) == sum(result["episodes"][0]["failures"].values()) >= 1
    strip = failed[0]
    assert strip["panels"][0]["label"] == "real" and strip["panels"][1]["label"] == "heaviest"
    weights = [p["weight"] for p in strip["panels"][1:]]
    assert weights[0] == max(weights)           # the heaviest particle comes first
    for m in index:
        png = (out / "frames" / f"{m['name']}.png").read_bytes()
        assert len(png) == m["bytes"] and _png_size(png)[0] == 320 * len(m["panels"])
    assert sorted(p.name for p in (out / "frames").glob("*.png")) == sorted(f"{n}.png" for n in names)
    assert np.isfinite(result["summary"]["final_size_mean"])
