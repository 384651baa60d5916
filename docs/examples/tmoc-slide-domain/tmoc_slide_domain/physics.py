"""Slide's physics half: a row of pucks of unknown friction, each pushed and let go.

Written against the public kit only (``sim_workers.base``, ``scene``, ``configuration``,
``obstacles``, ``trajectory``, ``properties``). The closed fingers, touching the puck's
back, push pJ along +x at a speed v and stop hard: the puck leaves them at v and slides
v^2 / (2 mu g) on its own. The speed comes from the distance D left to the goal line
alone: v^2 = 2 g mu_low f D, so even the most slippery puck the prior allows (mu_low)
slides only the share f (``slide_share``) of D. Y, the key pose, is where the fingers
start to brake: the puck, at the believed friction, then comes to rest on the goal line. A
belief above the truth lets go too late and the puck slides past the line (lost), one
below too early (it waits, to be pushed again from where it stopped). A camera reads every
puck's x (``position_sigma``): the slide it measures is what the belief learns from.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

import numpy as np

from sim_workers import trajectory as tr
from sim_workers.base import PhysicsDomain
from sim_workers.configuration import Configuration, quat_from_yaw
from sim_workers.obstacles import Box, body_box, hand_boxes
from sim_workers.properties import PropertySpace, per_object_property
from sim_workers.scene import Body, BoxShape, Gripper, SceneDescription

_PUSH = re.compile(r"^push\((p\d+)\)$")
G = 9.81
# The engines multiply two bodies' coefficients, so with the table at 1 a puck's friction
# (L) is the pair's. Not a spec field named mu_*: the reality gap jitters those, and a
# jittered table would move every puck's effective friction, L itself, each episode.
TABLE_FRICTION = 1.0
FRICTION_BOUNDS = (0.02, 2.0)               # what a hypothesis may say at all


@dataclass(frozen=True)
class SlideSpec:
    """Everything fixed about the scene; the pucks' friction is L, not here."""

    n_blocks: int = 4                  # pucks (the spec field the service sets the count by)
    true_friction: float = 0.3
    friction_low: float = 0.15
    friction_high: float = 0.6
    puck_half: tuple = (0.02, 0.02, 0.01)
    puck_mass: float = 0.1             # kg
    start_x: float = 0.0
    pitch: float = 0.1                 # between two pucks' rows, along y
    goal_x: float = 0.30               # a puck within goal_tol of this line is placed
    goal_tol: float = 0.015
    slide_share: float = 0.8           # the most slippery puck slides at most this share of the way
    push_accel: float = 40.0           # m/s^2, up to speed and braking: far harder than friction (mu g)
    position_sigma: float = 0.002      # m, the camera
    mu_finger: float = 0.5
    clearance: float = 0.006           # fingers behind the puck: 3 x the 2 mm perception sigma, so they come down clear of it
    tool_z: float = 0.01               # the push at the puck's mid-height: no torque to tip it
    carry_height: float = 0.12
    move_speed: float = 0.4
    approach_speed: float = 0.2
    base_max_force: float = 60.0
    grip_force: float = 5.0
    settle_s: float = 1.0              # long enough for the slowest slide to end
    time_step: float = 0.002           # at 1/240 s pybullet's contact lets go ~2 cm short of the model
    solver_iterations: int = 50

    PALM_HALF = (0.006, 0.02, 0.01)
    FINGER_HALF = (0.005, 0.005, 0.03)

    @property
    def names(self) -> list[str]:
        return [f"p{i + 1}" for i in range(self.n_blocks)]

    def row_y(self, i: int) -> float:
        return (i - (self.n_blocks - 1) / 2) * self.pitch

    def speed(self, distance: float) -> float:
        """The push's speed for a puck `distance` short of the line (geometry alone)."""
        return float(np.sqrt(2 * G * self.friction_low * self.slide_share * max(distance, 0.0)))

    def release(self, distance: float, mu: float) -> float:
        """How far the puck travels with the fingers for it to move `distance` in all at
        friction `mu`: the rest it slides, v^2 / (2 mu g)."""
        v = self.speed(distance)
        return distance - v * v / (2 * mu * G)


