"""The container domain's scene as data: geometry, physics settings, locations (docs/BUILTIN_DOMAINS.md, "The container domain")."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np


@dataclass(frozen=True)
class ContainerSpec:
    """Everything fixed about the scene; the unknown block sizes are not here (they are L)."""

    n_blocks: int = 8
    # Blocks: the truth the agent does not know, and its prior.
    true_size: float = 0.045
    prior_low: float = 0.030
    prior_high: float = 0.060
    density: float = 700.0          # kg/m^3, known to the agent (wood)
    # Where things are (metres). z up, table at z = 0.
    init_row_x: float = -0.20
    row_pitch: float = 0.075
    container_init: tuple[float, float] = (0.0, 0.0)
    container_goal: tuple[float, float] = (0.6, 0.0)
    delivered_x: float = 0.95       # the helper unloads delivered blocks into a row here
    # The open container (tray): its inner footprint takes two blocks side by side along x
    # up to 48.5 mm (inner_half[0] - slot_gap / 2), larger ones in one column (columns.py).
    inner_half: tuple[float, float] = (0.050, 0.036)
    wall_thickness: float = 0.006
    wall_height: float = 0.035      # above the floor
    floor_thickness: float = 0.006
    container_mass: float = 0.30
    # Gripper: palm, two prismatic fingers; pose = fingertip centre (tool point).
    # The palm is narrower (12 mm) than any block: a block toppling off a pushed pile slides
    # off the wrist instead of riding on it for the rest of the episode.
    palm_half: tuple[float, float, float] = (0.006, 0.055, 0.010)
    finger_half: tuple[float, float, float] = (0.012, 0.005, 0.030)
    max_opening: float = 0.09
    grip_force: float = 5.0         # N per finger; more overpowers 20 solver iterations (measured)
    finger_speed: float = 0.15      # m/s
    base_max_force: float = 40.0    # N, the constraint that carries the floating base
    # Friction (Bullet multiplies the two bodies' coefficients).
    mu_table: float = 0.5
    mu_container: float = 0.6       # container-table 0.30
    mu_block: float = 0.8           # block-table 0.40, block-block 0.64
    mu_finger: float = 1.5          # finger-block 1.20
    # Physics: chosen by measurement (benchmarks/bench_worlds.py).
    time_step: float = 1.0 / 120.0
    # 50 iterations: at 20 a gripper landing on a block drives it into the table (the
    # fingers should stop on its top); at 1/60 s blocks sink into the table at any count.
    solver_iterations: int = 50
    # Y's grasp rules, in terms of the believed size s: pre-grasp opening = open_ratio * s,
    # fingertips max(grip_depth, grip_depth_ratio * s) below the believed top
    # (sim_workers.blocks.hand.grip_depth says why the grip deepens with the size).
    open_ratio: float = 1.15
    # ... widened to s + 2 grasp_clearance where the other objects leave the fingers room
    # (sim_workers.blocks.hand.grasp_opening: the perception error a grasp tolerates); 0: off.
    # 6 mm: 3 sigma of the simulated reality's 2 mm camera (docs/LOOP.md, "Y's grasp clearance").
    grasp_clearance: float = 0.006
    grip_depth: float = 0.010       # the least depth: fingertips this far below the believed top
    grip_depth_ratio: float = 1.0 / 3.0   # ... or this share of the believed size if deeper
    release_clearance: float = 0.006
    slot_gap: float = 0.003
    approach_height: float = 0.08
    carry_height: float = 0.20
    push_tip_z: float = 0.008
    push_opening: float = 0.05
    # Push with the front finger of the open gripper turned a quarter round (issue 41): an
    # arm's wrist, on the tool's axis 0.10-0.15 m above the fingertips, then stays behind the
    # pushing face instead of over the tray's wall. Runs with an arm set it (RunConfig).
    push_open: bool = False
    push_speed: float = 0.50       # a brisk stroke: tall piles topple, low loads ride (probe-tuned)
    push_accel: float = 8.0
    move_speed: float = 0.30
    approach_speed: float = 0.20    # m/s, the last 8 cm down to a grasp or release
    lift_speed: float = 0.30        # m/s, up and away once the fingers have acted
    settle_s: float = 0.5           # at most this long after the trajectory (stops at rest)

    # Thresholds of Y^-1 and margins of the action skeletons (metres, seconds): the domain's
    # data, named here. ClassVar, not fields: they are not options a run may set.
    CONTAINER_XY_MARGIN: ClassVar[float] = 0.004    # a block this far past the inner walls is in
    CONTAINER_TOP_MARGIN: ClassVar[float] = 0.01    # above the tallest possible pile: not in
    GOAL_BAND: ClassVar[float] = 0.1                # past delivered_x minus this: delivered
    INIT_RADIUS: ClassVar[float] = 0.02             # this close to its start slot: at init
    MIN_GRASP_Z: ClassVar[float] = 0.003            # fingertips never lower than this
    PUSH_CLEARANCE: ClassVar[float] = 0.012         # fingers this far behind the outer wall
    START_OPENING_MARGIN: ClassVar[float] = 0.005   # the start opening: max_opening minus this
    PUSH_PRE_HEIGHT: ClassVar[float] = 0.12         # a push's pre-pose above its key pose
    GRIP_DWELL_S: ClassVar[float] = 0.3             # after closing: let the grip settle
    RELEASE_DWELL_S: ClassVar[float] = 0.2          # after opening: let the block settle
    STACK_LEAVE_CLEARANCE: ClassVar[float] = 0.10   # leave a stack at least this far up
    PUSH_BACK_OFF: ClassVar[float] = 0.03           # after a stroke, back off this far

    @property
    def object_names(self) -> list[str]:
        return ["c"] + self.block_names

    @property
    def block_names(self) -> list[str]:
        return [f"b{i + 1}" for i in range(self.n_blocks)]

    @property
    def floor_top(self) -> float:
        return self.floor_thickness

    @property
    def outer_half(self) -> tuple[float, float]:
        return (self.inner_half[0] + self.wall_thickness, self.inner_half[1] + self.wall_thickness)

    @property
    def finger_length(self) -> float:
        return 2.0 * self.finger_half[2]

    @property
    def palm_offset(self) -> float:
        """Height of the palm centre above the fingertips."""
        return self.finger_length + self.palm_half[2]

    def init_slot(self, i: int) -> np.ndarray:
        """Nominal (x, y) of block i (0-based) in the start row."""
        return np.array([self.init_row_x, (i - (self.n_blocks - 1) / 2.0) * self.row_pitch])

    def delivered_slot(self, i: int) -> np.ndarray:
        return np.array([self.delivered_x, (i - (self.n_blocks - 1) / 2.0) * self.row_pitch])

    def location_xy(self, name: str) -> np.ndarray:
        return np.array(self.container_goal if name == "goal" else self.container_init)
