"""Property-based API testing: schemathesis against the live server's /openapi.json.

Every route is exercised (all phases: examples, coverage, fuzzing, stateful) with all
checks: no 5xx, status codes, content types, headers and bodies as the schema documents,
schema-valid requests accepted and schema-invalid ones refused, 401 without the token.

Bounds and the one excluded check, and why:
- a dedicated server with tiny limits (particles <= 2, episodes 1, max_steps <= 2, 4 queued
  tasks, 4 sessions), because fuzzed task specs are real work: they are queued and run;
- `--max-examples 5` and a fixed seed keep the run short and reproducible;
- `--max-auth-failures` high: its auth checks send wrong tokens from its own address;
- `use_after_free` is excluded: it expects a DELETEd resource to be gone (404), but here
  DELETE means "cancel the task" / "close the session" (issue 5), and a cancelled task or a
  closed session stays readable on purpose (its status, episodes and curve are history).
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from .conftest import TOKEN, Server

# Slow: fuzzing a served API. Timeout: the server's start (90 s) and the schemathesis subprocess (400 s).
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def test_schemathesis_finds_no_server_errors_and_no_schema_violations(tmp_path):
    # Its auth checks send wrong tokens on purpose, from the address its own requests come
    # from: with the default 10 a minute that address would be throttled (issue 38) and
    # every later request a 429.
    srv = Server(tmp_path / "fuzz.sqlite", "--max-particles", "2", "--max-episodes", "1",
                 "--max-steps", "2", "--max-queued", "4", "--max-sessions", "4",
                 "--max-auth-failures", "1000000").start()
    try:
        cli = Path(sys.executable).with_name("schemathesis")
        cmd = [str(cli) if cli.exists() else "schemathesis", "run", f"{srv.base}/openapi.json",
               "-H", f"Authorization: Bearer {TOKEN}", "--checks", "all",
               "--exclude-checks", "use_after_free", "--max-examples", "5", "--seed", "1",
               "--request-timeout", "60", "--workers", "1", "--no-color"]
        env = dict(os.environ, SCHEMATHESIS_HOOKS="", NO_COLOR="1")
        out = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=400)
        report = out.stdout[-12000:] + out.stderr[-3000:]
        assert out.returncode == 0, report
        # every operation the server publishes was exercised (none filtered out)
        spec = httpx.get(f"{srv.base}/openapi.json", headers=srv.headers, timeout=10).json()
        n_ops = sum(1 for ops in spec["paths"].values() for m in ops if m in
                    ("get", "post", "put", "patch", "delete"))
        assert n_ops >= 21, sorted(spec["paths"])
        assert f"Selected: {n_ops}/{n_ops}" in out.stdout, report
    finally:
        srv.stop()
    assert "Traceback" not in srv.log(), srv.log()
