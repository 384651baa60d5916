"""What `tmoc serve` configures (:class:`Settings`), held in ``app.state.settings``."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Settings:
    """What `tmoc serve` configures; `token` comes from TMOC_API_TOKEN."""

    db: str = "tmoc.sqlite"
    ray_address: str | None = None
    token: str | None = None
    max_particles: int = 512
    max_episodes: int = 1000
    max_steps: int = 1000
    max_queued: int = 64
    max_sessions: int = 16
    max_body_bytes: int = 4 * 1024 * 1024
    n_shards: int | None = None
    shutdown_grace_s: float = 5.0
    max_frames: int = 48          # scene pictures kept per task (0: none rendered)


__all__ = ["Settings"]
