"""Scene pictures of a run (issue 16): the real world at the end of every episode, and after
every failed action the real outcome side by side with the outcomes a few particles
predicted (the heaviest, one that matched the real outcome, one that did not).

A :class:`FrameRecorder` is one of a session's observers (``coordinator.loop.observer``),
added by ``runner.run``; it
reads configurations and weights and never touches the run's state or generators, so a run
with pictures has exactly the episodes of a run without (tests/api/test_frames.py). Frames
go to a sink (``add(name, png, meta)``): a folder for ``tmoc run --frames``, the task store
for the service. Both keep at most ``max_frames`` (the oldest go first).
"""
from __future__ import annotations

import io
import json
import logging
import time
from pathlib import Path
from typing import Protocol

import numpy as np

from sim_workers.configuration import Configuration

from ..loop.observer import Prediction, RunObserver, StepEvent

log = logging.getLogger("tmoc.frames")

MAX_FRAMES = 48                 # per task: ~48 x (5-25 KB); the oldest are dropped first
MAX_FRAME_BYTES = 256 * 1024    # a frame larger than this is not kept (never seen: ~5-25 KB)


class FrameSink(Protocol):
    def add(self, name: str, png: bytes, meta: dict) -> None: ...



def pick_particles(weights: np.ndarray, matched: np.ndarray) -> list[tuple[str, int]]:
    """(label, index) of the particles to picture: the heaviest, then the heaviest other one
    that matched and the heaviest other one that did not (when there are such). Ties go
    to the lower index, so the choice is deterministic and draws nothing."""
    order = np.lexsort((np.arange(len(weights)), -np.asarray(weights)))
    if len(order) == 0:
        return []
    top = int(order[0])
    picks = [("heaviest", top)]
    for label, want in (("matched", True), ("did not match", False)):
        rest = [int(i) for i in order if int(i) != top and bool(matched[i]) == want]
        if rest:
            picks.append((label, rest[0]))
    return picks


def frame_name(episode: int, step: int | None) -> str:
    """e003-end (episode 3's last configuration) or e003-s007 (its 8th action failed)."""
    return f"e{episode:03d}-end" if step is None else f"e{episode:03d}-s{step:03d}"


