"""Where a task's scene pictures go: :class:`StoreFrameSink` writes a run's frames into the
store, at most ``--max-frames`` per task (the oldest deleted first). The routes that read
them are api.routes.frames.
"""
from __future__ import annotations

from .store import Store


class StoreFrameSink:
    """A run's frames into the store, bounded per task."""

    def __init__(self, store: Store, task_id: str, max_frames: int) -> None:
        self.store, self.task_id, self.max_frames = store, task_id, max_frames

    def add(self, name: str, png: bytes, meta: dict) -> None:
        self.store.add_frame(self.task_id, name, png, meta, self.max_frames)


__all__ = ["StoreFrameSink"]