class SlidePhysics(PhysicsDomain):
    """Pucks pushed and let go to slide onto a line; L = each puck's friction."""

    name = "slide"
    max_objects = 8

    def __init__(self, spec: SlideSpec | None = None, **overrides) -> None:
        spec = dataclasses.replace(spec or SlideSpec(), **overrides)
        if not 1 <= spec.n_blocks <= self.max_objects:
            raise ValueError(f"n_blocks: {spec.n_blocks} is outside [1, {self.max_objects}]")
        if not FRICTION_BOUNDS[0] <= spec.friction_low < spec.friction_high <= FRICTION_BOUNDS[1]:
            raise ValueError(f"friction_low, friction_high: need {FRICTION_BOUNDS[0]} <= low < high <= "
                             f"{FRICTION_BOUNDS[1]}")
        self.spec = spec

    # -- the objects and L --------------------------------------------------------------
    @property
    def object_names(self) -> list[str]:
        return self.spec.names

    @property
    def L(self) -> PropertySpace:
        sp = self.spec
        return PropertySpace(("friction",), ("1",), (sp.friction_low,), (sp.friction_high,), (sp.true_friction,))

    def true_properties(self, sizes_variation: bool = False) -> dict:
        return {"friction": np.full(self.n_objects, self.spec.true_friction)}

    def properties(self, props: dict) -> dict:
        """{"friction": (n,)}: one coefficient for every puck or one each, within bounds."""
        return {"friction": per_object_property(props, "friction", self.n_objects, *FRICTION_BOUNDS)}

    def props_from_row(self, row: np.ndarray) -> dict:
        return {"friction": self.L.split(row, self.n_objects)["friction"]}

    def object_sizes(self, props: dict) -> np.ndarray:
        return np.full(self.n_objects, 2 * self.spec.puck_half[0])

    # -- the scene ------------------------------------------------------------------------
    def scene_description(self, props: dict) -> SceneDescription:
        sp = self.spec
        mu = self.properties(props)["friction"]
        table = Body("table", (BoxShape((1.0, 1.0, 0.05)),), 0, (0.2, 0.0, -0.05), TABLE_FRICTION)
        pucks = tuple(Body(n, (BoxShape(sp.puck_half),), sp.puck_mass, (sp.start_x, sp.row_y(i), sp.puck_half[2]),
                           float(mu[i])) for i, n in enumerate(sp.names))
        gripper = Gripper(sp.PALM_HALF, sp.FINGER_HALF, 0.5, 0.05, sp.carry_height,
                          2 * sp.FINGER_HALF[2] + sp.PALM_HALF[2], 0.04, sp.mu_finger, sp.base_max_force,
                          sp.grip_force)
        return SceneDescription(sp.time_step, sp.solver_iterations, (table, *pucks), tuple(sp.names), gripper)

    def initial_configuration(self, props: dict) -> Configuration:
        sp = self.spec
        self.properties(props)
        objects = np.array([[sp.start_x, sp.row_y(i), sp.puck_half[2], 0, 0, 0, 1] for i in range(self.n_objects)])
        return Configuration(np.array([sp.start_x, 0.0, sp.carry_height, 0.0, 0.0]), objects)

    def place(self, config: Configuration, props: dict) -> Configuration:
        """Every puck flat on the table (their size is known: nothing to re-ground)."""
        self.properties(props)
        objects = config.objects.copy()
        objects[:, 2] = self.spec.puck_half[2]
        objects[:, 3:] = [quat_from_yaw(float(2 * np.arctan2(q[2], q[3]))) for q in objects[:, 3:]]
        return Configuration(config.robot, objects)

    # -- Y^-1 and Y --------------------------------------------------------------------------
    def symbolic_state(self, config: Configuration) -> frozenset[str]:
        """waiting(pJ) short of the line, placed(pJ) on it, lost(pJ) past it."""
        sp = self.spec
        where = lambda x: ("waiting" if x < sp.goal_x - sp.goal_tol else
                           "placed" if x <= sp.goal_x + sp.goal_tol else "lost")
        return frozenset(f"{where(p[0])}({n})" for n, p in zip(sp.names, config.objects))

    def _puck(self, action: str) -> int:
        m = _PUSH.match(action.replace(" ", ""))
        if not m or m.group(1) not in self.spec.names:
            raise ValueError(f"action {action!r}: expected push(pJ) of one of {', '.join(self.spec.names)}")
        return self.spec.names.index(m.group(1))

    def action_pose(self, props: dict, config: Configuration, action: str) -> np.ndarray:
        """Where the closed fingers let go: the puck, at the believed friction, slides on
        from there to rest on the goal line."""
        sp = self.spec
        j = self._puck(action)
        mu = float(self.properties(props)["friction"][j])
        key = self._start(config, action)
        key[0] += sp.clearance + sp.release(sp.goal_x - config.objects[j, 0], mu)
        return key

    # -- motion ------------------------------------------------------------------------------
    def _start(self, config: Configuration, action: str) -> np.ndarray:
        """The fingers just behind the puck, low."""
        sp = self.spec
        p = config.objects[self._puck(action)]
        return np.array([p[0] - sp.puck_half[0] - sp.FINGER_HALF[0] - sp.clearance, p[1], sp.tool_z, 0.0, 0.0])

    def pre_pose(self, config: Configuration, action: str, key: np.ndarray) -> np.ndarray:
        pre = self._start(config, action)
        pre[2] += 0.06
        return pre

    def _phases(self, config: Configuration, action: str, key: np.ndarray, transit) -> tuple[np.ndarray, float]:
        sp = self.spec
        pre, start = self.pre_pose(config, action, key), self._start(config, action)
        if transit is None:
            path = self.default_transit(config.robot.copy(), pre)
        else:                               # the checked transit's waypoints (x, y, z, yaw)
            waypoints = np.asarray(transit, dtype=np.float64)[:, :4]
            path = np.vstack([config.robot, np.column_stack([waypoints, np.zeros(len(waypoints))]), pre])
        move = tr.time_parameterize(path, sp.move_speed)
        down = tr.time_parameterize(np.array([pre, start]), sp.approach_speed)
        # Up to speed, on at it, and braking from the key pose: the puck leaves the fingers there.
        v = sp.speed(sp.goal_x - config.objects[self._puck(action), 0])
        stop = np.array(key[:5], dtype=np.float64)
        stop[0] = max(stop[0], start[0] + v * v / sp.push_accel) + v * v / (2 * sp.push_accel)
        push = tr.trapezoid_stroke(start, stop, max(v, 1e-3), sp.push_accel, 0.0, dt=0.004)
        up = push[-1, 1:].copy()
        up[2] = sp.carry_height
        leave = tr.time_parameterize(np.array([push[-1, 1:], up]), sp.approach_speed)
        return tr.concatenate(move, down, push, leave), float(move[-1, 0])

    def action_trajectory(self, config: Configuration, action: str, key: np.ndarray,
                          transit: np.ndarray | None = None) -> np.ndarray:
        return self._phases(config, action, key, transit)[0]

    def transit_end_time(self, config: Configuration, action: str, key: np.ndarray,
                         transit: np.ndarray | None = None) -> float:
        return self._phases(config, action, key, transit)[1]

    def obstacles(self, config: Configuration, size) -> list[Box]:
        """Every puck as its box (their size is known: `size` is not read)."""
        return [body_box(p, self.spec.puck_half) for p in config.objects]

    def gripper_boxes(self, held_size: float = 0.0, opening: float | None = None) -> list:
        sp = self.spec
        return hand_boxes(sp.PALM_HALF, sp.FINGER_HALF, 2 * sp.FINGER_HALF[2] + sp.PALM_HALF[2], 0.0)

    # -- measurements ------------------------------------------------------------------------
    def measurements(self, config: Configuration, log=None, action: str = "") -> np.ndarray:
        """Every puck's x (m)."""
        return np.array(config.objects[:, 0], dtype=np.float64)

    def measurement_model(self) -> tuple[np.ndarray, np.ndarray]:
        return np.arange(self.n_objects), np.full(self.n_objects, self.spec.position_sigma)

    def measurement_channels(self) -> list[dict]:
        return [{"name": f"{n}_x", "index": i, "unit": "m", "sigma": self.spec.position_sigma}
                for i, n in enumerate(self.spec.names)]
