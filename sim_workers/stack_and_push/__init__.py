"""The stack-and-push domain (the paper's real-robot task; docs/BUILTIN_DOMAINS.md):
stack cubes into a tower on a rail's start site, push the tower along the rail to the goal.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..base import PhysicsDomain
from ..blocks.hand import BLOCK_OPTION_RANGES, grasp_alternatives, grip_depth, pickup_misalignment
from ..blocks.terms import held_block
from ..configuration import Configuration, Workspace
from ..scene import SceneDescription
from ..blocks.scene import GRIPPER_MASS
from ..obstacles import Box, cube_box, hand_boxes, per_block
from ..properties import MAX_DENSITY, MIN_DENSITY, SIZES_VARIATION_SCALE, PropertyError, PropertySpace, block_properties
from . import efforts, probes, scene, state_mapping, trajectories
from .spec import StackAndPushSpec

MAX_BLOCKS = 8
MIN_FORCE_SIGMA = 0.001     # N


class StackAndPushDomain(PhysicsDomain):
    """Cubes, a guide rail and a floating gripper; L = the blocks' side lengths."""

    name = "stack_and_push"
    # An arm beside the workspace, clear of the start row and the tray's (or tower's) path:
    # on a 10 cm grid, a base from which a UR5e reaches every tool point of episodes at the
    # prior's ends and middle in both built-in domains, as do its four neighbours
    # (docs/SERVICE.md, Robots).
    robot_base = (0.2, 0.4, 0.0, -math.pi / 2)
    # Only the ranges of options this scene has (``blocks.hand.BLOCK_OPTION_RANGES``).
    option_ranges = {k: v for k, v in BLOCK_OPTION_RANGES.items() if k in StackAndPushSpec.__dataclass_fields__}
    # The action kinds whose particle worlds leave out the bodies they cannot reach
    # (sim_workers/reach.py), by measurement (benchmarks/bench_worlds.py (e), 2 cores): a
    # pickup x1.4, a stack onto a tower x1.09, the same symbolic outcomes and the weighed
    # channels within 1e-9 (a 3-episode run: the same utilities, posterior 44.862 mm both
    # ways, 2e-7 mm apart; 1.3x less wall time). Not bit for bit: Bullet's solver stops on
    # a residual summed over every contact row, left-out rows included. A push of the tower
    # keeps every block (x1.02): it stays whole.
    leave_out_actions: tuple[str, ...] = ("pickup", "stack")
    max_objects = MAX_BLOCKS

    def __init__(self, spec: StackAndPushSpec | None = None, **overrides) -> None:
        spec = spec or StackAndPushSpec()
        if overrides:
            unknown = set(overrides) - {f.name for f in dataclasses.fields(StackAndPushSpec)}
            if unknown:
                raise ValueError(f"stack_and_push domain: unknown option(s) {sorted(unknown)}")
            spec = dataclasses.replace(spec, **overrides)
        if not 1 <= spec.n_blocks <= MAX_BLOCKS:
            raise ValueError(f"n_blocks: {spec.n_blocks} is outside [1, {MAX_BLOCKS}]")
        if not MIN_DENSITY < spec.density <= MAX_DENSITY:
            raise ValueError(f"density: {spec.density} kg/m^3 is outside ({MIN_DENSITY:g}, {MAX_DENSITY:g}]")
        if spec.force_sigma is not None and not spec.force_sigma > 0:
            raise ValueError(f"force_sigma: {spec.force_sigma} N must be positive")
        if spec.force_sigma is not None and spec.force_sigma < MIN_FORCE_SIGMA:
            raise ValueError(f"force_sigma: {spec.force_sigma} N is below {MIN_FORCE_SIGMA} N "
                             "(a wrist sensor resolves about 1 mN at best)")
        if not 0 < spec.density_low < spec.density_high:
            raise ValueError(f"density_low/density_high: need 0 < {spec.density_low} < {spec.density_high}")
        if not 0 < spec.prior_low < spec.prior_high:
            raise ValueError(f"prior_low/prior_high: need 0 < {spec.prior_low} < {spec.prior_high}")
        if not spec.weigh_s > 0:
            raise ValueError(f"weigh_s: {spec.weigh_s} s must be positive")
        for name in ("grip_safety", "push_safety", "push_accel_ref"):
            if not getattr(spec, name) > 0:
                raise ValueError(f"{name}: {getattr(spec, name)} must be positive")
        self.spec = spec

    # -- data -----------------------------------------------------------------------
    @property
    def object_names(self) -> list[str]:
        return self.spec.object_names

    @property
    def learned_objects(self) -> list[str]:
        return self.spec.block_names

    @property
    def execution_jitter(self) -> dict[str, float]:
        """A real arm's push runs U(1 +- push_time_jitter) times as fast as planned."""
        return {"push": float(self.spec.push_time_jitter)} if self.spec.push_time_jitter else {}

    @property
    def workspace(self) -> Workspace:
        """The motion planner's bounds: room above a tower of every block at the largest
        prior size plus a held block and the palm (the loop's default stops at 0.6 m)."""
        return Workspace(np.array([-0.5, -0.6, 0.0, -np.pi]), np.array([1.2, 0.6, 0.75, np.pi]))

    @property
    def L(self) -> PropertySpace:
        """The unknown properties: the block size, and with ``unknown_density`` the density."""
        sp = self.spec
        if sp.unknown_density:
            return PropertySpace(("size", "density"), ("m", "kg/m^3"), (sp.prior_low, sp.density_low),
                                 (sp.prior_high, sp.density_high), (sp.true_size, sp.density))
        return PropertySpace(("size",), ("m",), (sp.prior_low,), (sp.prior_high,), (sp.true_size,))

    def true_properties(self, sizes_variation: bool = False) -> dict:
        """The hidden truth: all blocks `true_size`, or (variation "sizes") one 20 % larger."""
        sizes = np.full(self.spec.n_blocks, self.spec.true_size)
        if sizes_variation:
            sizes[0] *= SIZES_VARIATION_SCALE
        return {"block_sizes": sizes, "density": self.spec.density}

    def properties(self, props: dict) -> dict:
        """Validated properties: block_sizes (n,), density, block_masses (n,); idempotent."""
        if not isinstance(props, dict):
            raise PropertyError("properties: expected a mapping with 'block_sizes'")
        return block_properties(props, self.spec.n_blocks, self.spec.density)

    def props_from_row(self, row: np.ndarray) -> dict:
        """A row of L as properties: (size) or (size, density), for every block alike, or
        one per block per property (property-major)."""
        values = self.L.split(row, self.spec.n_blocks)
        props = {"block_sizes": values["size"]}
        if "density" in values:
            d = values["density"]
            props["density"] = float(d[0]) if np.all(d == d[0]) else d
        return props

    # -- physics ---------------------------------------------------------------------
    def scene_description(self, props: dict) -> SceneDescription:
        p = self.properties(props)
        return scene.scene_description(self.spec, p["block_sizes"], p["block_masses"])

    def initial_configuration(self, props: dict) -> Configuration:
        return state_mapping.initial_configuration(self.spec, self.properties(props)["block_sizes"])

    def place(self, config: Configuration, props: dict) -> Configuration:
        return state_mapping.place_for_sizes(self.spec, config, self.properties(props)["block_sizes"])

    def after_action(self, config: Configuration, action: str) -> Configuration:
        """After a push a helper clears the goal area: every block lying in it (in the rail
        between goal_x) goes to its delivered slot and counts as is_in(B,goal)."""
        if not action.replace(" ", "").startswith("push("):
            return config
        spec = self.spec
        obj = config.objects
        moved = [i for i in range(spec.n_blocks) if state_mapping.in_goal_area(spec, obj[i, :3])]
        if not moved:
            return config
        objects = obj.copy()
        half = _half_heights(obj, moved)
        for i in moved:
            xy = spec.delivered_slot(i)
            objects[i] = [xy[0], xy[1], half[i], 0, 0, 0, 1]
        return Configuration(config.robot, objects)

    # -- Y and Y^-1 ------------------------------------------------------------------
    def symbolic_state(self, config: Configuration) -> frozenset[str]:
        return state_mapping.symbolic_state(self.spec, config)

    def action_pose(self, props: dict, config: Configuration, action: str) -> np.ndarray:
        """Y: the key pose (x, y, z, yaw, opening) under the believed properties, and with
        mass in Y a sixth entry, the effort (grip force per finger, or push force limit)
        from the believed masses."""
        p = self.properties(props)
        key = state_mapping.action_pose(self.spec, p["block_sizes"], config, action)
        if not self.force_from_mass:
            return key
        name, args = state_mapping.parse_action(action)
        block = state_mapping.block_index(self.spec, args[1]) if name != "push" else None
        chain = state_mapping.block_labels(self.spec, config)[1] if name == "push" else []
        return np.append(key, efforts.effort(self.spec, p["block_masses"], name, block, chain))

    def misalignment(self, config: Configuration, action: str) -> tuple[int, np.ndarray] | None:
        """A pickup's block and the fingers' closing axis (``blocks.hand.pickup_misalignment``)."""
        return pickup_misalignment(self.spec, config, action, 0)

    def pose_alternatives(self, config: Configuration, action: str, pose: np.ndarray,
                          rows: np.ndarray) -> list[np.ndarray]:
        """A pickup's grasp a quarter turn round when a block is within the fingers' reach
        (``blocks.hand.grasp_alternatives``; the largest believed size bounds the reach)."""
        rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
        largest = float(np.max(self._split_rows(rows)["size"])) if len(rows) else 0.0
        return grasp_alternatives(self.spec, config, action, pose, largest, 0)

    def take_first(self, config: Configuration) -> tuple[str, ...]:
        """Blocks resting on others: one lying on another (``state_mapping.lying_on_blocks``)
        or standing on an edge, which a cube does only leaning on a neighbour. The tower's
        blocks and the held one are not waiting to be picked and are left out."""
        labels, _ = state_mapping.block_labels(self.spec, config)
        on = state_mapping.lying_on_blocks(self.spec, config.objects)
        return tuple(self.spec.block_names[i] for i, label in enumerate(labels)
                     if label in state_mapping.PICKUP_PLACES
                     and (on[i] or not state_mapping.upright(config.objects[i, 3:])))

    def action_poses(self, rows: np.ndarray, config: Configuration, action: str) -> np.ndarray:
        """Y for every row of L at once ((N, D) -> (N, 5), or (N, 6) with mass in Y), bit
        for bit the per-row `action_pose` of `props_from_row`."""
        rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
        values = self._split_rows(rows)
        sizes = values["size"]
        density = values.get("density")
        # Validation as per row: every value is inside its range iff each column's extremes are.
        self.properties({"block_sizes": sizes.min(axis=0)})
        self.properties({"block_sizes": sizes.max(axis=0)})
        if density is not None:
            self.properties({"block_sizes": sizes[0], "density": density.min(axis=0)})
            self.properties({"block_sizes": sizes[0], "density": density.max(axis=0)})
        key = state_mapping.action_poses(self.spec, sizes, config, action)
        if not self.force_from_mass:
            return key
        masses = (self.spec.density if density is None else density) * sizes ** 3
        name, args = state_mapping.parse_action(action)
        block = state_mapping.block_index(self.spec, args[1]) if name != "push" else None
        chain = state_mapping.block_labels(self.spec, config)[1] if name == "push" else []
        return np.column_stack([key, efforts.efforts(self.spec, masses, name, block, chain)])

    def _split_rows(self, rows: np.ndarray) -> dict[str, np.ndarray]:
        """Rows of L (N, D) as {name: (N, n_blocks)}: `L.split` for many rows."""
        names, n = self.L.names, self.spec.n_blocks
        if rows.shape[1] == len(names):
            return {name: np.repeat(rows[:, j:j + 1], n, axis=1) for j, name in enumerate(names)}
        if rows.shape[1] == len(names) * n:
            return {name: rows[:, j * n:(j + 1) * n] for j, name in enumerate(names)}
        raise PropertyError(f"L: rows of {rows.shape[1]} values; expected {len(names)} "
                            f"({', '.join(names)}) or {len(names) * n} (one per block per property)")

    @property
    def force_from_mass(self) -> bool:
        """Whether Y sizes the grip and the push from the believed mass: as set, else
        exactly when the density is unknown."""
        fm = self.spec.force_from_mass
        return bool(self.spec.unknown_density if fm is None else fm)

    def action_trajectory(self, config: Configuration, action: str, key: np.ndarray,
                          transit: np.ndarray | None = None) -> np.ndarray:
        return trajectories.action_trajectory(self.spec, config, action, key, transit)

    def transit_end_time(self, config: Configuration, action: str, key: np.ndarray,
                         transit: np.ndarray | None = None) -> float:
        return trajectories.transit_end_time(self.spec, config, action, key, transit)

    def gripper_boxes(self, held_size: float = 0.0, opening: float | None = None) -> list[tuple[np.ndarray, float]]:
        """(half extents, z offset of the centre above the fingertips) of the boxes of the
        gripper: palm, fingers `opening` apart (default: their widest) and a held block as
        Y grasps it."""
        sp = self.spec
        opening = sp.max_opening if opening is None else min(float(opening), sp.max_opening)
        return hand_boxes(sp.palm_half, sp.finger_half, sp.palm_offset, opening, held_size,
                          grip_depth(sp, held_size))

    def obstacles(self, config: Configuration, size) -> list[Box]:
        """Boxes (centre, half extents, rotation) of the rail walls and every block
        not in the hand or delivered, for the motion planner's collision check; `size` is
        the believed block size, one for all or one per block."""
        spec = self.spec
        labels, _ = state_mapping.block_labels(spec, config)
        sizes = per_block(size, spec.n_blocks)
        x0, x1 = spec.rail_x
        yc = spec.rail_half_gap + spec.wall_thickness / 2
        wall = np.array([(x1 - x0) / 2, spec.wall_thickness / 2, spec.wall_height / 2])
        boxes = [(np.array([(x0 + x1) / 2, s * yc, spec.wall_height / 2]), wall.copy(), np.eye(3)) for s in (-1, 1)]
        for i, label in enumerate(labels):
            if label not in (state_mapping.HELD, state_mapping.GOAL):
                # As it lies: the push's pre-pose is 3 mm behind the tower's rear faces.
                boxes.append(cube_box(config.objects[i], sizes[i]))
        return boxes

    def pre_pose(self, config: Configuration, action: str, key: np.ndarray) -> np.ndarray:
        holding = any(a.startswith("is_holding") for a in self.symbolic_state(config))
        return trajectories.pre_pose(self.spec, action, key, holding)

    @property
    def logs_sensors(self) -> bool:
        """Whether worlds log the sensors during an action (and pass the log to
        `measurements`): only when the held weight is weighed. Logging costs 6-8 % of a
        physics step (measured), which a run with the density known need not pay; its
        held-weight channel then reads NaN (not measured)."""
        return self.force_sigma is not None

    def senses(self, action: str) -> bool:
        """Whether an action's sensor log is read: pickups only (the held weight and the
        grasp width); logging a stack or a push would cost 4-14 % of its steps for nothing
        (benchmarks/bench_mass_in_y.py)."""
        return action.replace(" ", "").startswith("pickup(")

    def measurements(self, config: Configuration, log=None, action: str = "") -> np.ndarray:
        """The finger opening, planar block positions (x, y per block; no heights: a depth
        reading of a block would give its size away), then the held weight (N): the mean
        vertical wrist force over the lift's last ``weigh_s`` of a pickup, less the empty
        gripper's weight (NaN after any other action, or without a sensor log), and the
        grasp width (m): the finger opening at the end of a pickup's grip, before the
        lift (what the hand closed on; NaN likewise). Without the grasp width a block
        that slipped out on the lift (too heavy for the grip) and one the fingers missed
        (too small) look alike, and the filter learned "small" from a slip (measured:
        every particle at the prior's 30 mm floor, truth 45 mm)."""
        return np.concatenate([[config.robot[4]], config.objects[:, :2].ravel(),
                               [held_weight(self.spec, log, action), grasp_width(log, action)]])

    def measurement_channels(self) -> list[dict]:
        """Every channel: name, index, unit and sigma (None: reported, not weighed)."""
        n = self.spec.n_blocks
        return ([{"name": "finger_opening", "index": 0, "unit": "m", "sigma": 0.002}]
                + [{"name": f"{b}_{ax}", "index": 1 + 2 * i + k, "unit": "m", "sigma": None}
                   for i, b in enumerate(self.learned_objects) for k, ax in enumerate("xy")]
                + [{"name": "held_weight", "index": 1 + 2 * n, "unit": "N", "sigma": self.force_sigma,
                    "sensed": True},
                   {"name": "grasp_width", "index": 2 + 2 * n, "unit": "m",
                    "sigma": 0.002 if self.logs_sensors else None, "sensed": True}])

    @property
    def force_sigma(self) -> float | None:
        """The held-weight channel's noise: as set, else 0.1 N when the density is unknown
        (weighed), else None (reported only: a known density leaves it nothing to learn
        that the finger opening does not already say)."""
        sp = self.spec
        if sp.force_sigma is not None:
            return float(sp.force_sigma)
        return 0.1 if sp.unknown_density else None

    def measurement_model(self) -> tuple[np.ndarray, np.ndarray]:
        """(indices, std) of the weighed channels: the finger opening (2 mm) and, when it
        has a sigma, the held weight; landing positions after a topple are chaotic (the
        container's finding) and are not weighed."""
        chans = [c for c in self.measurement_channels() if c["sigma"] is not None]
        return np.array([c["index"] for c in chans]), np.array([float(c["sigma"]) for c in chans])

    # -- probe (tmoc probe, T* estimates) --------------------------------------------
    probe_actions = probes.PROBE_ACTIONS

    def probe_trial(self, action: str, true_size: float, believed_size: float, load_k: int,
                    rng: np.random.Generator, believed_density: float | None = None) -> bool | None:
        """One seeded trial of `action` in this (already jittered) world (None: a built
        tower's context was not reached)."""
        return probes.probe_trial(self, action, true_size, believed_size, load_k, rng, believed_density)

    def probe_loads(self, action: str) -> range:
        """Tower heights a probe of `action` accepts (``sim_workers.probe.probe`` checks
        them): a stack onto 0..n-1 (a block must stay free; 0 is the empty start site,
        which ``t_star_probe_jobs`` asks for), a push or stand of 1..n; for
        ``rail_pickup`` the blocks lying beside it on the rail, 0..2."""
        n = self.spec.n_blocks
        if action == "rail_pickup":          # the blocks lying beside it on the rail
            return range(min(probes.RAIL_NEIGHBOURS, n - 1) + 1)
        return range(n) if action.removeprefix("built_") == "stack" else range(1, n + 1)

    # -- T* (what `tmoc experiment` compares the learned T against) -------------------
    @staticmethod
    def t_star_probe_jobs(n_blocks: int) -> list[tuple[str, int]]:
        """(action, tower height) of the probes T* needs: pickup; a pickup then a stack
        onto a tower of h, h = 0..n-1; a push of a tower of k, k = 1..n. The towers are
        built by the agent's own pickups and stacks (``built_*`` probes), so T* judges the
        towers the agent really pushes."""
        return ([("pickup", 1)] + [("built_stack", h) for h in range(n_blocks)]
                + [("built_push", k) for k in range(1, n_blocks + 1)])

    @staticmethod
    def t_star_from_probes(successes: dict, trials: int, n_blocks: int) -> dict:
        """T* from probe counts: pickup is its rate; stack[h] is the rate of "pick up, then
        stack onto a tower of h" divided by the pickup rate (clipped to [0, 1]; 0 if no
        pickup succeeded); push[k-1] is the rate of pushing a tower of k; the towers are
        built by the agent's own actions."""
        p_pickup = successes[("pickup", 1)] / trials
        kind = "built_" if ("built_push", 1) in successes else ""   # (caches from before: synthetic towers)
        stack = [0.0 if p_pickup == 0 else float(min(1.0, successes[(kind + "stack", h)] / trials / p_pickup))
                 for h in range(n_blocks)]
        push = [successes[(kind + "push", k)] / trials for k in range(1, n_blocks + 1)]
        return {"pickup": float(p_pickup), "stack": stack, "push": [float(p) for p in push]}

    @staticmethod
    def held_object(state: frozenset[str]) -> str | None:
        return held_block(state)

    def check_action(self, action: str) -> None:
        name, args = state_mapping.parse_action(action)
        if name == "pickup":
            if len(args) != 3 or args[0] != "r":
                raise ValueError(f"action: expected pickup(r,B,L), got {action!r}")
            state_mapping.block_index(self.spec, args[1])
            if args[2] not in state_mapping.PICKUP_PLACES:
                raise ValueError(f"action: pickup from {args[2]!r} (expected init, table or rail)")
        elif name == "stack":
            if len(args) != 3 or args[0] != "r" or args[2] != "tower":
                raise ValueError(f"action: expected stack(r,B,tower), got {action!r}")
            state_mapping.block_index(self.spec, args[1])
        elif args != ["r", "tower", "start", "goal"]:
            raise ValueError(f"action: expected push(r,tower,start,goal), got {action!r}")


