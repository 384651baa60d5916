"""The tray's column layout: where Y piles blocks under one hypothesis of their sizes.

An empty tray is filled by the rule (``two_columns``): two columns side by side along the
tray's x axis when every block of the hypothesis fits in half the tray beside half the
slot gap, else one column on the tray's centre line. With the default tray (inner half
50 mm, slot gap 3 mm) the rule gives two columns up to 48.5 mm. The gap is the physics'
(issue 40, measured): a block carried to the tray slides about 2 mm forward in the fingers
as the carry stops, so the first column lands that far in from its wall, and above 48.5 mm
the second column's block comes down on the first one's edge and wedges there (49 and
49.5 mm in the unjittered world). Such a pile still counts as stacked and travels when
low, so two columns of 49 mm blocks are not infeasible, only costly to learn: with the rule
at 50 mm (tried, docs/RESULTS.md) a run at a hidden 49.0 mm scored 35, -30, -40, -100,
then 110, 110 (two trips of four), and the learning grid's first 49.3 mm run lost 7
actions in 4 episodes (stacks onto the third layer, pushes of five, which the worlds'
square piles carried) against 1 with one column.

A tray that holds blocks keeps the layout it has (``tray_layout``): the pile the robot
built is what it is, whatever the hypothesis' rule would have built. Blocks on the centre
line are a one-column pile under every hypothesis; blocks beside it, a two-column pile
under every hypothesis whose blocks fit side by side in the tray at all (up to 50 mm,
``side_by_side``), each against its wall above 48.5 mm (``column_x``). So a world on the
other side of the rule's threshold from the belief re-grounds the robot's pile as the robot
built it, instead of as a pile it never was (a two-column pile as one tower of offset
blocks, which a push topples in that world and not in reality: the belief then left the
truth, 7.9 std at 49.3 mm; issue 40), and Y puts the next block on the pile there is. Y
(``action_pose``), its vectorised form (``action_poses``) and the re-grounding
(``place_for_sizes``) agree on the layout.
"""
from __future__ import annotations

import math

import numpy as np

from ..configuration import Configuration, rotate_z, yaw_of
from .spec import ContainerSpec

LEFT, RIGHT = 0, 1


def _fits_half(spec: ContainerSpec, sizes: np.ndarray, gap: float) -> bool | np.ndarray:
    """Whether each hypothesis' largest block beside half of `gap` fits in half the tray."""
    fits = np.max(np.asarray(sizes, dtype=np.float64), axis=-1) + gap / 2 <= spec.inner_half[0]
    return bool(fits) if np.ndim(fits) == 0 else fits


def two_columns(spec: ContainerSpec, sizes: np.ndarray) -> bool | np.ndarray:
    """Whether a hypothesis piles an empty tray in two columns: its largest block beside
    the slot gap fits in half the tray. (n,) sizes -> bool; (N, n) -> (N,) bools, one per
    hypothesis."""
    return _fits_half(spec, sizes, spec.slot_gap)


def side_by_side(spec: ContainerSpec, sizes: np.ndarray) -> bool | np.ndarray:
    """Whether a hypothesis' blocks can lie in two columns at all: its largest block fits in
    half the tray (no gap). (n,) sizes -> bool; (N, n) -> (N,) bools."""
    return _fits_half(spec, sizes, 0.0)


def tray_layout(spec: ContainerSpec, config: Configuration, sizes: np.ndarray,
                inside: list[int]) -> bool | np.ndarray:
    """The layout under each hypothesis of a tray holding blocks `inside` (0-based block
    indices): one column where every one of them lies on the centre line; two where some
    lie beside it and the hypothesis' blocks fit side by side (``side_by_side``), else one;
    the rule (``two_columns``) for an empty tray. (n,) sizes -> bool; (N, n) -> (N,) bools.

    A block lies on the centre line under a hypothesis when its centre is at most s / 4 off
    it (s its size there): halfway between where one column puts it (on the line) and the
    nearest two columns do (s / 2 off), 3.75 sigma of the camera's 2 mm at the prior's
    smallest block."""
    sz = np.asarray(sizes, dtype=np.float64)
    if not inside:
        return two_columns(spec, sz)
    off = np.abs([tray_x(config, config.objects[1 + j]) for j in inside])
    beside = np.any(off > sz[..., inside] / 4, axis=-1)
    out = beside & side_by_side(spec, sz)
    return bool(out) if np.ndim(out) == 0 else out


def tray_x(config: Configuration, p: np.ndarray) -> float:
    """A point's x in the tray's frame (along the axis its columns stand side by side on)."""
    c = config.objects[0]
    return float(rotate_z(p[:2] - c[:2], -yaw_of(c[3:]))[0])


def side_of(config: Configuration, p: np.ndarray) -> int:
    """The half of the tray (along its x axis) a point is in: LEFT or RIGHT."""
    return RIGHT if tray_x(config, p) > 0 else LEFT


def column_of(config: Configuration, p: np.ndarray, two: bool) -> int:
    """The column a block at `p` counts in: its half of the tray, or the only column."""
    return side_of(config, p) if two else LEFT


def column_x(spec: ContainerSpec, s: float | np.ndarray, col: int | np.ndarray,
             two: bool | np.ndarray) -> np.ndarray:
    """The tray-frame x of the centre of a block of size `s` stacked in column `col`
    (scalars or arrays alike): beside the centre line with half the slot gap, or on it.
    A block too large for that (over 48.5 mm in the default tray: a world re-grounding the
    robot's two-column pile, ``tray_layout``) goes against the wall, with what room is left
    between the columns."""
    off = np.minimum(s / 2 + spec.slot_gap / 2, spec.inner_half[0] - s / 2)
    return np.where(two, np.where(col == RIGHT, 1.0, -1.0) * off, 0.0)


def tallest_pile(spec: ContainerSpec) -> float:
    """The tallest pile Y can build over the prior: every block of the largest prior size,
    in as many columns as that size gets (one, in the default tray)."""
    columns = 2 if two_columns(spec, np.array([spec.prior_high])) else 1
    return spec.prior_high * math.ceil(spec.n_blocks / columns)
