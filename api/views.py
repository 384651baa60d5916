"""What the routes show: stored rows mapped to the API's views (tasks, sessions, curves,
beliefs with links), and the pictures made on request (the learning curve PNG, the prior).
"""
from __future__ import annotations

import io
import logging
import threading
from typing import Callable

from . import schemas as S

_log = logging.getLogger("tmoc.api")


def page(items: list, total: int, limit: int, offset: int, skipped: int = 0) -> dict:
    """A list endpoint's envelope; next_offset is None on the last page. `skipped`: rows of
    this page left out because their stored data is corrupt (``shown``)."""
    seen = len(items) + skipped
    nxt = offset + seen if offset + seen < total else None
    out = {"items": items, "total": total, "limit": limit, "offset": offset, "next_offset": nxt}
    if skipped:
        out["skipped"] = skipped
    return out


def shown(rows: list, view: Callable[[dict], dict], model: type) -> tuple[list[dict], int]:
    """Each row's view, validated as the list's item `model`; a row whose stored data is
    corrupt (None from the store, or a view that fails or does not validate) is left out
    and logged, so one bad row fails itself alone, not the whole list (issue 38)."""
    items, skipped = [], 0
    for row in rows:
        try:
            if row is None:
                raise ValueError("a stored column is not valid JSON")
            item = view(row)
            model.model_validate(item)          # a row that would fail the response: left out here
            items.append(item)
        except Exception as exc:  # noqa: BLE001 - one corrupt row must not fail the list
            skipped += 1
            _log.error("list: a stored row is corrupt and left out (%s: %s)", type(exc).__name__, exc)
    return items, skipped


def task_links(task_id: str) -> dict[str, str]:
    base = f"/v1/tasks/{task_id}"
    return {"self": base, "events": f"{base}/events", "episodes": f"{base}/episodes",
            "belief": f"{base}/belief", "curve": f"{base}/curve", "curve_png": f"{base}/curve.png",
            "frames": f"{base}/frames", "transition": f"{base}/transition", "export": f"{base}/export"}


def task_nodes(row: dict, live: list[dict] | None = None) -> list[dict] | None:
    """The Ray nodes that ran a task's particles: the result's when it succeeded, else what
    the worker reported at the running task's last episode boundary."""
    runtime = (row.get("result") or {}).get("runtime") or {}
    nodes = runtime.get("nodes", live)
    if nodes is None:
        return None
    # Results stored by earlier versions list bare node ids.
    return [n if isinstance(n, dict) else {"node_id": str(n), "hostname": "", "shards": 0,
                                           "particle_actions": 0} for n in nodes]


def task_view(row: dict, live_nodes: list[dict] | None = None) -> dict:
    return {
        "id": row["id"], "status": row["status"], "spec": row["spec"],
        "progress": {"episodes_done": row["episodes_done"], "episodes": row["episodes"]},
        "latest": row.get("latest"), "cancel_requested": bool(row["cancel_requested"]),
        "attempts": row["attempts"], "error": row.get("error"), "result": row.get("result"),
        "nodes": task_nodes(row, live_nodes),
        "created_at": S.ts(row["created_at"]), "started_at": S.ts(row.get("started_at")),
        "finished_at": S.ts(row.get("finished_at")), "links": task_links(row["id"]),
    }


def session_links(session_id: str) -> dict[str, str]:
    base = f"/v1/sessions/{session_id}"
    return {"self": base, "next": f"{base}/next", "observations": f"{base}/observations",
            "episodes": f"{base}/episodes", "belief": f"{base}/belief", "curve": f"{base}/curve",
            "export": f"{base}/export"}


def session_view(row: dict) -> dict:
    return {
        "id": row["id"], "status": row["status"], "spec": row["spec"],
        "episodes": row["spec"]["episodes"], "episodes_done": row["episodes_done"],
        "in_episode": bool(row["in_episode"]), "step": row["step"], "pending": row.get("pending"),
        "posterior": row.get("posterior"), "latest": row.get("latest"),
        "last_observation": _last_observation(row.get("last_reply")),
        "created_at": S.ts(row["created_at"]), "updated_at": S.ts(row["updated_at"]),
        "links": session_links(row["id"]),
    }


def _last_observation(last_reply: dict | None) -> dict | None:
    """The last accepted observation (as stored: configuration, state, measurements), the
    action and step it answered and whether that action succeeded."""
    if not last_reply:
        return None
    report = (last_reply.get("reply") or {}).get("report") or {}
    return {"step_id": last_reply.get("step_id"), "action": last_reply.get("action"),
            "success": report.get("success"), **(last_reply.get("observation") or {})}


def curve_points(records: list[dict]) -> list[dict]:
    """One point per stored episode record; `size_mean`/`size_std` are None where L has no
    size (the chute's friction, a plugin's properties: read `properties`)."""
    return [{"episode": r["episode"], "utility": r["utility"],
             "size_mean": r["posterior"].get("size_mean"), "size_std": r["posterior"].get("size_std"),
             "actions": r["actions"], "delivered": r["delivered"], "loads": r["loads"],
             "properties": r["posterior"].get("properties")}
            for r in records if "corrupt" not in r]       # a corrupt stored record: no point


_plot_lock = threading.Lock()


def render_png(spec: dict, records: list[dict]) -> bytes:
    from coordinator.loop.runner import plot_curve

    config = dict(spec)
    config.setdefault("true_size", float("nan"))
    buf = io.BytesIO()
    with _plot_lock:                     # pyplot keeps global state
        plot_curve({"config": config, "episodes": records}, buf)
    return buf.getvalue()


def prior(spec: dict) -> tuple[dict | None, dict]:
    """The belief a run starts from (exactly: the same seeded draw as the run)."""
    from coordinator.loop.session import Session

    s = Session(S.run_config(spec))
    return (s.belief.summary() if s.belief is not None else None), s.posterior()


def belief_view(run_id: str, spec: dict, belief: dict | None, posterior: dict, done: int,
                true_size: float | None) -> dict:
    """A run's belief as GET .../belief shows it (the particles only for agents that learn)."""
    from coordinator.agents import agent_spec

    learns = agent_spec(spec["agent"]).learn_belief
    return {"run_id": run_id, "agent": spec["agent"], "episodes_done": done,
            "learns_belief": learns, "posterior": posterior,
            "belief": belief if learns else None, "true_size": true_size}


__all__ = ["belief_view", "curve_points", "page", "prior", "render_png", "session_links",
           "session_view", "task_links", "task_nodes", "task_view"]
