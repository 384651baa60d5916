"""``GET /v1/tasks/{id}/export`` and ``GET /v1/sessions/{id}/export``: a task's or a robot
session's steps as MCAP (``coordinator.integrations.export``), built from the stored step records.

Streamed and bounded (issue 38: 42 concurrent exports stalled the service, a client that
did not read held an 8 MiB spool, and nothing was sent until a whole MCAP was built):

- an export is written to a file on disk beside the database (``<db>.exports/``) by a
  thread of its own, and the response streams that file as it grows: the first bytes go
  out at once;
- a finished export is kept per run and stored step count, so a retry (or anyone else)
  streams the file instead of building it again; requests for an export being built follow
  that one build;
- at most ``MAX_BUILDS`` exports are built at a time (then 429 with ``Retry-After``), and
  building never takes a thread of the request pool;
- a response holds one ``CHUNK`` (64 KiB) at a time, and a client that reads nothing for
  ``SEND_TIMEOUT_S`` is dropped.
"""
from __future__ import annotations

import asyncio
import json
import logging
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import AsyncIterator, BinaryIO

from starlette.concurrency import run_in_threadpool
from starlette.responses import StreamingResponse

from coordinator.integrations.export import write_mcap

from .store import Store

MEDIA_TYPE = "application/octet-stream"
CHUNK = 1 << 16
MAX_BUILDS = 2               # exports built at once; each is one core of JSON and zlib
SEND_TIMEOUT_S = 30.0        # a client that takes no bytes for this long is dropped
POLL_S = 0.02                # how often a response looks for more of a file being built

_log = logging.getLogger("tmoc.api")


class ExportBusy(Exception):
    """`MAX_BUILDS` exports are being built: retry later."""


@dataclass
class _Build:
    path: Path
    partial: Path
    done: threading.Event = field(default_factory=threading.Event)
    error: str | None = None


@dataclass
class Source:
    """An export to stream: an open file, and the build still writing it (None: finished)."""

    file: BinaryIO
    build: _Build | None


class Exports:
    """The service's exports on disk, and the builds under way."""

    def __init__(self, folder: str | Path, max_builds: int = MAX_BUILDS) -> None:
        self.folder = Path(folder)
        self.max_builds = max_builds
        self._lock = threading.Lock()
        self._building: dict[Path, _Build] = {}

    @classmethod
    def beside(cls, db: str | Path) -> "Exports":
        db = Path(db)
        return cls(db.parent / f"{db.name}.exports")

    def open(self, store: Store, run_id: str, kind: str, spec: dict) -> Source:
        """The export of `run_id` as it is stored now: the finished file, the one being
        built, or a new build (ExportBusy past `max_builds`). Blocking: call in a thread."""
        steps, episodes = store.export_counts(run_id)
        path = self.folder / f"{run_id}-{steps}-{episodes}.mcap"
        with self._lock:
            if path.exists():
                return Source(open(path, "rb"), None)
            build = self._building.get(path)
            if build is not None:
                try:
                    return Source(open(build.partial, "rb"), build)
                except FileNotFoundError:       # it finished (renamed) or failed just now
                    if path.exists():
                        return Source(open(path, "rb"), None)
                    raise ExportBusy("the export being built failed") from None
            if len(self._building) >= self.max_builds:
                raise ExportBusy(f"{len(self._building)} exports are being built")
            self.folder.mkdir(parents=True, exist_ok=True)
            build = _Build(path, path.with_suffix(f".partial-{os.getpid()}"))
            build.partial.write_bytes(b"")
            reader = open(build.partial, "rb")   # before the build can rename it
            self._building[path] = build
            threading.Thread(target=self._build, args=(build, store, run_id, kind, spec),
                             name=f"tmoc-export-{run_id}", daemon=True).start()
            return Source(reader, build)

    def _build(self, build: _Build, store: Store, run_id: str, kind: str, spec: dict) -> None:
        try:
            episodes = (json.loads(r) for _, r in store.episodes(run_id))
            # Unbuffered: each MCAP record reaches the file (and the readers) as written.
            with open(build.partial, "wb", buffering=0) as f:
                write_mcap(f, store.steps(run_id), episodes,
                           {"source": kind, "id": run_id, "domain": str(spec.get("domain", "")), "config": spec})
            os.replace(build.partial, build.path)        # readers keep their open file
            for old in self.folder.glob(f"{run_id}-*.mcap"):
                if old != build.path:
                    old.unlink(missing_ok=True)          # one finished export per run
        except Exception as exc:  # noqa: BLE001 - the readers end with an error, the server goes on
            build.error = f"{type(exc).__name__}: {exc}"
            _log.error("export of %s failed: %s", run_id, build.error)
            build.partial.unlink(missing_ok=True)
        finally:
            with self._lock:
                self._building.pop(build.path, None)
            build.done.set()

    def forget(self, run_id: str) -> None:
        """Delete a run's finished exports (its rows were purged)."""
        for old in self.folder.glob(f"{run_id}-*.mcap") if self.folder.exists() else ():
            old.unlink(missing_ok=True)

    def building(self) -> int:
        with self._lock:
            return len(self._building)


