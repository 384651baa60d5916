"""MuJoCo worlds stepped on threads of one process against one process per core (issue 42).

MuJoCo's stepping calls (``mj_step``, ``rollout``) release the GIL, so one shard can step
several worlds at once (``Shard(threads=T)``); what stays under the GIL is each
particle-action's Python (reset, Y^-1, observation). For each domain's three actions (the
workload of ``bench_worlds``: sizes from the prior, one trajectory from Y with the true
size), the same batch in one run:

  (a) one thread      ``Shard(threads=1)``;
  (b) T threads       ``Shard(threads=T)``, one process (outcomes checked bit-identical to (a));
  (c) T processes     T plain processes, each a ``Shard(threads=1)`` with 1/T of the batch.

Wall-clock seconds (the machine's cores are what is compared). Prints per action the
speedups of (b) and (c) over (a), and last ``threads_vs_processes=<(c) time / (b) time>``
over every action: above 1 threads win, below 1 processes do.

    python benchmarks/bench_threads.py              # T = the machine's cores, 32 particles
    python benchmarks/bench_threads.py --threads 4 --particles 64
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench_worlds import make_cases, particle_sizes  # noqa: E402

from sim_workers.domains import load  # noqa: E402
from sim_workers.shard import Shard  # noqa: E402


def _half(job) -> float:
    """In a plain process: one shard simulates its rows (after a warm-up); wall seconds."""
    domain_name, case, sizes = job
    start, action, traj, t0 = case
    shard = Shard(domain_name, {"engine": "mujoco"})
    shard.simulate(start, sizes[:1], action, traj, t0)
    t = time.perf_counter()
    shard.simulate(start, sizes, action, traj, t0)
    dt = time.perf_counter() - t
    shard.close()
    return dt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 2)
    ap.add_argument("--particles", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domains", default="container,stack_and_push")
    args = ap.parse_args(argv)
    if args.threads < 2:
        ap.error("--threads: at least 2")
    t_threads = t_procs = 0.0
    ctx = mp.get_context("spawn")
    with ctx.Pool(args.threads) as procs:
        for name in args.domains.split(","):
            domain = load(name, engine="mujoco")
            cases = make_cases(domain, args.seed)
            sizes = particle_sizes(domain, args.particles, args.seed + 1)
            one = Shard(name, {"engine": "mujoco"})
            many = Shard(name, {"engine": "mujoco"}, threads=args.threads)
            for kind, (start, action, traj, t0) in cases.items():
                one.simulate(start, sizes[:1], action, traj, t0)
                many.simulate(start, sizes[: args.threads], action, traj, t0)
                t = time.perf_counter()
                a = one.simulate(start, sizes, action, traj, t0)
                ta = time.perf_counter() - t
                t = time.perf_counter()
                b = many.simulate(start, sizes, action, traj, t0)
                tb = time.perf_counter() - t
                same = all(a[k].tobytes() == b[k].tobytes() for k in ("configurations", "measurements", "steps")) \
                    and list(a["states"]) == list(b["states"])      # bytes: NaN channels compare equal
                jobs = [(name, (start, action, traj, t0), part)
                        for part in np.array_split(sizes, args.threads)]
                t = time.perf_counter()
                procs.map(_half, jobs)
                tc = time.perf_counter() - t
                t_threads += tb
                t_procs += tc
                print(f"{name:15s} {kind:7s} one thread {ta * 1e3 / len(sizes):6.2f} ms/particle-action  "
                      f"{args.threads} threads x{ta / tb:.2f} (bit-identical: {same})  "
                      f"{args.threads} processes x{ta / tc:.2f}", flush=True)
            one.close()
            many.close()
    print(f"threads_vs_processes={t_procs / t_threads:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
