"""The chute's physics half: pucks of unknown friction queued in a lane, swept to a line.

Written against the public kit only (``sim_workers.base``, ``scene``, ``configuration``,
``obstacles``, ``trajectory``, ``grounded_world``, ``reality_gap``, ``properties``): no
block-world code. The scene is data (``scene_description``) that the engine backend builds.

- The objects are pucks (a mesh this package ships, ``assets/puck.obj``) of known size and
  mass, queued in a lane between two rails; p1 is the front puck, nearest the goal line.
- L is each puck's friction coefficient on the table (Bullet multiplies the two bodies'
  coefficients; the table's is 1, so the puck's is the pair's).
- ``sweep(pj)`` lowers the closed fingers behind puck pj and strokes along the lane with a
  force-limited wrist: pj pushes every queued puck ahead of it, a train of k. Y sizes
  the limit from the believed friction (no harder than the train needs, with a margin,
  never over ``sweep_force``): a belief below the truth stalls the train, which is why
  grounding L pays. Friction grows with k x mu and the limit is capped, so a long train
  stalls or lags and ends short of the line: the trade-off between fewer sweeps and
  failed ones, which T learns per k.
- A puck past the goal line is delivered: a helper lifts it off to its parking slot
  beside the lane (``after_action``), as the container's helper unloads the tray; the
  chute's indexer sets the queued pucks back in their slots after every sweep.
- Measurements: every puck's x (a camera, 5 mm) and the wrist force along the lane during
  the stroke's middle half (a sensed channel, 0.3 N), about k mu m g.
"""
from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sim_workers import trajectory as tr
from sim_workers.base import PhysicsDomain
from sim_workers.configuration import Configuration, Workspace, quat_from_yaw
from sim_workers.engines import make_world
from sim_workers.grounded_world import act
from sim_workers.obstacles import Box, body_box, hand_boxes
from sim_workers.properties import PropertySpace, per_object_property
from sim_workers.reality_gap import action_jitter, executed, jitter_planar
from sim_workers.scene import Body, BoxShape, Gripper, MeshShape, SceneDescription

PUCK_MESH = str(Path(__file__).resolve().parent / "assets" / "puck.obj")
_SWEEP = re.compile(r"^sweep\((p\d+)\)$")
PALM_MASS, FINGER_MASS = 0.5, 0.05          # kg
FRICTION_BOUNDS = (0.02, 2.0)               # what a hypothesis may say at all


@dataclass(frozen=True)
class ChuteSpec:
    """Everything fixed about the chute; the pucks' friction is L, not here."""

    n_blocks: int = 8                  # pucks (the service's name for the object count)
    true_friction: float = 0.45
    friction_low: float = 0.15
    friction_high: float = 0.75
    puck_radius: float = 0.025
    puck_height: float = 0.02
    puck_mass: float = 0.2             # kg, known (a scale weighed them)
    first_x: float = 0.15              # p1's start; the queue runs back along -x
    pitch: float = 0.08                # room for the fingers between two pucks
    goal_x: float = 0.40               # a puck past this line is delivered
    goal_margin: float = 0.03          # the stroke takes the rear puck this far past it
    lane_clearance: float = 0.004      # between a puck and a rail
    park_y: float = 0.30               # delivered pucks wait here, beside the lane
    sweep_force: float = 5.0           # N, the most the wrist may exert along a stroke
    force_margin: float = 0.1          # Y's stroke limit: (1 + margin) x the believed friction ...
    force_floor: float = 0.3           # ... plus this (N)
    sweep_speed: float = 0.35          # m/s
    sweep_accel: float = 3.0           # m/s^2
    sweep_time_jitter: float = 0.2     # a real arm strokes U(1 +- this) times as fast
    position_sigma: float = 0.005      # m, the camera
    force_sigma: float = 0.3           # N, the wrist sensor
    mu_table: float = 1.0
    mu_rail: float = 0.1
    mu_finger: float = 0.5
    tool_z: float = 0.004              # fingertips above the table during a stroke
    clearance: float = 0.006           # fingers behind the puck before a stroke
    carry_height: float = 0.15
    move_speed: float = 0.4
    approach_speed: float = 0.2
    base_max_force: float = 60.0
    grip_force: float = 5.0
    settle_s: float = 0.6
    time_step: float = 1.0 / 120.0
    solver_iterations: int = 50

    SETTLE_DWELL_S = 0.3
    PALM_HALF = (0.006, 0.02, 0.01)
    FINGER_HALF = (0.005, 0.005, 0.03)
    MAX_OPENING = 0.04

    @property
    def names(self) -> list[str]:
        return [f"p{i + 1}" for i in range(self.n_blocks)]

    @property
    def lane_half(self) -> float:
        return self.puck_radius + self.lane_clearance

    @property
    def palm_offset(self) -> float:
        return 2 * self.FINGER_HALF[2] + self.PALM_HALF[2]

    def start_x(self, i: int) -> float:
        return self.first_x - i * self.pitch

    def park_xy(self, i: int) -> tuple[float, float]:
        return self.goal_x + 0.1 + i * self.pitch, self.park_y


