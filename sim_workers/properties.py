"""Validation of the objects' continuous properties L (the particle filter's hypotheses)."""
from __future__ import annotations

from dataclasses import dataclass
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
        raise PropertyError(f"{field}: {x!r} is outside ({low}, {high}]")
    return x


def per_object_property(props: Mapping, name: str, n: int, low: float, high: float) -> np.ndarray:
    """``props[name]`` as (n,) floats within [low, high], from one number for every object or
    one each, where `props` holds that property alone (an L of one property per object, as
    the example domains' friction); PropertyError naming the field otherwise."""
    if not isinstance(props, Mapping) or name not in props:
        raise PropertyError(f"{name}: missing")
    unknown = sorted(set(props) - {name})
    if unknown:
        raise PropertyError(f"{unknown[0]}: unknown property (known: {name})")
    try:
        arr = np.broadcast_to(np.asarray(props[name], dtype=np.float64), (n,))
    except (TypeError, ValueError):
        raise PropertyError(f"{name}: expected one number or {n}") from None
    bad = np.flatnonzero(~np.isfinite(arr) | (arr < low) | (arr > high))
    if bad.size:
        raise PropertyError(f"{name}[{int(bad[0])}]: {float(arr[bad[0]])!r} is outside [{low}, {high}]")
    return arr.copy()


MIN_DENSITY = 1.0          # kg/m^3: below, not a solid block
MAX_DENSITY = 25000.0      # above osmium
# The "sizes" variation of the paper's experiments: block 1 is this much larger than the
# others (every domain's true_properties, the loop's truth row, the experiments' errors).
SIZES_VARIATION_SCALE = 1.2


def validate_density(value, n_blocks: int) -> float | np.ndarray:
    """One density for every block (a float) or one per block ((n,) array), kg/m^3."""
    arr = np.asarray(value, dtype=np.float64) if not isinstance(value, str) else None
    if arr is None or arr.ndim == 0:
        return validate_positive(value, "density", MIN_DENSITY, MAX_DENSITY)
    if arr.shape != (n_blocks,):
        raise PropertyError(f"density: expected one value or {n_blocks}, got shape {arr.shape}")
    for i, v in enumerate(arr):
        validate_positive(v, f"density[{i}]", MIN_DENSITY, MAX_DENSITY)
    return arr.copy()


@dataclass(frozen=True)
class PropertySpace:
    """L as data: the names, units, uniform prior and default truth of each unknown
    property. A row of L is property-major: one value per property (every block alike) or
    one per block per property (``per_block``): sizes of b1..bn, then densities of b1..bn."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    truth: tuple[float, ...]

    def dims(self, n_blocks: int, per_block: bool) -> int:
        return len(self.names) * (n_blocks if per_block else 1)

    def bounds(self, n_blocks: int, per_block: bool) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) of a row."""
        k = n_blocks if per_block else 1
        return np.repeat(self.low, k).astype(np.float64), np.repeat(self.high, k).astype(np.float64)

    def split(self, row, n_blocks: int) -> dict[str, np.ndarray]:
        """A row as {name: (n_blocks,) values}; PropertyError unless its length is one
        value per property or one per block per property."""
        row = np.asarray(row, dtype=np.float64).reshape(-1)
        p = len(self.names)
        if row.size == p:
            return {name: np.full(n_blocks, row[j]) for j, name in enumerate(self.names)}
        if row.size == p * n_blocks:
            return {name: row[j * n_blocks:(j + 1) * n_blocks].copy() for j, name in enumerate(self.names)}
        raise PropertyError(f"L: a row of {row.size} values; expected {p} ({', '.join(self.names)}) "
                            f"or {p * n_blocks} (one per block per property)")

    def truth_row(self, truth: Mapping[str, float], n_blocks: int, per_block: bool,
                  first_block_scale: Mapping[str, float] | None = None) -> np.ndarray:
        """The hidden truth as a row: `truth` by name over the defaults (a name L does not
        have raises PropertyError naming it); with `per_block`, block 1 of each property is
        scaled by `first_block_scale` (the "sizes" variation)."""
        unknown = sorted(set(truth) - set(self.names))
        if unknown:
            raise PropertyError(f"truth.{unknown[0]}: not a property of L "
                                f"(properties: {', '.join(self.names)})")
        values = [float(truth.get(n, t)) for n, t in zip(self.names, self.truth)]
        for name, v in zip(self.names, values):
            validate_positive(v, f"truth.{name}", 0.0, np.inf)
        if not per_block:
            return np.array(values)
        cols = []
        for name, v in zip(self.names, values):
            block = np.full(n_blocks, v)
            block[0] *= (first_block_scale or {}).get(name, 1.0)
            cols.append(block)
        return np.concatenate(cols)


# The names a caller may pass for blocks. `block_masses` is derived (density x size^3) and
# accepted back only when it agrees, so that a validated dict can be validated again
# without losing anything (it once lost `density`: 7800 kg/m^3 built 700 kg/m^3 blocks).
BLOCK_PROPERTY_NAMES = ("block_sizes", "density", "block_masses")


class ValidatedProperties(dict):
    """Properties ``block_properties`` has checked for `n_blocks` objects: validated once,
    they pass through it again as they are (a particle-action hands them to place, build
    and Y, each of which validates what it is given)."""

    def __init__(self, values: dict, n_blocks: int) -> None:
        super().__init__(values)
        self.n_blocks = int(n_blocks)

    def __reduce__(self):
        return (ValidatedProperties, (dict(self), self.n_blocks))


def block_properties(props: Mapping, n_blocks: int, default_density: float) -> dict:
    """Validated {block_sizes (n,), density, block_masses (n,)} from a property mapping.

    Every key either reaches the physics or is refused by name: an unknown key, or a
    `block_masses` that disagrees with `density` x `block_sizes`^3, raises PropertyError.
    A mapping this returned is returned as it is.
    """
    if type(props) is ValidatedProperties and props.n_blocks == n_blocks:
        return props
    if "block_sizes" not in props:
        raise PropertyError("block_sizes: missing")
    unknown = sorted(str(k) for k in props if k not in BLOCK_PROPERTY_NAMES)
    if unknown:
        raise PropertyError(f"{unknown[0]}: unknown property (known: block_sizes, density)")
    sizes = validate_sizes(props["block_sizes"], n_blocks)
    density = validate_density(props.get("density", default_density), n_blocks)
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
    return ValidatedProperties({"block_sizes": sizes, "density": density, "block_masses": masses}, n_blocks)
