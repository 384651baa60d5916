"""The node dispatcher: one Ray actor per node that spreads a node's slice over its shards.

Why. With one remote call per shard the driver submits C calls per action on C cores,
serially (about 0.27 ms each on a 2-core machine): at 256 cores that is ~70 ms of every
action, more than the physics of N = 1000 particles. With a dispatcher per node the
driver submits one call per *node*; each dispatcher submits its node's shard calls, on
its own node, at the same time as every other node's dispatcher (docs/SCALING.md).

The dispatcher reserves no CPU (it waits, the shards simulate) and is an asyncio actor:
calls from several tasks sharing a pool interleave while they await their shards, and a
``set_shards`` (sent when the pool re-plans) runs whole before the next call starts.
The shards' results come back as a list in row order, each part still naming the node
and process that ran it, so the pool's per-node accounting is unchanged, and the rows are
bit-identical to any other split (every particle-action runs in a freshly built world).

A shard of this node that ended for good has its rows re-run on the node's other shards;
if none is left the call fails with :class:`NodeShardsLost` and the pool treats the node
as lost (re-runs the slice on other nodes), as it does when the node itself leaves.
"""
from __future__ import annotations

import os
import time

import numpy as np


class NodeShardsLost(RuntimeError):
    """Every shard of this node ended for good while a call was in flight."""


def split_bounds(lo: int, hi: int, parts: int) -> list[tuple[int, int]]:
    """Contiguous, near-equal, non-empty row ranges covering [lo, hi) in order.

    >>> split_bounds(0, 5, 2), split_bounds(0, 1, 3), split_bounds(2, 2, 2)
    ([(0, 2), (2, 5)], [(0, 1)], [])
    """
    bounds = np.linspace(lo, hi, max(1, parts) + 1).astype(int)
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]


def slice_args(args: tuple, sliced: tuple[int, ...], a: int, b: int) -> tuple:
    """`args` with the positions in `sliced` cut to rows a..b (the rest shared).

    >>> slice_args(("x", [1, 2, 3], 7), (1,), 1, 3)
    ('x', [2, 3], 7)
    """
    return tuple(v[a:b] if i in sliced else v for i, v in enumerate(args))


class NodeDispatcher:
    """Fans one call out over the shard actors of its node (wrap with ``remote_dispatcher``)."""

    def __init__(self, shards: list | None = None, epoch: int = 0) -> None:
        self.shards = list(shards or [])
        self.epoch = epoch
        self.reruns = 0

    def set_shards(self, shards: list, epoch: int) -> int:
        """The node's shard actors, in the order rows are dealt to them, as of the pool's
        plan number `epoch` (an older plan arriving late is ignored). Returns the epoch held."""
        if epoch >= self.epoch:
            self.shards, self.epoch = list(shards), epoch
        return self.epoch

    async def fan(self, method: str, args: tuple, sliced: tuple[int, ...], n: int,
                  epoch: int = 0) -> dict:
        """``method(*args)`` on this node's shards, rows 0..n of the `sliced` arguments
        split contiguously over them. Returns ``parts`` (the shards' results, row order),
        ``reruns`` (slices re-run here because a shard ended for good), and ``calls`` and
        ``submit_s`` (the shard calls it made and its time submitting them), ``lost`` (the
        plan's indices of shards that ended for good, for the pool to forget); or ``stale``
        if this dispatcher does not hold the pool's plan `epoch` (Ray restarted it with
        its first shard list, or the plan's ``set_shards`` has not arrived): the pool
        sends the plan and calls again."""
        import ray

        if epoch != self.epoch:
            return {"stale": True, "epoch": self.epoch}
        sliced = tuple(sliced)
        plan = list(self.shards)           # the plan's order: the pool is told lost shards by it
        parts: dict[int, dict] = {}
        todo = [(0, n)]
        reruns, submit_s, n_calls, lost = 0, 0.0, 0, []
        while todo:
            shards = list(self.shards)
            if not shards:
                raise NodeShardsLost("node dispatcher: no shard left on this node")
            calls = []
            t0 = time.perf_counter()
            for lo, hi in todo:
                for s, (a, b) in zip(shards, split_bounds(lo, hi, len(shards))):
                    calls.append((a, b, s, getattr(s, method).remote(*slice_args(args, sliced, a, b))))
            submit_s += time.perf_counter() - t0
            n_calls += len(calls)
            todo = []
            for a, b, s, ref in calls:
                try:
                    parts[a] = await ref
                except ray.exceptions.RayActorError:
                    self.shards = [x for x in self.shards if x is not s]
                    lost += [i for i, x in enumerate(plan) if x is s and i not in lost]
                    todo.append((a, b))
            reruns += len(todo)
        self.reruns += reruns
        return {"parts": [parts[a] for a in sorted(parts)], "reruns": reruns,
                "submit_s": submit_s, "calls": n_calls, "lost": sorted(lost)}

    def ping(self) -> dict:
        """The plan this dispatcher holds (epoch, shard count) and its process id."""
        return {"epoch": self.epoch, "shards": len(self.shards), "pid": os.getpid()}


def remote_dispatcher():
    """The Ray actor class: no CPU reserved, restarted and its call retried by Ray when its
    process dies (the shards it holds are other actors and live on)."""
    import ray

    return ray.remote(num_cpus=0, max_restarts=-1, max_task_retries=-1,
                      max_concurrency=64)(NodeDispatcher)