class ChutePhysics(PhysicsDomain):
    """Pucks in a lane, swept in trains to a line; L = each puck's friction."""

    name = "chute"
    max_objects = 12
    logs_sensors = True
    probe_actions = ("sweep",)
    # What a run may set the sensors' noise to (`tmoc run --option`, a request's options):
    # a sigma near 0 leaves the likelihood no width.
    option_ranges = {"position_sigma": (1e-4, 0.1), "force_sigma": (1e-3, 10.0)}

    def __init__(self, spec: ChuteSpec | None = None, **overrides) -> None:
        spec = spec or ChuteSpec()
        if overrides:
            unknown = set(overrides) - {f.name for f in dataclasses.fields(ChuteSpec)}
            if unknown:
                raise ValueError(f"chute domain: unknown option(s) {sorted(unknown)}")
            spec = dataclasses.replace(spec, **overrides)
        if not 1 <= spec.n_blocks <= self.max_objects:
            raise ValueError(f"n_blocks: {spec.n_blocks} is outside [1, {self.max_objects}]")
        lo, hi = FRICTION_BOUNDS
        if not lo <= spec.friction_low < spec.friction_high <= hi:
            raise ValueError(f"friction_low, friction_high: need {lo} <= low < high <= {hi}")
        if not lo <= spec.true_friction <= hi:
            raise ValueError(f"true_friction: {spec.true_friction} is outside [{lo}, {hi}]")
        if not 0 < spec.sweep_force <= spec.base_max_force:
            raise ValueError(f"sweep_force: {spec.sweep_force} N is outside (0, base_max_force]")
        self.spec = spec

    # -- the objects and L --------------------------------------------------------------
    @property
    def object_names(self) -> list[str]:
        return self.spec.names

    @property
    def L(self) -> PropertySpace:
        sp = self.spec
        return PropertySpace(("friction",), ("1",), (sp.friction_low,), (sp.friction_high,),
                             (sp.true_friction,))

    def true_properties(self, sizes_variation: bool = False) -> dict:
        return {"friction": np.full(self.n_objects, self.spec.true_friction)}

    def properties(self, props: dict) -> dict:
        """{"friction": (n,)}: one coefficient for every puck or one each, within bounds."""
        return {"friction": per_object_property(props, "friction", self.n_objects, *FRICTION_BOUNDS)}

    def props_from_row(self, row: np.ndarray) -> dict:
        return {"friction": self.L.split(row, self.n_objects)["friction"]}

    def object_sizes(self, props: dict) -> np.ndarray:
        return np.full(self.n_objects, 2 * self.spec.puck_radius)

    # -- the scene ------------------------------------------------------------------------
    def scene_description(self, props: dict) -> SceneDescription:
        sp = self.spec
        mu = self.properties(props)["friction"]
        r, h, w = sp.puck_radius, sp.puck_height, sp.lane_half
        table = Body("table", (BoxShape((2.0, 2.0, 0.05)),), 0, (0.0, 0.0, -0.05), sp.mu_table)
        rail_half = (1.0, 0.01, 0.015)
        rails = tuple(Body(f"rail_{s}", (BoxShape(rail_half),), 0, (0.2, sign * (w + 0.01), 0.015), sp.mu_rail)
                      for s, sign in (("left", 1), ("right", -1)))
        pucks = tuple(Body(n, (MeshShape(PUCK_MESH, (r, r, h)),), sp.puck_mass, (sp.start_x(i), 0.0, h / 2),
                           float(mu[i]), maximal_coordinates=True)
                      for i, n in enumerate(sp.names))
        gripper = Gripper(sp.PALM_HALF, sp.FINGER_HALF, PALM_MASS, FINGER_MASS, sp.carry_height,
                          sp.palm_offset, sp.MAX_OPENING, sp.mu_finger, sp.base_max_force, sp.grip_force)
        return SceneDescription(sp.time_step, sp.solver_iterations, (table, *rails, *pucks),
                                tuple(sp.names), gripper)

    @property
    def execution_jitter(self) -> dict[str, float]:
        return {"sweep": float(self.spec.sweep_time_jitter)} if self.spec.sweep_time_jitter else {}

    @property
    def workspace(self) -> Workspace:
        return Workspace(np.array([-0.9, -0.5, 0.0, -np.pi]), np.array([1.4, 0.6, 0.5, np.pi]))

    def initial_configuration(self, props: dict) -> Configuration:
        sp = self.spec
        self.properties(props)
        objects = np.array([[sp.start_x(i), 0.0, sp.puck_height / 2, 0, 0, 0, 1] for i in range(self.n_objects)])
        robot = np.array([sp.first_x, 0.0, sp.carry_height, 0.0, 0.0])
        return Configuration(robot, objects)

    def place(self, config: Configuration, props: dict) -> Configuration:
        """Every puck on the table, upright (their size is known: nothing to re-ground)."""
        self.properties(props)
        objects = config.objects.copy()
        objects[:, 2] = self.spec.puck_height / 2
        objects[:, 3:] = [quat_from_yaw(float(2 * np.arctan2(q[2], q[3]))) for q in objects[:, 3:]]
        return Configuration(config.robot, objects)

    def after_action(self, config: Configuration, action: str) -> Configuration:
        """A helper lifts each puck that crossed the line to its parking slot, and the
        chute's indexer sets the queued ones back in their slots: a stalled train is
        pressed together, and fingers could not go down between touching pucks."""
        sp = self.spec
        objects = config.objects.copy()
        for i, p in enumerate(config.objects):
            if self._parked(p):
                continue
            x, y = sp.park_xy(i) if p[0] > sp.goal_x else (sp.start_x(i), 0.0)
            objects[i] = [x, y, sp.puck_height / 2, 0, 0, 0, 1]
        if np.array_equal(objects, config.objects):
            return config
        return Configuration(config.robot, objects)

    def _parked(self, pose: np.ndarray) -> bool:
        return abs(pose[1] - self.spec.park_y) < 0.05

    # -- Y^-1 and Y --------------------------------------------------------------------------
    def symbolic_state(self, config: Configuration) -> frozenset[str]:
        sp = self.spec
        atoms = []
        for name, p in zip(sp.names, config.objects):
            done = self._parked(p) or p[0] > sp.goal_x
            atoms.append(f"delivered({name})" if done else f"queued({name})")
        return frozenset(atoms)

    def check_action(self, action: str) -> None:
        m = _SWEEP.match(action.replace(" ", ""))
        if not m:
            raise ValueError(f"action {action!r}: the chute's one action is sweep(pJ)")
        if m.group(1) not in self.spec.names:
            raise ValueError(f"action {action!r}: no puck {m.group(1)} (pucks p1..p{self.n_objects})")

    def _puck(self, action: str) -> int:
        self.check_action(action)
        return self.spec.names.index(_SWEEP.match(action.replace(" ", "")).group(1))

    def action_pose(self, props: dict, config: Configuration, action: str) -> np.ndarray:
        """The closed fingers just behind puck pj, low, facing along the lane; the sixth
        entry is the stroke's force limit, sized from the believed friction."""
        sp = self.spec
        j = self._puck(action)
        x = config.objects[j, 0] - sp.puck_radius - sp.FINGER_HALF[0] - sp.clearance
        return np.array([x, 0.0, sp.tool_z, 0.0, 0.0, self.stroke_limit(props, config, j)])

    def stroke_limit(self, props: dict, config: Configuration, j: int) -> float:
        """The wrist's limit (N) for a train ending at puck j: what slides the believed
        train with a margin (``force_margin``) plus ``force_floor``, never more than
        ``sweep_force``. A robot pushes no harder than it must (pucks jump and rails wear
        under a full-force stroke); a belief below the truth stalls the train."""
        sp = self.spec
        mu = self.properties(props)["friction"]
        train = [i for i in range(j + 1) if not self._parked(config.objects[i])]
        need = sp.puck_mass * 9.81 * float(np.sum(mu[train]))
        return float(min(sp.sweep_force, sp.force_floor + (1.0 + sp.force_margin) * need))

    # -- motion ------------------------------------------------------------------------------
    def pre_pose(self, config: Configuration, action: str, key: np.ndarray) -> np.ndarray:
        pre = np.array(key[:5], dtype=np.float64)
        pre[2] = key[2] + 0.08
        return pre

    def _phases(self, config: Configuration, action: str, key: np.ndarray, transit):
        sp = self.spec
        start = config.robot.copy()
        pre = self.pre_pose(config, action, key)
        if transit is None:
            path = self.default_transit(start, pre)
        else:
            path = np.asarray(transit, dtype=np.float64)
            if path.shape[1] == 4:
                path = np.column_stack([path, np.full(len(path), pre[4])])
            path = np.vstack([start, path, pre])
        limit = float(key[5]) if len(key) > 5 else sp.sweep_force
        key = np.asarray(key[:5], dtype=np.float64)
        move = tr.time_parameterize(path, sp.move_speed)
        descend = tr.time_parameterize(np.array([pre, key]), sp.approach_speed)
        # Dwell at the key pose: the wrist lags its reference by a few mm on the way down,
        # and fingers still above the puck's top would ride over it.
        descend = np.vstack([descend, [descend[-1, 0] + sp.SETTLE_DWELL_S, *key]])
        end = np.array(key, dtype=np.float64)
        end[0] = sp.goal_x + sp.goal_margin - sp.puck_radius - sp.FINGER_HALF[0]
        stroke = tr.trapezoid_stroke(key, end, sp.sweep_speed, sp.sweep_accel, 0.0)
        up = end.copy()
        up[0] -= 0.02
        up[2] = sp.carry_height
        leave = tr.time_parameterize(np.array([end, up]), sp.approach_speed)
        free = sp.base_max_force
        pieces = [tr.with_efforts(move, sp.grip_force, free), tr.with_efforts(descend, sp.grip_force, free),
                  tr.with_efforts(stroke, sp.grip_force, limit), tr.with_efforts(leave, sp.grip_force, free)]
        return tr.concatenate(*pieces), float(move[-1, 0])

    def action_trajectory(self, config: Configuration, action: str, key: np.ndarray,
                          transit: np.ndarray | None = None) -> np.ndarray:
        return self._phases(config, action, key, transit)[0]

    def transit_end_time(self, config: Configuration, action: str, key: np.ndarray,
                         transit: np.ndarray | None = None) -> float:
        return self._phases(config, action, key, transit)[1]

    def obstacles(self, config: Configuration, size) -> list[Box]:
        """The rails and every puck as boxes (their size is known: `size` is not read)."""
        sp = self.spec
        r, h = sp.puck_radius, sp.puck_height
        rails = [body_box(np.array([0.2, s * (sp.lane_half + 0.01), 0.015, 0, 0, 0, 1]), (1.0, 0.01, 0.015))
                 for s in (1, -1)]
        return rails + [body_box(p, (r, r, h / 2)) for p in config.objects]

    def gripper_boxes(self, held_size: float = 0.0, opening: float | None = None) -> list:
        sp = self.spec
        opening = 0.0 if opening is None else min(float(opening), sp.MAX_OPENING)
        return hand_boxes(sp.PALM_HALF, sp.FINGER_HALF, sp.palm_offset, opening)

    # -- measurements ------------------------------------------------------------------------
    def senses(self, action: str) -> bool:
        return action.replace(" ", "").startswith("sweep(")

    def measurements(self, config: Configuration, log=None, action: str = "") -> np.ndarray:
        """Every puck's x, then the stroke force (N, NaN without a sweep's sensor log)."""
        return np.concatenate([config.objects[:, 0], [self.stroke_force(log)]])

    def stroke_force(self, log) -> float:
        """The mean wrist force along the lane over the middle half of the force-limited
        stroke: the train's friction while it slides (the cap while it stalls)."""
        if log is None or log.commanded is None or log.commanded.shape[1] < 7:
            return float("nan")
        idx = np.flatnonzero(log.commanded[:, 6] < self.spec.base_max_force)
        if len(idx) < 4:
            return float("nan")
        mid = idx[len(idx) // 4: 3 * len(idx) // 4]
        return float(abs(np.mean(log.wrist_force[mid, 0])))

    def measurement_channels(self) -> list[dict]:
        n, sp = self.n_objects, self.spec
        return ([{"name": f"{p}_x", "index": i, "unit": "m", "sigma": sp.position_sigma}
                 for i, p in enumerate(sp.names)]
                + [{"name": "stroke_force", "index": n, "unit": "N", "sigma": sp.force_sigma, "sensed": True}])

    def measurement_model(self) -> tuple[np.ndarray, np.ndarray]:
        chans = self.measurement_channels()
        return np.array([c["index"] for c in chans]), np.array([float(c["sigma"]) for c in chans])

    # -- probes and T* --------------------------------------------------------------------------
    def probe_trial(self, action: str, load_k: int, rng: np.random.Generator, *, truth: dict,
                    belief: dict) -> bool:
        """A sweep of a train of `load_k` pucks at the `truth`'s friction with Y at the
        `belief`'s (both by L's names, every property given: `tmoc probe --truth friction=V
        --belief friction=W`, or T*'s probes at the world's ``true_friction``), placed and
        timed with the reality gap's jitter; True when all of them are delivered."""
        if action != "sweep":
            raise ValueError(f"action: {action!r} is not one of sweep")
        truth = {"friction": np.full(self.n_objects, float(truth["friction"]))}
        belief = {"friction": np.full(self.n_objects, float(belief["friction"]))}
        config = self.initial_configuration(truth)
        config = Configuration(config.robot, jitter_planar(rng, config.objects, range(self.n_objects)))
        run_as = (lambda traj, a: executed(traj, a, rng, action_jitter(self, a)))
        with make_world(self) as world:
            config = world.reset(config, truth)
            out = act(world, self, config, belief, f"sweep(p{load_k})", run_as=run_as)
        return all(f"delivered(p{i + 1})" in out.state for i in range(load_k))

    def t_star_probe_jobs(self, n_blocks: int) -> list[tuple[str, int]]:
        return [("sweep", k) for k in range(1, n_blocks + 1)]

    def t_star_from_probes(self, successes: dict, trials: int, n_blocks: int) -> dict:
        return {"sweep": [successes[("sweep", k)] / trials for k in range(1, n_blocks + 1)]}
