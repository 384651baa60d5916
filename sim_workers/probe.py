"""Seeded physics trials of one action: does Y with a believed size work in a true world?

Each trial perturbs the true world (block placement by a few mm, friction by about 10 %)
from the seeded generator, takes the action's poses from Y with the believed size, runs the
action in a grounded world and reads the outcome through Y^-1.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .configuration import Configuration, quat_from_yaw
from .domains import load
from .grounded_world import GroundedWorld

PLACEMENT_JITTER_M = 0.002   # std of block placement, clipped at 2 std
YAW_JITTER_RAD = 0.05
FRICTION_JITTER = 0.10       # relative, uniform


@dataclass(frozen=True)
class ProbeResult:
    action: str
    trials: int
    successes: int
    true_size: float
    believed_size: float
    load: int

    @property
    def success_rate(self) -> float:
        return self.successes / self.trials if self.trials else 0.0

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "success_rate": self.success_rate}


def jittered_domain(rng: np.random.Generator, friction: float = FRICTION_JITTER,
                    domain: str = "container", **options):
    """`domain` with every friction coefficient (spec fields mu_*) scaled by U(1 +- friction)."""
    base = load(domain, **options)
    mus = {f.name: getattr(base.spec, f.name) * rng.uniform(1 - friction, 1 + friction)
           for f in dataclasses.fields(base.spec) if f.name.startswith("mu_")}
    return load(domain, **{**options, **mus})


def jitter_planar(rng: np.random.Generator, objects: np.ndarray, rows,
                  placement_m: float = PLACEMENT_JITTER_M, yaw_rad: float = YAW_JITTER_RAD) -> np.ndarray:
    """Objects `rows` moved by N(0, placement) clipped at 2 std, and turned by U(+-yaw)."""
    objects = objects.copy()
    for i in rows:
        objects[i, :2] += np.clip(rng.normal(0, placement_m, 2), -2 * placement_m, 2 * placement_m)
        objects[i, 3:] = quat_from_yaw(rng.uniform(-yaw_rad, yaw_rad))
    return objects


def loaded_configuration(domain, sizes: np.ndarray, load_k: int, rng: np.random.Generator) -> Configuration:
    """The first `load_k` blocks piled in the container, two side by side per layer."""
    spec = domain.spec
    config = domain.initial_configuration({"block_sizes": sizes})
    objects = jitter_planar(rng, config.objects, range(1, 1 + spec.n_blocks))
    c = objects[0, :2]
    for i in range(load_k):
        s = sizes[i]
        lx = (1 if i % 2 else -1) * (s / 2 + spec.slot_gap / 2)
        # Heights only order the pile (place() re-stacks each column from the floor).
        z = spec.floor_top + (i // 2 + 0.5) * s
        objects[1 + i, :3] = [c[0] + lx + rng.normal(0, PLACEMENT_JITTER_M / 2),
                              c[1] + rng.normal(0, PLACEMENT_JITTER_M / 2), z]
        objects[1 + i, 3:] = quat_from_yaw(rng.uniform(-YAW_JITTER_RAD, YAW_JITTER_RAD))
    return domain.place(Configuration(config.robot, objects), {"block_sizes": sizes})


def _act(world: GroundedWorld, domain, config, believed: dict, action: str):
    key = domain.action_pose(believed, config, action)
    traj = domain.action_trajectory(config, action, key)
    # The transit to the pre-pose is free space: skip it.
    return world.execute(traj, action, start_time=domain.transit_end_time(config, action, key))


def run_trial(action: str, true_size: float, believed_size: float, load_k: int,
              rng: np.random.Generator, n_blocks: int = 8, options: dict | None = None) -> bool:
    """One seeded trial; True when the action had its intended symbolic effect."""
    domain = jittered_domain(rng, n_blocks=n_blocks, **(options or {}))
    sizes = np.full(n_blocks, true_size)
    truth = {"block_sizes": sizes}
    believed = {"block_sizes": np.full(n_blocks, believed_size)}
    with GroundedWorld(domain) as world:
        if action == "push":
            config = world.reset(loaded_configuration(domain, sizes, load_k, rng), truth)
            out = _act(world, domain, config, believed, "push(r,c,init,goal)")
            return all(f"is_in(b{i + 1},goal)" in out.state for i in range(load_k))
        config = domain.initial_configuration(truth)
        config = Configuration(config.robot, jitter_planar(rng, config.objects, range(1, 1 + n_blocks)))
        config = world.reset(config, truth)
        if action == "pickup":
            b = f"b{int(rng.integers(n_blocks)) + 1}"
            out = _act(world, domain, config, believed, f"pickup(r,{b},init)")
            return f"is_holding(r,{b})" in out.state
        for i in range(load_k):                    # stack: pick and place the first k blocks
            b = f"b{i + 1}"
            out = _act(world, domain, config, believed, f"pickup(r,{b},init)")
            if f"is_holding(r,{b})" not in out.state:
                return False
            out = _act(world, domain, out.configuration, believed, f"stack(r,{b},c)")
            config = out.configuration
        return all(f"at_container(b{i + 1},c)" in out.state for i in range(load_k)) \
            and "hand_empty(r)" in out.state


def probe(action: str, true_size: float, believed_size: float | None = None, load_k: int = 4,
          trials: int = 20, seed: int = 0, n_blocks: int = 8, options: dict | None = None) -> ProbeResult:
    """Run `trials` seeded trials of `action` (pickup | stack | push)."""
    if action not in ("pickup", "stack", "push"):
        raise ValueError(f"action: {action!r} is not one of pickup, stack, push")
    believed = true_size if believed_size is None else believed_size
    if not 1 <= load_k <= n_blocks:
        raise ValueError(f"load: {load_k} is outside [1, {n_blocks}]")
    # One child generator per trial: trial t's outcome does not depend on the trial count.
    children = np.random.default_rng(seed).spawn(trials)
    wins = sum(run_trial(action, true_size, believed, load_k, rng, n_blocks, options) for rng in children)
    return ProbeResult(action, trials, int(wins), float(true_size), float(believed), int(load_k))
