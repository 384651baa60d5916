"""Task-planner latency: clingo incremental #minimize for 8 and 16 blocks under several T.

Each setting plans from the initial state (all blocks at init) with the default costs and
times the whole `planner.container.planner.plan` call (validation, grounding, every solve of the
incremental horizon loop, naming and re-scoring the plan). T settings:

    optimistic   every action succeeds (one trip with all blocks)
    push-linear  push to goal succeeds with 1 - a*k for load k (a = 0.08 at 8 blocks,
                 0.05 at 16, so it stays positive)
    push-step    push succeeds with 1 up to load 4, 0.3 above
    stack-fall   stack succeeds with 1 - 0.06*height, push with 1 - 0.03*k, pickup 0.9
    mid-episode  push-linear from a state with b1 delivered, a loaded container at init,
                 a block in the gripper and one on the table

The same settings for stack-and-push (`planner.stack_and_push.plan`; its mid-episode state
is b1 delivered, a tower of two, a block in the gripper and one lying in the rail; the
domain has at most 8 blocks, so 16 is skipped for it).

    python benchmarks/bench_planner.py [--quick] [--repeats 15] [--domain container,stack_and_push]

The last line is machine-readable: median_ms_8=... median_ms_16=... (median over all runs
of all settings for that number of blocks, first domain), then DOMAIN_median_ms_8=... for
every domain.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from planner import stack_and_push  # noqa: E402
from planner.container import symbolic  # noqa: E402
from planner.container import planner as task_planner  # noqa: E402

MAX_BLOCKS = {"container": 16, "stack_and_push": 8}


def transition(n: int, push: Callable[[int], float] = lambda k: 1.0,
               stack: Callable[[int], float] = lambda j: 1.0, pickup: float = 1.0) -> dict:
    return {"pickup": pickup,
            "stack": np.clip([stack(j) for j in range(n)], 0.0, 1.0).tolist(),
            "push": np.clip([push(k) for k in range(1, n + 1)], 0.0, 1.0).tolist()}


def mid_episode_state(n: int) -> frozenset[str]:
    atoms = {"is_in(b1,goal)", "at_container(b2,c)", "at_container(b3,c)",
             "is_holding(r,b4)", "is_in(b5,table)", "is_in(c,init)"}
    atoms |= {f"is_in(b{i},init)" for i in range(6, n + 1)}
    return frozenset(atoms)


def mid_episode_stack_and_push(n: int) -> frozenset[str]:
    atoms = {"is_in(b1,goal)", "on(b2,start)", "on(b3,b2)", "is_holding(r,b4)", "is_in(b5,rail)"}
    atoms |= {f"is_in(b{i},init)" for i in range(6, n + 1)}
    return frozenset(atoms)


def settings(n: int, domain: str = "container") -> dict[str, tuple[frozenset[str], dict]]:
    slope = 0.08 if n <= 8 else 0.05
    linear = transition(n, push=lambda k: 1 - slope * k)
    if domain == "stack_and_push":
        start, mid = stack_and_push.initial_state(n), mid_episode_stack_and_push(n)
    else:
        start, mid = symbolic.initial_state(n), mid_episode_state(n)
    return {
        "optimistic": (start, task_planner.optimistic_transition(n)),
        "push-linear": (start, linear),
        "push-step": (start, transition(n, push=lambda k: 1.0 if k <= 4 else 0.3)),
        "stack-fall": (start, transition(n, push=lambda k: 1 - 0.03 * k,
                                         stack=lambda j: 1 - 0.06 * j, pickup=0.9)),
        "mid-episode": (mid, linear),
    }


def time_plans(state: frozenset[str], T: dict, repeats: int,
               domain: str = "container") -> tuple[list[float], task_planner.Plan]:
    """Wall times (ms) of `repeats` calls after one warm-up call, and the plan."""
    plan = stack_and_push.plan if domain == "stack_and_push" else task_planner.plan
    result = plan(state, T)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = plan(state, T)
        times.append((time.perf_counter() - t0) * 1e3)
    return times, result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 repeats per setting (smoke run)")
    ap.add_argument("--repeats", type=int, default=15, help="timed calls per setting (default 15)")
    ap.add_argument("--blocks", default="8,16", help="comma-separated block counts (default 8,16)")
    ap.add_argument("--domain", default="container,stack_and_push",
                    help="comma-separated domains (default container,stack_and_push)")
    args = ap.parse_args(argv)
    repeats = 3 if args.quick else args.repeats
    if repeats < 1:
        ap.error("--repeats must be at least 1")
    try:
        counts = [int(b) for b in args.blocks.split(",")]
    except ValueError:
        ap.error(f"--blocks: {args.blocks!r} is not a list of integers")
    if any(n < 5 for n in counts):
        ap.error("--blocks: the mid-episode setting needs at least 5 blocks")

    domains = [d.strip() for d in args.domain.split(",") if d.strip()]
    unknown = [d for d in domains if d not in MAX_BLOCKS]
    if unknown or not domains:
        ap.error(f"--domain: unknown domain {unknown[0] if unknown else ''!r} "
                 f"(known: {', '.join(MAX_BLOCKS)})")

    print(f"{'domain':<15} {'blocks':>6}  {'T setting':<12} {'median ms':>9} {'p90 ms':>8} "
          f"{'max ms':>8}  {'optimal':<7}  loads")
    all_times: dict[tuple[str, int], list[float]] = {}
    for domain in domains:
        for n in counts:
            if n > MAX_BLOCKS[domain]:
                continue
            for name, (state, T) in settings(n, domain).items():
                times, result = time_plans(state, T, repeats, domain)
                all_times.setdefault((domain, n), []).extend(times)
                print(f"{domain:<15} {n:>6}  {name:<12} {statistics.median(times):>9.1f} "
                      f"{float(np.percentile(times, 90)):>8.1f} {max(times):>8.1f}  "
                      f"{str(result.optimal):<7}  {'+'.join(map(str, result.loads))}")
    first = [f"median_ms_{n}={statistics.median(t):.1f}" for (d, n), t in all_times.items()
             if d == domains[0]]
    rest = [f"{d}_median_ms_{n}={statistics.median(t):.1f}" for (d, n), t in all_times.items()]
    print(" ".join(first + rest))
    return 0


if __name__ == "__main__":
    sys.exit(main())
