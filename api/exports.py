"""``GET /v1/tasks/{id}/export`` and ``GET /v1/sessions/{id}/export``: a task's or a robot
session's steps as MCAP (``coordinator.export``), built from the stored step records."""
from __future__ import annotations

import json
import tempfile
from typing import IO, Iterator

from coordinator.export import write_mcap

from .store import Store

MEDIA_TYPE = "application/octet-stream"
SPOOL_BYTES = 8 << 20           # past this the file being built goes to disk, not memory
CHUNK = 1 << 16


def mcap_file(store: Store, run_id: str, kind: str, spec: dict) -> IO[bytes]:
    """The MCAP of `run_id` (`kind`: task or session) in a spooled temporary file, at 0."""
    f = tempfile.SpooledTemporaryFile(max_size=SPOOL_BYTES)
    episodes = (json.loads(r) for _, r in store.episodes(run_id))
    write_mcap(f, store.steps(run_id), episodes,
               {"source": kind, "id": run_id, "domain": str(spec.get("domain", "")), "config": spec})
    f.seek(0)
    return f


def chunks(f: IO[bytes]) -> Iterator[bytes]:
    try:
        while block := f.read(CHUNK):
            yield block
    finally:
        f.close()


def download(name: str) -> dict:
    return {"Content-Disposition": f'attachment; filename="{name}.mcap"'}


RESPONSES = {200: {"content": {MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
                   "description": "the steps as MCAP: /tmoc/step, /tmoc/trajectory, /tmoc/episode"}}
