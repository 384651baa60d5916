"""The tray's column layout: where Y piles blocks under one hypothesis of their sizes.

Blocks go in two columns side by side along the tray's x axis when every block of the
hypothesis fits in half the tray, else in one column on the tray's centre line. The
layout depends on all of the hypothesis' sizes (not on the block in hand), so it does not
change during an episode, and Y (``action_pose``), its vectorised form (``action_poses``)
and the re-grounding (``place_for_sizes``) agree on it. With the default tray (inner half
50 mm, slot gap 3 mm) two columns hold blocks up to 48.5 mm.
"""
from __future__ import annotations

import math

import numpy as np

from ..configuration import Configuration, rotate_z, yaw_of
from .spec import ContainerSpec

LEFT, RIGHT = 0, 1


def two_columns(spec: ContainerSpec, sizes: np.ndarray) -> bool | np.ndarray:
    """Whether a hypothesis piles in two columns: its largest block beside the slot gap
    fits in half the tray. (n,) sizes -> bool; (N, n) -> (N,) bools, one per hypothesis."""
    fits = np.max(np.asarray(sizes, dtype=np.float64), axis=-1) + spec.slot_gap / 2 <= spec.inner_half[0]
    return bool(fits) if np.ndim(fits) == 0 else fits


def side_of(config: Configuration, p: np.ndarray) -> int:
    """The half of the tray (along its x axis) a point is in: LEFT or RIGHT."""
    c = config.objects[0]
    return RIGHT if rotate_z(p[:2] - c[:2], -yaw_of(c[3:]))[0] > 0 else LEFT


def column_of(config: Configuration, p: np.ndarray, two: bool) -> int:
    """The column a block at `p` counts in: its half of the tray, or the only column."""
    return side_of(config, p) if two else LEFT


def column_x(spec: ContainerSpec, s: float | np.ndarray, col: int | np.ndarray,
             two: bool | np.ndarray) -> np.ndarray:
    """The tray-frame x of the centre of a block of size `s` stacked in column `col`
    (scalars or arrays alike): beside the centre line with half the slot gap, or on it."""
    return np.where(two, np.where(col == RIGHT, 1.0, -1.0) * (s / 2 + spec.slot_gap / 2), 0.0)


def tallest_pile(spec: ContainerSpec) -> float:
    """The tallest pile Y can build over the prior: every block of the largest prior size,
    in as many columns as that size gets (one, in the default tray)."""
    columns = 2 if two_columns(spec, np.array([spec.prior_high])) else 1
    return spec.prior_high * math.ceil(spec.n_blocks / columns)
