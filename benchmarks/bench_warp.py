"""MuJoCo Warp's batch engine against CPU MuJoCo: particle-actions per second (issue 42).

For the container's three actions (bench_worlds' workload: sizes from the prior, one
trajectory from Y with the true size), one batch of K particles per action in a
``Shard`` of each engine: CPU MuJoCo steps them one after another on one core; the
``mujoco_warp`` engine steps all K at once on Warp's device (a GPU where Warp sees one,
else the CPU). Wall-clock seconds after a warm-up batch (kernel compilation excluded,
reported apart). Prints per K and action both throughputs and their ratio, the outcome
agreement (share of particles with the same Y^-1), the device's time for one batch step
of all K worlds and the throughput it alone would allow (the engine's controller is the
twins' Python, per world per step: the difference is its cost), and last
``ratio_warp_device_vs_cpu_core=<total particle-actions per second, warp over CPU>``.

    python benchmarks/bench_warp.py                 # K = 16 and 64, about 2 minutes on a CPU
    python benchmarks/bench_warp.py --batches 256,1024
    python benchmarks/bench_warp.py --raw --batches 1024,8192,32768   # the device's step alone
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from bench_worlds import make_cases, particle_sizes  # noqa: E402

from sim_workers.domains import load  # noqa: E402
from sim_workers.shard import Shard  # noqa: E402


def device_step_ms(batch, steps: int = 30) -> float:
    """Milliseconds of one ``mujoco_warp.step`` of the batch last loaded (all its worlds),
    the device alone: what a controller vectorised over the worlds would approach."""
    import mujoco_warp as mjw
    import warp as wp

    with wp.ScopedDevice(batch.device):
        mjw.step(batch._model, batch._data)
        wp.synchronize()
        t = time.perf_counter()
        for _ in range(steps):
            mjw.step(batch._model, batch._data)
        wp.synchronize()
    return (time.perf_counter() - t) / steps * 1e3


def raw(batches: list[int], domain_name: str, seed: int) -> int:
    """``--raw``: the device alone. The pickup's drive commands are recorded from CPU
    MuJoCo's one-step loop (one world at the true size), then replayed by ``mujoco_warp.step``
    on K worlds at once (per-world sizes, masses and force limits batched, as the engine
    does); against ``mj_step`` of the same model on one core. What a controller vectorised
    over the worlds would approach; no twins, no Python per world."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    from sim_workers.configuration import Configuration
    from sim_workers.engines.registry import make_world
    from sim_workers.engines.warp_batch import device_name
    from sim_workers.grounded_world import GroundedWorld

    device = device_name()
    domain = load(domain_name, engine="mujoco")
    start, action, traj, t0 = make_cases(domain, seed)["pickup"]
    world = make_world(domain)
    world.reset(Configuration.from_array(start), domain.true_properties())
    world.skip_to(traj, t0)
    m, d = world.model, world.data
    q0, v0 = d.qpos.copy(), d.qvel.copy()
    ctrl = []

    def record(w=world):
        ctrl.append(w.data.ctrl.copy())
        mujoco.mj_step(w.model, w.data)

    world._step = record
    world._run = GroundedWorld._run.__get__(world)
    world.execute(traj, action, start_time=t0)
    ctrl = np.array(ctrl)
    n = len(ctrl)

    def fresh():
        dd = mujoco.MjData(m)
        dd.qpos[:], dd.qvel[:] = q0, v0
        mujoco.mj_forward(m, dd)
        return dd

    dd = fresh()
    t = time.perf_counter()
    for c in ctrl:
        dd.ctrl[:] = c
        mujoco.mj_step(m, dd)
    cpu = (time.perf_counter() - t) / n
    print(f"device={device}; {domain_name} pickup, {n} steps; CPU mj_step {cpu * 1e6:.1f} us a step: "
          f"{1 / (n * cpu):.1f} pickups/s on one core", flush=True)
    m.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    best = 0.0
    with wp.ScopedDevice(device):
        for k in batches:
            t = time.perf_counter()
            mw = mjw.put_model(m, batch_sizes={"geom_size": k, "body_mass": k, "actuator_forcerange": k})
            mw.opt.warn_overflow = 0
            dw = mjw.put_data(m, fresh(), nworld=k, nconmax=128, njmax=512)
            cw = wp.array(np.repeat(ctrl[:, None, :], k, axis=1).astype(np.float32), dtype=float)
            wp.copy(dw.ctrl, cw[0])
            mjw.step(mw, dw)
            wp.synchronize()
            first = time.perf_counter() - t
            dw = mjw.put_data(m, fresh(), nworld=k, nconmax=128, njmax=512)
            wp.synchronize()
            t = time.perf_counter()
            for s in range(n):
                wp.copy(dw.ctrl, cw[s])
                mjw.step(mw, dw)
            wp.synchronize()
            per = (time.perf_counter() - t) / n
            rate = k / (n * per)
            best = max(best, rate * n * cpu)
            print(f"K={k}: first step (compile or cache load) {first:.1f} s; batch step {per * 1e3:.2f} ms; "
                  f"{k / per:.0f} world-steps/s; {rate:.0f} pickups/s = x{rate * n * cpu:.1f} one CPU core",
                  flush=True)
    print(f"ratio_device_step_vs_cpu_core={best:.2f}")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", default="16,64", help="batch sizes K")
    ap.add_argument("--domain", default="container")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--raw", action="store_true",
                    help="the device's batch step alone, replaying one pickup on K worlds (see raw())")
    args = ap.parse_args(argv)
    if args.raw:
        return raw([int(v) for v in args.batches.split(",")], args.domain, args.seed)
    from sim_workers.engines.warp_batch import device_name

    device = device_name()
    domain = load(args.domain, engine="mujoco")
    cases = make_cases(domain, args.seed)
    cpu = Shard(args.domain, {"engine": "mujoco"})
    warp = Shard(args.domain, {"engine": "mujoco_warp"})
    start, action, traj, t0 = next(iter(cases.values()))
    t = time.perf_counter()
    warp.simulate(start, particle_sizes(domain, 2, 0), action, traj, t0)
    print(f"device={device} warm-up batch (kernel compilation or cache load) {time.perf_counter() - t:.1f} s", flush=True)
    total = {"cpu": [0, 0.0], "warp": [0, 0.0]}
    for k in [int(v) for v in args.batches.split(",")]:
        sizes = particle_sizes(domain, k, args.seed + 1)
        for kind, (start, action, traj, t0) in cases.items():
            warp.simulate(start, sizes[:2], action, traj, t0)       # this action's kernels
            runs = {}
            for name, shard in (("cpu", cpu), ("warp", warp)):
                t = time.perf_counter()
                runs[name] = shard.simulate(start, sizes, action, traj, t0)
                dt = time.perf_counter() - t
                total[name][0] += k
                total[name][1] += dt
                runs[name + "_s"] = dt
            same = np.mean([a == b for a, b in zip(runs["cpu"]["states"], runs["warp"]["states"])])
            step_ms = device_step_ms(warp._batch)
            steps = float(np.max(runs["warp"]["steps"]))
            print(f"K={k:5d} {kind:7s} cpu core {k / runs['cpu_s']:8.1f}/s  warp ({device}) "
                  f"{k / runs['warp_s']:8.1f}/s  ratio {runs['cpu_s'] / runs['warp_s']:.3f}  same Y^-1 {same:.0%}  "
                  f"device step {step_ms:.2f} ms for {k} worlds (device alone: "
                  f"{k / (steps * step_ms / 1e3):.0f} particle-actions/s)", flush=True)
    cpu.close()
    warp.close()
    rate = {n: c / s for n, (c, s) in total.items()}
    print(f"particle-actions per second: cpu core {rate['cpu']:.1f}, warp on {device} {rate['warp']:.1f}")
    print(f"ratio_warp_device_vs_cpu_core={rate['warp'] / rate['cpu']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