async def stream(source: Source) -> AsyncIterator[bytes]:
    """The file's bytes, CHUNK at a time, following a build until it is done."""
    f, build = source.file, source.build
    try:
        while True:
            block = await run_in_threadpool(f.read, CHUNK)
            if block:
                yield block
                continue
            if build is None:
                return
            if build.done.is_set():
                rest = await run_in_threadpool(f.read)          # written before `done`
                if rest:
                    yield rest
                if build.error is not None:
                    # Past the 200 the only way to say so: break the transfer, so the client
                    # sees an incomplete download, never a short file that looks whole.
                    raise RuntimeError(f"export failed: {build.error}")
                return
            await asyncio.sleep(POLL_S)
    finally:
        f.close()


class BoundedStream(StreamingResponse):
    """A StreamingResponse whose every send must be taken within `SEND_TIMEOUT_S`: a client
    that stops reading is dropped instead of holding its response (and file) open."""

    send_timeout_s = SEND_TIMEOUT_S

    async def stream_response(self, send) -> None:
        await send({"type": "http.response.start", "status": self.status_code, "headers": self.raw_headers})
        async for chunk in self.body_iterator:
            if not isinstance(chunk, (bytes, memoryview)):
                chunk = chunk.encode(self.charset)
            await asyncio.wait_for(send({"type": "http.response.body", "body": chunk, "more_body": True}),
                                   self.send_timeout_s)
        await send({"type": "http.response.body", "body": b"", "more_body": False})


async def serve(exports: Exports, store: Store, run_id: str, kind: str, spec: dict) -> BoundedStream:
    """The export route's response (429 with Retry-After while `max_builds` are built)."""
    from fastapi import HTTPException

    try:
        source = await run_in_threadpool(exports.open, store, run_id, kind, spec)
    except ExportBusy as exc:
        raise HTTPException(429, f"export: {exc}, at most {exports.max_builds} at a time: retry later",
                            headers={"Retry-After": "5"}) from None
    return BoundedStream(stream(source), media_type=MEDIA_TYPE, headers=download(run_id))


async def purged(purge, exports: Exports, kind: str, run_id: str, first: str) -> dict:
    """A purge route's reply: `purge(run_id)` (a store or manager method) run in a thread,
    404 for an unknown run, 409 naming what to do `first` while it is not finished, and
    the run's kept exports deleted with its rows."""
    from fastapi import HTTPException

    outcome = await run_in_threadpool(purge, run_id)
    if outcome is None:
        raise HTTPException(404, f"{kind} {run_id!r}: no such {kind}")
    status, rows = outcome
    if not rows:
        raise HTTPException(409, f"{kind} {run_id!r} is {status}: {first} it, then purge it")
    await run_in_threadpool(exports.forget, run_id)
    return {"id": run_id, "status": status, "purged": rows}


def download(name: str) -> dict:
    return {"Content-Disposition": f'attachment; filename="{name}.mcap"'}


RESPONSES = {200: {"content": {MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
                   "description": "the steps as MCAP: /tmoc/step, /tmoc/trajectory, /tmoc/episode"},
             429: {"description": "too many exports are being built: retry after Retry-After seconds"}}
