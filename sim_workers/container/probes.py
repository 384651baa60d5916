"""The container's probe trials (``tmoc probe --domain container``): how each action kind
is set up in a true world and judged through Y^-1."""
from __future__ import annotations

import numpy as np

from ..configuration import Configuration, quat_from_yaw
from ..engines.registry import make_world
from ..grounded_world import act
from ..reality_gap import PLACEMENT_JITTER_M, YAW_JITTER_RAD, jitter_planar
from .columns import column_x, side_by_side, two_columns

PROBE_ACTIONS = ("pickup", "stack", "push")


def loaded_configuration(domain, sizes: np.ndarray, load_k: int, rng: np.random.Generator,
                         believed: np.ndarray | None = None) -> Configuration:
    """The first `load_k` blocks (true `sizes`) piled in the container as Y piles them at
    the `believed` sizes (default: the true ones): two side by side per layer, or one column
    when the believed blocks do not fit in half the tray (``columns``). A counterfactual
    world of 49.3 mm blocks pushes the two columns a 48 mm belief builds, each block against
    its wall, not the one column its own size would get: the pile the robot would push."""
    spec = domain.spec
    config = domain.initial_configuration({"block_sizes": sizes})
    objects = jitter_planar(rng, config.objects, range(1, 1 + spec.n_blocks))
    c = objects[0, :2]
    layout = sizes if believed is None else believed
    two = two_columns(spec, layout) and side_by_side(spec, sizes)
    per_layer = 2 if two else 1
    for i in range(load_k):
        s = sizes[i]
        lx = column_x(spec, s, i % per_layer, two)
        # Heights only order the pile (place() re-stacks each column from the floor).
        z = spec.floor_top + (i // per_layer + 0.5) * s
        objects[1 + i, :3] = [c[0] + lx + rng.normal(0, PLACEMENT_JITTER_M / 2),
                              c[1] + rng.normal(0, PLACEMENT_JITTER_M / 2), z]
        objects[1 + i, 3:] = quat_from_yaw(rng.uniform(-YAW_JITTER_RAD, YAW_JITTER_RAD))
    return domain.place(Configuration(config.robot, objects), {"block_sizes": sizes})


def probe_trial(domain, action: str, true_size: float, believed_size: float, load_k: int,
                rng: np.random.Generator) -> bool:
    """pickup: one random block from the row; stack: pick and place the first `load_k`
    blocks; push: the container loaded with `load_k` blocks to goal."""
    n_blocks = domain.spec.n_blocks
    sizes = np.full(n_blocks, true_size)
    truth = {"block_sizes": sizes}
    believed = {"block_sizes": np.full(n_blocks, believed_size)}
    with make_world(domain) as world:
        if action == "push":
            config = world.reset(loaded_configuration(domain, sizes, load_k, rng, believed["block_sizes"]), truth)
            out = act(world, domain, config, believed, "push(r,c,init,goal)")
            return all(f"is_in(b{i + 1},goal)" in out.state for i in range(load_k))
        config = domain.initial_configuration(truth)
        config = Configuration(config.robot, jitter_planar(rng, config.objects, range(1, 1 + n_blocks)))
        config = world.reset(config, truth)
        if action == "pickup":
            b = f"b{int(rng.integers(n_blocks)) + 1}"
            out = act(world, domain, config, believed, f"pickup(r,{b},init)")
            return f"is_holding(r,{b})" in out.state
        for i in range(load_k):                    # stack: pick and place the first k blocks
            b = f"b{i + 1}"
            out = act(world, domain, config, believed, f"pickup(r,{b},init)")
            if f"is_holding(r,{b})" not in out.state:
                return False
            out = act(world, domain, out.configuration, believed, f"stack(r,{b},c)")
            config = out.configuration
        return all(f"at_container(b{i + 1},c)" in out.state for i in range(load_k)) \
            and "hand_empty(r)" in out.state


def t_star_probe_jobs(n_blocks: int) -> list[tuple[str, int]]:
    """(action, load) of every probe T* needs: pickup; stack of the first k blocks, k =
    1..n; push with k blocks loaded, k = 1..n."""
    return ([("pickup", 1)] + [("stack", k) for k in range(1, n_blocks + 1)]
            + [("push", k) for k in range(1, n_blocks + 1)])


def true_T_from_probes(successes: dict[tuple[str, int], int], trials: int, n_blocks: int) -> dict:
    """T* in the planner's form from probe success counts.

    pickup: its success rate. push[k-1]: the rate of a push with k blocks loaded.
    stack[h] (h blocks already in the container): a stack probe of k blocks succeeds when
    all k pickups and stacks do, and trial t of every k replays the same seeded world, so
    S(h+1) / S(h) (S(0) = trials) is the rate of "pick up, then stack on h"; dividing by
    the pickup rate leaves the stack's (clipped to [0, 1]). A height no trial reached
    (S(h) = 0) gets 0: never seen to succeed.
    """
    p_pickup = successes[("pickup", 1)] / trials
    S = [trials] + [successes[("stack", k)] for k in range(1, n_blocks + 1)]
    stack = []
    for h in range(n_blocks):
        if S[h] == 0 or p_pickup == 0:
            stack.append(0.0)
        else:
            stack.append(float(min(1.0, S[h + 1] / S[h] / p_pickup)))
    push = [successes[("push", k)] / trials for k in range(1, n_blocks + 1)]
    return {"pickup": float(p_pickup), "stack": stack, "push": [float(p) for p in push]}
