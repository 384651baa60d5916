"""Stack-and-push probe trials (``tmoc probe --domain stack_and_push``): how each action
kind is set up in a true world and judged through Y^-1.

``load_k`` is the tower height: the blocks already stacked before a probed ``stack``, the
tower pushed by ``push``, the tower left alone by ``stand``. Every tower block is placed
with the same jitter as the supply row (``PLACEMENT_JITTER_M``, ``YAW_JITTER_RAD``), so a
tall tower is a little crooked, as a stacked one is; with the friction jitter of
``sim_workers.reality_gap.jittered_domain`` that is what grades the push curve.
"""
from __future__ import annotations

import numpy as np

from ..configuration import Configuration, quat_from_yaw
from ..engines.registry import make_world
from ..grounded_world import GroundedWorld, act
from ..reality_gap import PLACEMENT_JITTER_M, YAW_JITTER_RAD, action_jitter, executed, jitter_planar

PROBE_ACTIONS = ("pickup", "stack", "push", "stand", "built_stack", "built_push", "rail_pickup")
# `rail_pickup`: a block lying on the rail, where a topple or a failed push leaves blocks,
# somewhere between the start site and the goal and turned by up to this much
RAIL_PICKUP_X = (0.10, 0.35)
RAIL_PICKUP_YAW = 0.35
RAIL_NEIGHBOURS = 2      # at most, beside it along the rail
STAND_S = 2.0            # how long a tower is left alone in the `stand` probe
TOWER_JITTER_M = PLACEMENT_JITTER_M / 2
# `built_*` probes build their tower with the agent's own actions; a build that fails
# (rare with Y at the truth) is started again from a fresh supply row this many times.
BUILD_TRIES = 3


def truth_and_belief(domain, true_size: float, believed_size: float,
                     believed_density: float | None = None) -> tuple[dict, dict]:
    """A probe's true properties (every block `true_size`) and Y's belief (every block
    `believed_size`, the density `believed_density` or the domain's)."""
    n = domain.spec.n_blocks
    believed = {"block_sizes": np.full(n, believed_size),
                "density": domain.spec.density if believed_density is None else float(believed_density)}
    return {"block_sizes": np.full(n, true_size)}, believed


def tower_atoms(k: int) -> set[str]:
    """The `on` chain of b1..bk stacked in order on the start site."""
    return {f"on(b{i + 1},{'start' if i == 0 else f'b{i}'})" for i in range(k)}


def real_push(world: GroundedWorld, domain, config: Configuration, believed: dict,
              rng: np.random.Generator):
    """The tower pushed to the goal through Y at the believed properties, its timing as a
    real arm runs it (``reality_gap.executed``: the simulated reality's per-push jitter)."""
    return act(world, domain, config, believed, "push(r,tower,start,goal)",
               run_as=lambda traj, action: executed(traj, action, rng, action_jitter(domain, action)))


def tower_configuration(domain, sizes: np.ndarray, load_k: int, rng: np.random.Generator) -> Configuration:
    """b1..bk stacked on the start site (each jittered in the plane and in yaw), the rest in
    the supply row (jittered), the gripper up and clear of the tower."""
    spec = domain.spec
    config = domain.initial_configuration({"block_sizes": sizes})
    objects = jitter_planar(rng, config.objects, range(spec.n_blocks))
    # A stack releases over the observed top block, so a block lands off the one below it
    # by the robot's placement error (half the supply row's jitter: the gripper's fingers
    # centre it as they open) and the offsets add up: a random walk, as in a built tower.
    step = TOWER_JITTER_M
    xy = spec.start_xy()
    for i in range(load_k):
        xy = xy + np.clip(rng.normal(0, step, 2), -2 * step, 2 * step)
        # Heights only order the tower (place() restacks it from the floor).
        objects[i, :3] = [xy[0], xy[1], (i + 0.5) * sizes[i]]
        objects[i, 3:] = quat_from_yaw(rng.uniform(-YAW_JITTER_RAD, YAW_JITTER_RAD))
    robot = config.robot.copy()
    robot[0] = spec.start_x - 0.2
    robot[2] = max(spec.carry_height, float(np.sum(sizes[:load_k])) + spec.carry_margin)
    return domain.place(Configuration(robot, objects), {"block_sizes": sizes})


