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
    # Counterfactual rows a task or session may ask for (its snapshot simulates rows x the
    # domain's contexts before each plan); one that names none gets min(4, this), 0: the
    # paper's loop on this server.
    max_counterfactual_rows: int = 32
    max_queued: int = 64
    max_sessions: int = 16
    # A session nothing was stored for this long no longer counts against max_sessions,
    # and leaves memory (it is rebuilt from the store when its robot comes back): an
    # abandoned session, or one whose create reply was lost, no longer holds a slot forever.
    session_idle_s: float = 3600.0
    max_body_bytes: int = 4 * 1024 * 1024
    n_shards: int | None = None
    shutdown_grace_s: float = 5.0
    max_frames: int = 48          # scene pictures kept per task (0: none rendered)
    # A task's running time at most (its `max_runtime_s`, and the default of one that
    # leaves it out): past it the task stops within one action and fails, its finished
    # episodes kept. Bounds what one request may cost (issue 25: an episode at the
    # accepted maxima takes hours).
    max_task_runtime_s: float = 3600.0
    # Host header names the server answers to (None: any). `tmoc serve` without a token
    # sets the loopback names, its --host and --allowed-host: a DNS-rebinding page that
    # reaches 127.0.0.1 under its own name gets a 400, not the API.
    allowed_hosts: tuple[str, ...] | None = None
    # Open event streams, per task and in all (then 429): each holds a descriptor.
    max_streams_per_task: int = 16
    max_streams: int = 256
    # Finished tasks and closed or finished sessions last changed longer ago than this are
    # purged at start-up and hourly (None: kept for ever).
    retain_days: float | None = None
    # episodes x max_steps a task or session may ask for at most: the step records it can
    # store (~1.4 KB a step; 100000 steps ~140 MB).
    max_stored_steps: int = 100_000
    # Failed sign-ins (wrong tokens, at /ui/login or as a bearer) an address may make in a
    # minute before it is refused (429) until they age out; 10x that over all addresses.
    max_auth_failures: int = 10


__all__ = ["Settings"]
