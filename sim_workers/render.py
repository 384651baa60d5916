"""Pictures of a scene configuration: pybullet's TinyRenderer (CPU only, no GPU, no window).

A :class:`SceneRenderer` owns one DIRECT client of its own, built in the process that
renders (a client id does not survive pickling), and rebuilds the scene for each picture
under the properties given (a particle's hypothesis, or the truth). Rendering reads a
configuration; it never steps physics, so a picture changes nothing of a run. Whatever
engine a run simulates in, its pictures are pybullet's (MuJoCo's renderer needs an OpenGL
context, which a headless server lacks); without pybullet a run has no pictures.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from .configuration import Configuration
from .domains import Domain
from .engines.pybullet_world import PybulletWorld

WIDTH, HEIGHT = 320, 240        # one panel; a PNG of it is ~2-10 KB (flat colours compress well)
FOV_DEG = 45.0
PITCH_DEG = -45.0
MARGIN_M = 0.12                 # room around the objects' positions

BLOCK_RGBA = (0.90, 0.55, 0.15, 1.0)
OTHER_OBJECT_RGBA = (0.25, 0.45, 0.80, 1.0)   # the container (objects not named b<i>)
GRIPPER_RGBA = (0.25, 0.25, 0.25, 1.0)
SCENERY_RGBA = (0.86, 0.86, 0.83, 1.0)        # table, rails


@dataclass(frozen=True)
class Camera:
    """Where the camera looks (yaw 0: image x is world x) and from how far."""

    target: tuple[float, float, float]
    distance: float


def camera_for(configs: list[Configuration]) -> Camera:
    """One camera that frames the objects of every configuration given (so the panels of
    one picture are comparable side by side)."""
    xyz = np.concatenate([np.asarray(c.objects)[:, :3] for c in configs])
    lo, hi = xyz.min(axis=0) - MARGIN_M, xyz.max(axis=0) + MARGIN_M
    centre = (lo + hi) / 2.0
    half_w = max((hi[0] - lo[0]) / 2.0, (hi[1] - lo[1]) / 2.0, 0.2)
    tan_h = np.tan(np.radians(FOV_DEG / 2.0)) * WIDTH / HEIGHT
    return Camera((float(centre[0]), float(centre[1]), 0.0), float(half_w / tan_h + 0.05))


def _is_block(name: str) -> bool:
    return name.startswith("b") and name[1:].isdigit()


class SceneRenderer:
    """Renders configurations of one domain's scene (one pybullet client, this process)."""

    def __init__(self, domain: Domain) -> None:
        self.domain = domain
        self.world = PybulletWorld(domain)

    def close(self) -> None:
        self.world.close()

    def _colour(self) -> None:
        c, h = self.world.client, self.world.handles
        names = list(self.domain.object_names)
        rgba = {}
        for body in range(pb.getNumBodies(physicsClientId=c)):
            rgba[pb.getBodyUniqueId(body, physicsClientId=c)] = SCENERY_RGBA
        for name, body in zip(names, h.objects):
            rgba[body] = BLOCK_RGBA if _is_block(name) else OTHER_OBJECT_RGBA
        rgba[h.gripper] = GRIPPER_RGBA
        for body, colour in rgba.items():
            for link in range(-1, pb.getNumJoints(body, physicsClientId=c)):
                pb.changeVisualShape(body, link, rgbaColor=colour, physicsClientId=c)

    def render(self, config: Configuration, props: dict, camera: Camera) -> np.ndarray:
        """(HEIGHT, WIDTH, 3) uint8 RGB of `config` under `props` (placed as given)."""
        self.world.reset(config, props, place=False)
        self._colour()
        c = self.world.client
        view = pb.computeViewMatrixFromYawPitchRoll(list(camera.target), camera.distance, 0.0,
                                                    PITCH_DEG, 0.0, 2, physicsClientId=c)
        proj = pb.computeProjectionMatrixFOV(FOV_DEG, WIDTH / HEIGHT, 0.02, 10.0, physicsClientId=c)
        _, _, rgba, _, _ = pb.getCameraImage(WIDTH, HEIGHT, view, proj, shadow=1,
                                             lightDirection=[0.5, -0.8, 1.5],
                                             renderer=pb.ER_TINY_RENDERER, physicsClientId=c)
        return np.reshape(np.asarray(rgba, dtype=np.uint8), (HEIGHT, WIDTH, 4))[:, :, :3].copy()