def probe_trial(domain, action: str, true_size: float, believed_size: float, load_k: int,
                rng: np.random.Generator, believed_density: float | None = None) -> bool | None:
    """pickup: one random block from the supply row; stack: one more block onto a tower of
    `load_k`; push: a tower of `load_k` to the goal; stand: a tower of `load_k` left alone.
    The truth's density is the domain's (option ``density``); Y believes
    `believed_density` (default: the truth's), which matters when mass is in Y."""
    n = domain.spec.n_blocks
    if action.startswith("built_"):
        return built_probe_trial(domain, action.removeprefix("built_"), true_size, believed_size, load_k,
                                 rng, believed_density)
    if action == "rail_pickup":
        return rail_pickup_trial(domain, true_size, believed_size, load_k, rng, believed_density)
    if action == "stack" and not 0 <= load_k < n:
        raise ValueError(f"load: stack onto a tower of {load_k} needs a free block (0..{n - 1})")
    if action in ("push", "stand") and not 1 <= load_k <= n:
        raise ValueError(f"load: a tower of {load_k} is outside 1..{n}")
    truth, believed = truth_and_belief(domain, true_size, believed_size, believed_density)
    sizes = truth["block_sizes"]
    with make_world(domain) as world:
        if action == "pickup":
            config = domain.initial_configuration(truth)
            config = world.reset(Configuration(config.robot, jitter_planar(rng, config.objects, range(n))), truth)
            b = f"b{int(rng.integers(n)) + 1}"
            out = act(world, domain, config, believed, f"pickup(r,{b},init)")
            return f"is_holding(r,{b})" in out.state
        config = world.reset(tower_configuration(domain, sizes, load_k, rng), truth)
        if action == "push":
            out = real_push(world, domain, config, believed, rng)
            return all(f"is_in(b{i + 1},goal)" in out.state for i in range(load_k))
        if action == "stand":
            still = np.array([[0.0, *config.robot], [STAND_S, *config.robot]])
            out = world.execute(still, "stand")
            return tower_atoms(load_k) <= out.state and "hand_empty(r)" in out.state
        b = f"b{load_k + 1}"                         # stack: pick the next block, put it on top
        out = act(world, domain, config, believed, f"pickup(r,{b},init)")
        if f"is_holding(r,{b})" not in out.state:
            return False
        out = act(world, domain, out.configuration, believed, f"stack(r,{b},tower)")
        return tower_atoms(load_k + 1) <= out.state and "hand_empty(r)" in out.state


def built_tower(world: GroundedWorld, domain, truth: dict, believed: dict, load_k: int,
                rng: np.random.Generator) -> Configuration | None:
    """b1..bk stacked on the start site the way the agent stacks them: from a jittered
    supply row, each block picked up and stacked through Y at the believed properties
    (the tower's crookedness is the robot's own). None if BUILD_TRIES builds fail."""
    n = domain.spec.n_blocks
    for _ in range(BUILD_TRIES):
        config = domain.initial_configuration(truth)
        config = world.reset(Configuration(config.robot, jitter_planar(rng, config.objects, range(n))), truth)
        for i in range(load_k):
            b = f"b{i + 1}"
            out = act(world, domain, config, believed, f"pickup(r,{b},init)")
            if f"is_holding(r,{b})" not in out.state:
                break
            out = act(world, domain, out.configuration, believed, f"stack(r,{b},tower)")
            if not (tower_atoms(i + 1) <= out.state and "hand_empty(r)" in out.state):
                break
            config = out.configuration
        else:
            return config
    return None


