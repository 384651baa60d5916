"""The container domain (the paper's simulation experiment)."""
from __future__ import annotations

import dataclasses
import math
import re

import numpy as np

from ..base import PhysicsDomain
from ..blocks.hand import BLOCK_OPTION_RANGES, grasp_alternatives, grip_depth, pickup_misalignment
from ..blocks.terms import held_block
from ..configuration import Configuration
from ..scene import SceneDescription
from ..obstacles import Box, body_box, cube_box, hand_boxes, per_block
from ..properties import MAX_DENSITY, MIN_DENSITY, SIZES_VARIATION_SCALE, PropertyError, block_properties
from . import columns, probes, scene, state_mapping, trajectories
from .spec import ContainerSpec


class ContainerDomain(PhysicsDomain):
    """Blocks, an open container and a floating gripper; L = the blocks' side lengths."""

    name = "container"
    # An arm beside the workspace, clear of the start row and the tray's (or tower's) path:
    # on a 10 cm grid, a base from which a UR5e reaches every tool point of episodes at the
    # prior's ends and middle in both built-in domains, as do its four neighbours
    # (docs/SERVICE.md, Robots).
    robot_base = (0.2, 0.4, 0.0, -math.pi / 2)
    # Only the ranges of options this scene has (``blocks.hand.BLOCK_OPTION_RANGES``).
    option_ranges = {k: v for k, v in BLOCK_OPTION_RANGES.items() if k in ContainerSpec.__dataclass_fields__}
    # No action leaves bodies out (sim_workers/reach.py), although a pickup would gain x1.4
    # (benchmarks/bench_worlds.py (e)): with 50 solver iterations Bullet stops on a residual
    # summed over every contact row, so the resting bodies a pickup leaves out change when
    # the solver stops, and the grasp's opening (the likelihood's channel) moved by up to
    # 0.6 mm in a 3-episode run. Outcomes must not depend on leaving out: it stays off.
    leave_out_actions: tuple[str, ...] = ()
    max_objects = 16

    def __init__(self, spec: ContainerSpec | None = None, **overrides) -> None:
        spec = spec or ContainerSpec()
        if overrides:
            unknown = set(overrides) - {f.name for f in dataclasses.fields(ContainerSpec)}
            if unknown:
                raise ValueError(f"container domain: unknown option(s) {sorted(unknown)}")
            spec = dataclasses.replace(spec, **overrides)
        if not 1 <= spec.n_blocks <= self.max_objects:
            raise ValueError(f"n_blocks: {spec.n_blocks} is outside [1, {self.max_objects}]")
        if not MIN_DENSITY < spec.density <= MAX_DENSITY:
            raise ValueError(f"density: {spec.density} kg/m^3 is outside ({MIN_DENSITY:g}, {MAX_DENSITY:g}]")
        self.spec = spec

    # -- data -----------------------------------------------------------------------
    @property
    def object_names(self) -> list[str]:
        return self.spec.object_names

    @property
    def learned_objects(self) -> list[str]:
        return self.spec.block_names

    @property
    def jittered_objects(self) -> tuple[int, ...]:
        """The blocks (rows 1..n): the tray stands where the task starts, at init."""
        return tuple(range(1, 1 + self.spec.n_blocks))

    def true_properties(self, sizes_variation: bool = False) -> dict:
        """The hidden truth: all blocks `true_size`, or (variation "sizes") one 20 % larger."""
        sizes = np.full(self.spec.n_blocks, self.spec.true_size)
        if sizes_variation:
            sizes[0] *= SIZES_VARIATION_SCALE
        return {"block_sizes": sizes}

    def properties(self, props: dict) -> dict:
        """Validated properties: block_sizes (n,), density, block_masses (n,).

        Idempotent (a validated dict validates to itself), so `build` after `reset`
        keeps a caller's density.
        """
        if not isinstance(props, dict):
            raise PropertyError("properties: expected a mapping with 'block_sizes'")
        return block_properties(props, self.spec.n_blocks, self.spec.density)

    # -- physics ---------------------------------------------------------------------
    def scene_description(self, props: dict) -> SceneDescription:
        p = self.properties(props)
        return scene.scene_description(self.spec, p["block_sizes"], p["block_masses"])

    def initial_configuration(self, props: dict) -> Configuration:
        return state_mapping.initial_configuration(self.spec, self.properties(props)["block_sizes"])

    def place(self, config: Configuration, props: dict) -> Configuration:
        return state_mapping.place_for_sizes(self.spec, config, self.properties(props)["block_sizes"])

    def after_action(self, config: Configuration, action: str) -> Configuration:
        """At goal a helper unloads the container: its blocks count as delivered."""
        name, args = state_mapping.parse_action(action)
        if name != "push" or state_mapping.container_location(self.spec, config) != "goal":
            return config
        labels = state_mapping.block_labels(self.spec, config)
        objects = config.objects.copy()
        for i, label in enumerate(labels):
            if label == state_mapping.CONTAINER:
                xy = self.spec.delivered_slot(i)
                objects[1 + i] = [xy[0], xy[1], objects[1 + i, 2], 0, 0, 0, 1]
        return Configuration(config.robot, objects)

    # -- Y and Y^-1 ------------------------------------------------------------------
    def symbolic_state(self, config: Configuration) -> frozenset[str]:
        return state_mapping.symbolic_state(self.spec, config)

    def action_pose(self, props: dict, config: Configuration, action: str) -> np.ndarray:
        return state_mapping.action_pose(self.spec, self.properties(props)["block_sizes"], config, action)

    def _row_sizes(self, rows: np.ndarray) -> np.ndarray:
        """(N, D) rows of L as (N, n_blocks) sizes: one shared size broadcast to every block."""
        rows = np.asarray(rows, dtype=np.float64)
        return np.broadcast_to(rows, (len(rows), self.spec.n_blocks)) if rows.shape[1] == 1 else rows

    def action_poses(self, rows: np.ndarray, config: Configuration, action: str) -> np.ndarray:
        """Y for every row of L at once ((N, D) -> (N, 5)), bit for bit the per-row Y."""
        sizes = self._row_sizes(rows)
        self.properties({"block_sizes": sizes.min(axis=0)})       # validation, as per row
        self.properties({"block_sizes": sizes.max(axis=0)})
        return state_mapping.action_poses(self.spec, sizes, config, action)

    def misalignment(self, config: Configuration, action: str) -> tuple[int, np.ndarray] | None:
        """A pickup's block and the fingers' closing axis (``blocks.hand.pickup_misalignment``)."""
        return pickup_misalignment(self.spec, config, action, 1)

    def pose_alternatives(self, config: Configuration, action: str, pose: np.ndarray,
                          rows: np.ndarray) -> list[np.ndarray]:
        """A pickup's grasp a quarter turn round when a block is within the fingers' reach
        (``blocks.hand.grasp_alternatives``; the largest believed size bounds the reach)."""
        largest = float(np.max(self._row_sizes(rows))) if len(rows) else 0.0
        return grasp_alternatives(self.spec, config, action, pose, largest, 1)

    def pose_classes(self, rows: np.ndarray, config: Configuration, action: str) -> np.ndarray:
        """The discrete choice Y makes for each row of L ((N, D) -> (N,) ints): for a stack
        the tray's layout (1: two columns, 0: one; ``columns.tray_layout``), for other
        actions none (all 0). The coordinator averages the real pose over one class: the
        mean of a one-column and a two-column placement lands on neither column."""
        name, _ = state_mapping.parse_action(action)
        sizes = self._row_sizes(rows)
        if name != "stack":
            return np.zeros(len(sizes), dtype=np.int64)
        inside = state_mapping.in_tray(state_mapping.block_labels(self.spec, config))
        return np.asarray(columns.tray_layout(self.spec, config, sizes, inside), dtype=np.int64)

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
        """Boxes (centre, half extents, rotation) of the container and every block
        not in the hand, for the motion planner's geometric collision check; `size` is the
        believed block size, one for all or one per block."""
        labels = state_mapping.block_labels(self.spec, config)
        sizes = per_block(size, self.spec.n_blocks)
        ox, oy = self.spec.outer_half
        top = self.spec.floor_thickness + self.spec.wall_height
        boxes = [body_box(config.objects[0], (ox, oy, top / 2), (0.0, 0.0, top / 2))]
        for i, label in enumerate(labels):
            if label not in (state_mapping.HELD, state_mapping.GOAL):
                # As it lies: columns side by side in the tray are 3 mm apart, and a
                # held block goes down beside the other column or a leaning block.
                boxes.append(cube_box(config.objects[1 + i], sizes[i]))
        return boxes

    def pre_pose(self, config: Configuration, action: str, key: np.ndarray) -> np.ndarray:
        holding = any(a.startswith("is_holding") for a in self.symbolic_state(config))
        return trajectories.pre_pose(self.spec, action, key, holding)

    def measurements(self, config: Configuration, log=None, action: str = "") -> np.ndarray:
        """The gripper's finger opening, then planar block positions (x, y per block).

        What a robot measures without knowing sizes: its own gripper width (after a grasp
        it is the block's width, the most informative reading) and a top-down camera's
        block positions. Heights are left out on purpose: a depth reading of a block on
        the table would give its size away and leave nothing to learn.
        """
        return np.concatenate([[config.robot[4]], config.objects[1:, :2].ravel()])

    def measurement_channels(self) -> list[dict]:
        """Every channel: name, index, unit and sigma (None: reported, not weighed): the
        finger opening, then each block's x and y (issue 25: the listing showed the one
        weighed channel while an observation must carry all 17)."""
        return ([{"name": "finger_opening", "index": 0, "unit": "m", "sigma": 0.002}]
                + [{"name": f"{b}_{ax}", "index": 1 + 2 * i + k, "unit": "m", "sigma": None}
                   for i, b in enumerate(self.learned_objects) for k, ax in enumerate("xy")])

    def measurement_model(self) -> tuple[np.ndarray, np.ndarray]:
        """(indices, std) of the measurements the belief's Gaussian likelihood uses.

        Only the finger opening (std 2 mm). Block positions after a push or a fall are
        chaotic: weighting particles by where each block happened to land rewarded noise
        and collapsed the belief onto a wrong size in our runs (42.4 +- 0.08 mm for a
        45 mm truth), so they stay reported but out of the likelihood.
        """
        return np.array([0]), np.array([0.002])

    # -- probe (tmoc probe, T* estimates) --------------------------------------------
    probe_actions = probes.PROBE_ACTIONS

    def probe_trial(self, action: str, true_size: float, believed_size: float, load_k: int,
                    rng: np.random.Generator) -> bool:
        """One seeded trial of `action` in this (already jittered) world."""
        return probes.probe_trial(self, action, true_size, believed_size, load_k, rng)

    t_star_probe_jobs = staticmethod(probes.t_star_probe_jobs)
    t_star_from_probes = staticmethod(probes.true_T_from_probes)

    @staticmethod
    def held_object(state: frozenset[str]) -> str | None:
        return held_block(state)

    def check_action(self, action: str) -> None:
        name, args = state_mapping.parse_action(action)
        if name in ("pickup", "stack"):
            state_mapping.block_index(self.spec, args[1])
        if name == "pickup" and args[2] not in ("init", "table"):
            raise ValueError(f"action: pickup from {args[2]!r} (expected init or table)")
        if name == "push" and not all(re.fullmatch(r"init|goal", a) for a in args[2:4]):
            raise ValueError(f"action: push between {args[2:4]} (expected init/goal)")
