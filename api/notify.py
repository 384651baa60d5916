"""Wake-ups for the event streams: a task's worker stores something, its streams read it."""
from __future__ import annotations

import asyncio


class Notifier:
    """Thread-safe wake-ups for the event streams (asyncio events on the server's loop)."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self._subs: dict[str, set[asyncio.Event]] = {}

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop

    def subscribe(self, key: str) -> asyncio.Event:
        ev = asyncio.Event()
        self._subs.setdefault(key, set()).add(ev)
        return ev

    def count(self, key: str | None = None) -> int:
        """Open subscriptions of `key` (None: of every key)."""
        if key is None:
            return sum(len(subs) for subs in self._subs.values())
        return len(self._subs.get(key, ()))

    def unsubscribe(self, key: str, ev: asyncio.Event) -> None:
        subs = self._subs.get(key)
        if subs is not None:
            subs.discard(ev)
            if not subs:
                self._subs.pop(key, None)

    def _wake(self, key: str) -> None:
        for ev in list(self._subs.get(key, ())):
            ev.set()

    def notify(self, key: str) -> None:
        loop = self.loop
        if loop is None or loop.is_closed():
            return
        try:
            loop.call_soon_threadsafe(self._wake, key)
        except RuntimeError:  # loop closed meanwhile
            pass


__all__ = ["Notifier"]