def strip_png(panels: list[np.ndarray], titles: list[str], colours: list[str]) -> bytes:
    """One PNG: the panels side by side, each under its title (matplotlib's Agg canvas, not
    pyplot: no global state, safe on any thread)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    h, w = panels[0].shape[:2]
    dpi = 100
    fig = Figure(figsize=(w * len(panels) / dpi, (h + 34) / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    for k, (img, title, colour) in enumerate(zip(panels, titles, colours)):
        ax = fig.add_axes((k / len(panels), 0.0, 1.0 / len(panels), h / (h + 34)))
        ax.imshow(img, interpolation="nearest")
        ax.set_axis_off()
        fig.text((k + 0.5) / len(panels), 1.0 - 3 / (h + 34), title, ha="center", va="top",
                 fontsize=7.5, color=colour, wrap=True)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


class FrameRecorder(RunObserver):
    """Renders a run's frames into a sink: an observer of the run (``session.watch``)."""

    wants_predictions = True        # a failed action's picture shows what particles predicted

    def __init__(self, domain: str, options: dict, truth: dict | None, sink: FrameSink) -> None:
        self.domain_name, self.options = domain, dict(options)
        self.truth = truth
        self.sink = sink
        self._renderer = None               # built on first use, in this process, closed by close()
        self._home: Configuration | None = None   # the scene's start: every camera frames it too
        self.render_ms: list[float] = []    # per rendered panel (for the figure in docs/SERVICE.md)

    # -- plumbing -------------------------------------------------------------------------
    def _r(self):
        if self._renderer is None:
            from sim_workers.domains import load
            from sim_workers.render import SceneRenderer

            self._renderer = SceneRenderer(load(self.domain_name, **self.options))
        return self._renderer

    def _camera(self, configs: list[Configuration], props: dict):
        """A camera over the scene's start and `configs`: frames of one task look alike."""
        from sim_workers.render import camera_for

        if self._home is None:
            self._home = self._r().domain.initial_configuration(props)
        return camera_for([self._home, *configs])

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def _render(self, config: Configuration, props: dict, camera) -> np.ndarray:
        t0 = time.perf_counter()
        img = self._r().render(config, props, camera)
        self.render_ms.append((time.perf_counter() - t0) * 1000.0)
        return img

    def _emit(self, name: str, png: bytes, meta: dict) -> None:
        if len(png) > MAX_FRAME_BYTES:
            log.warning("frame %s: %d bytes, over %d; not kept", name, len(png), MAX_FRAME_BYTES)
            return
        self.sink.add(name, png, {**meta, "name": name, "bytes": len(png)})

    def _truth_props(self, fallback: dict) -> dict:
        return self.truth if self.truth is not None else fallback

    # -- events (from the session; a failure here never fails the run) ---------------------
    def on_step(self, session, event: StepEvent) -> None:
        if not event.success:
            self.failed_action(event.episode, event.step, event.action, event.expected,
                               event.observation.configuration, event.observation.state,
                               session.believed_props(), event.prediction, session.props_of)

    def on_episode(self, session, record: dict) -> None:
        self.episode_end(record, session.observation.configuration, session.believed_props())

    def episode_end(self, record: dict, config: Configuration, believed: dict) -> None:
        try:
            props = self._truth_props(believed)
            img = self._render(config, props, self._camera([config], props))
            ep = int(record["episode"])
            title = (f"episode {ep} end: utility {record['utility']:.0f}, delivered "
                     f"{record['delivered']}, loads {record['loads']}")
            self._emit(frame_name(ep, None), strip_png([img], [title], ["black"]),
                       {"kind": "episode_end", "episode": ep, "step": None, "action": None,
                        "panels": [{"label": "real", "title": title}]})
        except Exception:  # noqa: BLE001 - pictures are a view; the run goes on
            log.exception("frame of episode %s's end not rendered", record.get("episode"))

    def failed_action(self, episode: int, step: int, action: str, expected: frozenset,
                      real: Configuration, real_state: frozenset, believed: dict,
                      prediction: Prediction | None, props_of) -> None:
        """The real outcome of a failed action and, with a belief, the particles' predictions
        (`props_of(row)` turns a row of L into the domain's properties)."""
        try:
            self._failed(episode, step, action, expected, real, real_state, believed, prediction, props_of)
        except Exception:  # noqa: BLE001
            log.exception("frame of episode %d step %d not rendered", episode, step)

    def _failed(self, episode, step, action, expected, real, real_state, believed, prediction, props_of):
        picks = pick_particles(prediction.weights, prediction.matched) if prediction is not None else []
        configs = [real] + [Configuration.from_array(prediction.configurations[i]) for _, i in picks]
        camera = self._camera(configs, self._truth_props(believed))
        missing = sorted(expected - real_state)
        panels = [self._render(real, self._truth_props(believed), camera)]
        titles = [f"real: {action} failed\n(expected {', '.join(missing[:2]) or 'another state'})"]
        colours = ["black"]
        meta_panels = [{"label": "real", "title": titles[0], "success": False}]
        for (label, i), config in zip(picks, configs[1:]):
            row = np.asarray(prediction.rows[i], dtype=np.float64)
            predicted_ok = prediction.states[i] == expected
            size_mm = float(row[0]) * 1000.0
            ok = bool(prediction.matched[i])
            title = (f"{label}: particle {i}, w {prediction.weights[i]:.3f}\n"
                     f"size {size_mm:.1f} mm, {'succeeds' if predicted_ok else 'fails'} "
                     f"({'matches' if ok else 'does not match'})")
            panels.append(self._render(config, props_of(row), camera))
            titles.append(title)
            colours.append("#1a7f37" if ok else "#b3261e")
            meta_panels.append({"label": label, "particle": int(i), "weight": float(prediction.weights[i]),
                                "size_mm": size_mm, "matched": ok, "success": bool(predicted_ok),
                                "title": title})
        self._emit(frame_name(episode, step), strip_png(panels, titles, colours),
                   {"kind": "failed_action", "episode": int(episode), "step": int(step),
                    "action": action, "panels": meta_panels})


class DirectorySink:
    """Frames as PNG files in a folder, with ``index.json`` (their metadata, oldest first);
    at most `max_frames` (the oldest are deleted)."""

    def __init__(self, folder: Path, max_frames: int = MAX_FRAMES) -> None:
        self.folder = Path(folder)
        self.max_frames = max_frames
        self.index: list[dict] = []
        self.folder.mkdir(parents=True, exist_ok=True)

    def add(self, name: str, png: bytes, meta: dict) -> None:
        (self.folder / f"{name}.png").write_bytes(png)
        self.index = [m for m in self.index if m["name"] != name] + [meta]
        while len(self.index) > self.max_frames:
            old = self.index.pop(0)
            (self.folder / f"{old['name']}.png").unlink(missing_ok=True)
        (self.folder / "index.json").write_text(json.dumps(self.index, indent=1))
