"""The stack-and-push scene as data: rail, supply row, start site, goal area, gripper,
physics settings (docs/BUILTIN_DOMAINS.md)."""
from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class StackAndPushSpec:
    """Everything fixed about the scene; the unknown block sizes are not here (they are L)."""

    n_blocks: int = 8
    # Blocks: the truth the agent does not know, and its prior.
    true_size: float = 0.045
    prior_low: float = 0.030
    prior_high: float = 0.060
    density: float = 700.0          # kg/m^3: known to the agent (wood), or the default truth
    # Weight as an unknown (issue 14): L = (size, density) with a uniform density prior,
    # learned from the wrist force while a block is held.
    unknown_density: bool = False
    density_low: float = 300.0      # kg/m^3, the prior (cork-ish to ceramic)
    density_high: float = 3000.0
    # Noise (N) of the held-weight channel; None: reported, weighed only when the density
    # is unknown (then 0.1 N, an external wrist F/T sensor; a UR5e's built-in one is ~3.5 N).
    force_sigma: float | None = None
    weigh_s: float = 0.25           # the held weight is the mean over the lift's last 0.25 s
    # Mass in Y (issue 14): the grip force and the push's force limit come from the
    # believed mass (sim_workers/stack_and_push/efforts.py). None: on exactly when the
    # density is unknown, so runs with a known density keep their calibrated physics.
    force_from_mass: bool | None = None
    grip_safety: float = 2.5        # grip = safety x (believed weight) / (2 mu_finger-block)
    push_safety: float = 1.25       # push limit = gripper inertia + safety x tower (a + mu g)
    push_accel_ref: float = 8.0     # m/s^2, the force-limited stroke's reference speed-up
    # Supply row beside the rail (y < 0), one slot per block along x.
    init_row_x: float = -0.10
    init_row_y: float = -0.14
    row_pitch: float = 0.075
    # The rail: two low walls along x; its floor is the table (z = 0).
    rail_x: tuple[float, float] = (-0.10, 0.80)
    rail_gap: float = 0.075         # inner width: the largest prior block plus clearance
    wall_height: float = 0.010      # low, so fingers closing across y clear it
    wall_thickness: float = 0.010
    start_x: float = 0.0            # the start site (tower base) on the rail centre line
    goal_x: tuple[float, float] = (0.45, 0.75)
    goal_centre_x: float = 0.55     # where a push carries the tower's base centre
    delivered_x: float = 1.05       # the helper puts delivered blocks in a row here
    # Gripper: the container's floating parallel gripper (same geometry and limits).
    palm_half: tuple[float, float, float] = (0.006, 0.055, 0.010)
    finger_half: tuple[float, float, float] = (0.012, 0.005, 0.030)
    max_opening: float = 0.09
    grip_force: float = 5.0         # N per finger
    finger_speed: float = 0.15      # m/s
    base_max_force: float = 40.0    # N, the constraint that carries the floating base
    # Friction (Bullet multiplies the two bodies' coefficients). The rail floor is the
    # table: block-floor 0.8 * 0.5 = 0.40 at the nominal values.
    mu_table: float = 0.5
    mu_rail: float = 0.3            # the walls: block-wall 0.24, a smooth guide
    mu_block: float = 0.8           # block-block 0.64
    mu_finger: float = 1.5          # finger-block 1.20
    # Physics. The container's 1/120 s step, but 100 solver iterations: at 50 a lone,
    # perfectly aligned tower of eight 30-45 mm cubes creeps sideways and falls within
    # 3 s (drift of the stacked contacts); at 100 it stands 6 s within 3 mm (measured).
    time_step: float = 1.0 / 120.0
    solver_iterations: int = 100
    friction_anchor: bool = True    # Bullet's positional friction on the blocks (no creep)
    # Y's rules in terms of the believed size s.
    open_ratio: float = 1.15
    # ... widened to s + 2 grasp_clearance where the other objects leave the fingers room
    # (sim_workers.blocks.hand.grasp_opening: the perception error a grasp tolerates); 0: off.
    # 6 mm: 3 sigma of the camera the simulated reality declares (2 mm per axis), so a
    # pickup holds an error along the closing axis up to about 7.5 mm (measured +-6 mm at
    # 45 mm in 1 mm steps); docs/BUILTIN_DOMAINS.md has the probes and the learning runs.
    grasp_clearance: float = 0.006
    grip_depth: float = 0.010       # the least depth: fingertips this far below the believed top
    grip_depth_ratio: float = 1.0 / 3.0   # ... or this share of the believed size if deeper
    release_clearance: float = 0.004
    approach_height: float = 0.08
    carry_height: float = 0.20      # the minimum; stacks go higher (tower top + block + margin)
    carry_margin: float = 0.05
    push_tip_z: float = 0.008
    push_gap: float = 0.004         # pusher face behind the tower's rearmost believed face
    # Push with the front finger of the open gripper turned a quarter round (issue 41): an
    # arm's wrist, on the tool's axis 0.10-0.15 m above the fingertips, then stays 9 mm behind
    # the pushing face instead of standing 33 mm inside a tower taller than 10 cm. Runs with
    # an arm set it (RunConfig); the floating gripper pushes with closed fingers.
    push_open: bool = False
    push_speed: float = 0.30        # m/s, stroke cruise speed (probe-tuned, see probes.py)
    push_accel: float = 2.0         # m/s^2, speeding up
    push_decel: float = 2.0         # m/s^2, slowing down at the goal
    # A real arm runs each push U(1 +- this) times faster or slower than planned (so its
    # accelerations and a force-limited stroke's limit by the square): the simulated
    # reality and the probes do (sim_workers.reality_gap.executed), Y and the particle
    # worlds plan the nominal stroke. It grades the push's success by tower height at
    # every size of the prior (issue 24; measured in docs/EXPERIMENTS.md "Learning across the prior").
    push_time_jitter: float = 0.30
    move_speed: float = 0.30
    approach_speed: float = 0.10    # m/s, the last 8 cm down to a grasp or release
    lift_speed: float = 0.30
    settle_s: float = 1.0           # at most this long after the trajectory (stops at rest)

    @property
    def object_names(self) -> list[str]:
        return self.block_names

    @property
    def block_names(self) -> list[str]:
        return [f"b{i + 1}" for i in range(self.n_blocks)]

    @property
    def finger_length(self) -> float:
        return 2.0 * self.finger_half[2]

    @property
    def push_reach(self) -> float:
        """How far ahead of the tool point the pushing face is: the closed fingers' half
        width, or the open front finger's outer face."""
        return self.max_opening / 2 + 2 * self.finger_half[1] if self.push_open else self.finger_half[0]

    @property
    def push_yaw(self) -> float:
        """The gripper's yaw for a push: a quarter round when the open fingers push (their
        opening then lies along the rail)."""
        return 0.5 * math.pi if self.push_open else 0.0

    @property
    def palm_offset(self) -> float:
        """Height of the palm centre above the fingertips."""
        return self.finger_length + self.palm_half[2]

    @property
    def rail_half_gap(self) -> float:
        return self.rail_gap / 2.0

    def init_slot(self, i: int) -> np.ndarray:
        """Nominal (x, y) of block i (0-based) in the supply row."""
        return np.array([self.init_row_x + self.row_pitch * i, self.init_row_y])

    def delivered_slot(self, i: int) -> np.ndarray:
        return np.array([self.delivered_x, (i - (self.n_blocks - 1) / 2.0) * self.row_pitch])

    def start_xy(self) -> np.ndarray:
        return np.array([self.start_x, 0.0])

    def max_tower_top(self) -> float:
        """The highest a tower of every block at the prior's largest size reaches."""
        return self.n_blocks * self.prior_high
