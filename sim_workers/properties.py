"""Validation of the objects' continuous properties L (the particle filter's hypotheses)."""
from __future__ import annotations

from typing import Mapping

import numpy as np

# Outside these a hypothesis is not a block the gripper could ever hold: refuse it loudly.
MIN_SIZE_M = 0.01
MAX_SIZE_M = 0.10


class PropertyError(ValueError):
    """A property value is missing, non-finite or out of range; the message names the field."""


def validate_sizes(sizes, n_blocks: int, field: str = "block_sizes") -> np.ndarray:
    """Return `sizes` as a float64 array of shape (n_blocks,), or raise PropertyError."""
    try:
        arr = np.asarray(sizes, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PropertyError(f"{field}: not a list of numbers ({exc})") from None
    if arr.ndim == 0:
        arr = np.full(n_blocks, float(arr))
    if arr.shape != (n_blocks,):
        raise PropertyError(f"{field}: expected {n_blocks} sizes, got shape {arr.shape}")
    bad = ~np.isfinite(arr)
    if bad.any():
        raise PropertyError(f"{field}[{int(np.flatnonzero(bad)[0])}]: not a finite number")
    low = arr < MIN_SIZE_M
    high = arr > MAX_SIZE_M
    if low.any() or high.any():
        i = int(np.flatnonzero(low | high)[0])
        raise PropertyError(
            f"{field}[{i}]: {float(arr[i])!r} m is outside [{MIN_SIZE_M}, {MAX_SIZE_M}] m")
    return arr


def validate_positive(value, field: str, low: float = 0.0, high: float = np.inf) -> float:
    """A finite scalar in (low, high]; raise PropertyError naming `field` otherwise."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PropertyError(f"{field}: {value!r} is not a number") from None
    if not np.isfinite(x) or not (low < x <= high):
        raise PropertyError(f"{field}: {value!r} is outside ({low}, {high}]")
    return x


# The names a caller may pass for blocks. `block_masses` is derived (density x size^3) and
# accepted back only when it agrees, so that a validated dict can be validated again
# without losing anything (it once lost `density`: 7800 kg/m^3 built 700 kg/m^3 blocks).
BLOCK_PROPERTY_NAMES = ("block_sizes", "density", "block_masses")


def block_properties(props: Mapping, n_blocks: int, default_density: float) -> dict:
    """Validated {block_sizes (n,), density, block_masses (n,)} from a property mapping.

    Every key either reaches the physics or is refused by name: an unknown key, or a
    `block_masses` that disagrees with `density` x `block_sizes`^3, raises PropertyError.
    """
    if "block_sizes" not in props:
        raise PropertyError("block_sizes: missing")
    unknown = sorted(str(k) for k in props if k not in BLOCK_PROPERTY_NAMES)
    if unknown:
        raise PropertyError(f"{unknown[0]}: unknown property (known: block_sizes, density)")
    sizes = validate_sizes(props["block_sizes"], n_blocks)
    density = validate_positive(props.get("density", default_density), "density", 1.0, 25000.0)
    masses = density * sizes ** 3
    if "block_masses" in props:
        try:
            given = np.asarray(props["block_masses"], dtype=np.float64)
            agrees = given.shape == masses.shape and np.allclose(given, masses, rtol=1e-9, atol=0.0)
        except (TypeError, ValueError):
            agrees = False
        if not agrees:
            raise PropertyError("block_masses: derived from density x block_sizes^3; "
                                "set density instead")
    return {"block_sizes": sizes, "density": density, "block_masses": masses}