GRAVITY = 9.81


def held_weight(spec: StackAndPushSpec, log, action: str) -> float:
    """What the wrist sensor says the hand holds (N), from a pickup's sensor log: the mean
    vertical force over the last ``weigh_s`` of the lift (constant speed: no inertia), less
    the empty gripper's weight. NaN when there is nothing to weigh."""
    if log is None or not action.replace(" ", "").startswith("pickup("):
        return float("nan")
    sel = log.window(log.t_end - spec.weigh_s, log.t_end)
    if not sel.any():
        return float("nan")
    return float(np.mean(log.wrist_force[sel, 2])) - GRIPPER_MASS * GRAVITY


GRASP_S = 0.1     # s: the grasp width is the mean opening over the grip's last 0.1 s


def grasp_width(log, action: str) -> float:
    """The finger opening at the end of a pickup's grip (m): the mean over the last
    ``GRASP_S`` of the steps commanded closed at the lowest height, before the lift. NaN
    when there is nothing to read."""
    if log is None or log.commanded is None or not action.replace(" ", "").startswith("pickup("):
        return float("nan")
    z, opening = log.commanded[:, 2], log.commanded[:, 4]
    gripping = (opening <= 1e-9) & (z <= z.min() + 1e-6)
    if not gripping.any():
        return float("nan")
    t = log.times[gripping]
    last = gripping.copy()
    last[gripping] = t > t[-1] - GRASP_S
    return float(np.mean(log.opening[last]))


def _half_heights(objects: np.ndarray, rows: list[int]) -> dict[int, float]:
    """Half sizes of delivered blocks, read off how they rest (the helper sets each down
    on the table): a block on the floor has its centre at half its size, one resting on
    another is that block's top plus half its own. Clamped to the sizes properties accept."""
    half: dict[int, float] = {}
    for i in sorted(rows, key=lambda r: objects[r, 2]):
        below = [j for j in half if np.linalg.norm(objects[j, :2] - objects[i, :2]) < 0.02]
        z = objects[i, 2]
        h = z - (objects[below[-1], 2] + half[below[-1]]) if below else z
        half[i] = float(np.clip(h, 0.005, 0.05))
    return half