def built_probe_trial(domain, action: str, true_size: float, believed_size: float, load_k: int,
                      rng: np.random.Generator, believed_density: float | None = None) -> bool | None:
    """`stack` onto, or `push` of, a tower of `load_k` that the agent's actions built (what
    T* must judge: the issue-24 finding was a synthetic tower of 6 pushed 18/40 times while
    the agent's own towers of 6 went 8/8). A tower that cannot be built is None: the context
    was not reached (``sim_workers.probe.run_trial``, and so T*, counts it a failure; a
    counterfactual snapshot leaves it out)."""
    n = domain.spec.n_blocks
    if action == "stack" and not 0 <= load_k < n:
        raise ValueError(f"load: stack onto a tower of {load_k} needs a free block (0..{n - 1})")
    if action == "push" and not 1 <= load_k <= n:
        raise ValueError(f"load: a tower of {load_k} is outside 1..{n}")
    if action not in ("stack", "push"):
        raise ValueError(f"action: built_{action} is not a probe (built_stack, built_push)")
    truth, believed = truth_and_belief(domain, true_size, believed_size, believed_density)
    with make_world(domain) as world:
        config = built_tower(world, domain, truth, believed, load_k, rng)
        if config is None:          # the context was not reached (T* counts it a failure)
            return None
        if action == "push":
            out = real_push(world, domain, config, believed, rng)
            return all(f"is_in(b{i + 1},goal)" in out.state for i in range(load_k))
        b = f"b{load_k + 1}"
        out = act(world, domain, config, believed, f"pickup(r,{b},init)")
        if f"is_holding(r,{b})" not in out.state:
            return False
        out = act(world, domain, out.configuration, believed, f"stack(r,{b},tower)")
        return tower_atoms(load_k + 1) <= out.state and "hand_empty(r)" in out.state


def rail_configuration(domain, sizes: np.ndarray, neighbours: int, rng: np.random.Generator) -> Configuration:
    """The supply row (jittered) with b1 lying upright on the rail at a random place,
    offset and yaw, and `neighbours` more blocks (b2, b3) beside it along the rail, each a
    little beyond touching (as a toppled tower leaves them)."""
    spec = domain.spec
    config = domain.initial_configuration({"block_sizes": sizes})
    objects = jitter_planar(rng, config.objects, range(spec.n_blocks))
    s = float(sizes[0])
    play = max(0.0, spec.rail_half_gap - s / 2)
    x = rng.uniform(*RAIL_PICKUP_X)
    objects[0, :3] = [x, rng.uniform(-play, play), s / 2]
    objects[0, 3:] = quat_from_yaw(rng.uniform(-RAIL_PICKUP_YAW, RAIL_PICKUP_YAW))
    for k in range(neighbours):
        side = 1.0 if k % 2 == 0 else -1.0
        dx = s * (np.sqrt(0.5) + 0.5) + rng.uniform(0.0, 0.02)
        objects[1 + k, :3] = [x + side * dx, rng.uniform(-play, play), float(sizes[1 + k]) / 2]
        objects[1 + k, 3:] = quat_from_yaw(rng.uniform(-RAIL_PICKUP_YAW, RAIL_PICKUP_YAW))
    return domain.place(Configuration(config.robot, objects), {"block_sizes": sizes})


def rail_pickup_trial(domain, true_size: float, believed_size: float, load_k: int,
                      rng: np.random.Generator, believed_density: float | None = None) -> bool | None:
    """`rail_pickup`: b1 picked from the rail with `load_k` (0..2) blocks lying beside it;
    None where the scene did not settle with b1 read on the rail."""
    n = domain.spec.n_blocks
    if not 0 <= load_k <= min(RAIL_NEIGHBOURS, n - 1):
        raise ValueError(f"load: {load_k} neighbours on the rail is outside 0..{min(RAIL_NEIGHBOURS, n - 1)}")
    truth, believed = truth_and_belief(domain, true_size, believed_size, believed_density)
    sizes = truth["block_sizes"]
    with make_world(domain) as world:
        config = world.reset(rail_configuration(domain, sizes, load_k, rng), truth)
        if "is_in(b1,rail)" not in domain.symbolic_state(config):
            return None
        out = act(world, domain, config, believed, "pickup(r,b1,rail)")
        return "is_holding(r,b1)" in out.state
