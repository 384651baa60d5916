"""Particle-actions per second of a domain's grounded worlds, against raw pybullet.

For each action (pickup, stack, push) one batch of particles (block sizes drawn from the
prior) replays one trajectory from Y with the true size, starting at the pre-pose (the
free-space transit is skipped, as particle worlds do). The domain is ``--domain NAME``
(default container; also stack_and_push, with its own actions: pickup(r,b3,init),
stack(r,b3,tower) onto a tower of two, push(r,tower,start,goal) of a tower of four).
Measured on this machine in one run:

  (a) in-process   one ``sim_workers.shard.Shard`` (one world), the whole batch in one call;
  (b) ray x2       two shard actors on local Ray (``ray.init(num_cpus=2)``), the batch split
                   in two, one remote call per actor per action;
  (c) raw x2       two plain processes, each with the scene built once from its declaration,
                   calling ``stepSimulation`` as many times as the shards reported in
                   ``steps`` for its half, the gripper held static (a resting scene);
  (d) replay x2    two plain processes redoing the very same physics with a bare pybullet
                   loop: each particle's world rebuilt for its sizes and placed at the start
                   configuration, the same gripper commands every step, the same number of
                   steps, and nothing else (no rest checks, Y^-1, observation or Ray).

(d) is the physical limit of this work on these cores, and the last line is
``ratio_vs_raw=<ray x2 throughput / replay x2 throughput>`` over all three actions. (c) is
printed as ``ratio_vs_static_scene``: a resting scene's contacts converge in a few solver
iterations while an action's moving contacts use all 50, so no action can reach it (measured:
~57 us/step resting against ~120 us/step inside an action).

Shards leave out of a particle world the bodies an action cannot reach, for the action
kinds the domain names in ``leave_out_actions`` (``sim_workers/reach.py``); (a) to (d)
measure what the service runs, leave-out included (the replay removes the same bodies).
(e) compares, in-process on the same particles, worlds with every body (``leave_out=False``,
before) and with leave-out forced on for every action kind (after): steps and
milliseconds per particle-action by action kind, how many particle-actions the guard sent
back to the full world, whether the outcomes agree (symbolic states, largest difference
of a channel the belief weighs, and of any measurement), and whether the domain adopts
leave-out for that kind (its ``leave_out_actions``: only where the weighed channels stay
within a millionth of their sigma).

Also: the cost of one world reset (a rebuild), the share of in-process time spent inside
``stepSimulation``, and the RSS of each shard (``Shard.node()``, peak RSS of its process).

    python benchmarks/bench_worlds.py --quick      # under a minute
    python benchmarks/bench_worlds.py              # larger batches, best of 3 rounds
    python benchmarks/bench_worlds.py --quick --domain stack_and_push
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import sys
import time

import numpy as np

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
os.environ.setdefault("RAY_DEDUP_LOGS", "0")

try:        # its workload (make_cases) serves MuJoCo-only machines too (bench_warp)
    import pybullet as pb  # noqa: E402
except ImportError:  # pragma: no cover - where pybullet has no wheel
    pb = None

from sim_workers.domains import load  # noqa: E402
from sim_workers.configuration import Configuration  # noqa: E402
from sim_workers.engines import make_world  # noqa: E402
from sim_workers.container.probes import loaded_configuration  # noqa: E402
from sim_workers.shard import Shard, remote_shard  # noqa: E402

ACTIONS = ("pickup", "stack", "push")
DOMAINS = ("container", "stack_and_push")   # the domains make_cases has a workload for


# -- the workload -------------------------------------------------------------------------
def make_cases(domain, seed: int) -> dict:
    """Per action: (flat start configuration, action term, trajectory, start time).

    container: pickup(r,b3,init); stack(r,b3,c) onto a pile of two; push(r,c,init,goal)
    with four blocks loaded. stack_and_push: pickup(r,b3,init); stack(r,b3,tower) onto a
    tower of two; push(r,tower,start,goal) of a tower of four."""
    if domain.name not in DOMAINS:
        sys.exit(f"bench_worlds: no workload for domain {domain.name!r} (known: {', '.join(DOMAINS)})")
    rng = np.random.default_rng(seed)
    truth = domain.true_properties()
    sizes = truth["block_sizes"]
    cases = {}

    def case(name, config, action):
        key = domain.action_pose(truth, config, action)
        traj = domain.action_trajectory(config, action, key)
        # The pre-pose, where the transit ends (the 4th row of the default transit).
        cases[name] = (config.to_array(), action, traj, domain.transit_end_time(config, action, key))

    if domain.name == "stack_and_push":
        from sim_workers.stack_and_push.probes import tower_configuration

        def loaded(k):                     # b1..bk stacked on the start site
            return tower_configuration(domain, sizes, k, rng)
        target, push = "tower", "push(r,tower,start,goal)"
    else:
        def loaded(k):                     # b1..bk piled in the container
            return loaded_configuration(domain, sizes, k, rng)
        target, push = "c", "push(r,c,init,goal)"

    case("pickup", domain.initial_configuration(truth), "pickup(r,b3,init)")
    # Stack onto a pile (tower) of two: the start is a real grasp of b3 (observed after a pickup).
    two = loaded(2)
    with make_world(domain) as world:
        world.reset(two, truth)
        action = "pickup(r,b3,init)"
        key = domain.action_pose(truth, two, action)
        traj = domain.action_trajectory(two, action, key)
        held = world.execute(traj, action, start_time=domain.transit_end_time(two, action, key))
    if "is_holding(r,b3)" not in held.state:
        sys.exit("bench_worlds: the setup pickup for the stack case failed")
    case("stack", held.configuration, f"stack(r,b3,{target})")
    case("push", loaded(4), push)
    return cases


def particle_sizes(domain, n: int, seed: int) -> np.ndarray:
    """(n, n_blocks): one size per particle from the prior, shared by its blocks."""
    spec = domain.spec
    s = np.random.default_rng(seed).uniform(spec.prior_low, spec.prior_high, n)
    return np.repeat(s[:, None], spec.n_blocks, axis=1)


# -- (d) bare replay of the very same action physics in plain processes --------------------
def _replay(job) -> float:
    """Seconds for a bare pybullet loop to redo the shard's physics for some particles.

    Same worlds (rebuilt for each particle's sizes, placed at the start configuration),
    same gripper commands every step, the same number of steps the shard ran; none of the
    framework around it (no rest checks, no Y^-1, no observation, no Ray).
    """
    import pybullet as pb

    from sim_workers import trajectory as tr

    domain_name, start, sizes, traj, t0, counts, action = job
    domain = load(domain_name)
    world = make_world(domain, leave_out=True)
    config = Configuration.from_array(start)
    dt = domain.spec.time_step
    tic = time.perf_counter()
    for row, n in zip(sizes, counts):
        world.reset(config, {"block_sizes": row})
        world.skip_to(traj, t0)
        h, c = world.handles, world.client
        full = tr.sample(traj, t0 + dt * np.arange(1, int(np.ceil((traj[-1, 0] - t0 + world.settle_s) / dt)) + 1))
        if world._leaves_out(action):
            world._leave_out(full)          # the very bodies the shard left out (no guard)
        targets = full[:n, :5]
        for x, y, z, yaw, opening in targets:
            pb.changeConstraint(h.base_constraint, jointChildPivot=[x, y, z + h.palm_offset],
                                jointChildFrameOrientation=pb.getQuaternionFromEuler([0, 0, yaw]),
                                maxForce=domain.spec.base_max_force, physicsClientId=c)
            q = opening / 2 + h.finger_inner
            pb.setJointMotorControlArray(h.gripper, list(h.fingers), pb.POSITION_CONTROL,
                                         targetPositions=[q, q], forces=[h.grip_force] * 2,
                                         physicsClientId=c)
            pb.stepSimulation(physicsClientId=c)
    elapsed = time.perf_counter() - tic
    world.close()
    return elapsed


# -- (c) raw pybullet stepping in plain processes ------------------------------------------
def _raw_worker(conn, domain_name: str, n_blocks: int) -> None:
    """Steps one scene with bare ``stepSimulation`` calls; the gripper's target never changes.

    Message ("built", None, n): the scene as its declaration builds it (blocks in
    their row, the gripper up), built once. Message ("start", (start, action, traj, t0), n): the scene
    put once in the action's start configuration with the gripper at its pre-pose (same
    bodies in contact as the action starts with), then stepped n times. Replies the seconds
    spent stepping.
    """
    domain = load(domain_name, n_blocks=n_blocks)
    truth = domain.true_properties()
    client = pb.connect(pb.DIRECT)
    # The scene from the domain's declaration, as a pybullet world builds it (the domains'
    # own ``build`` methods went in issue 39).
    from sim_workers.engines.pybullet_engine import build_scene

    build_scene(client, domain.scene_description(domain.properties(truth)))
    step = pb.stepSimulation
    for _ in range(50):
        step(physicsClientId=client)
    placed = {}
    conn.send("ready")
    while True:
        msg = conn.recv()
        if msg is None:
            break
        mode, case, n = msg
        if mode == "built":
            cid = client
        else:
            start, action, traj, t0 = case
            if action not in placed:
                from sim_workers.configuration import Configuration
                world = make_world(domain)
                world.reset(Configuration.from_array(start), truth)
                world.skip_to(traj, t0)
                placed[action] = world
            cid = placed[action].client
        tic = time.perf_counter()
        for _ in range(n):
            step(physicsClientId=cid)
        conn.send(time.perf_counter() - tic)
    pb.disconnect(client)


class RawPool:
    """Plain processes, one pybullet scene each, built once."""

    def __init__(self, n: int, domain_name: str, n_blocks: int) -> None:
        ctx = mp.get_context("spawn")
        self.conns, self.procs = [], []
        for _ in range(n):
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_raw_worker, args=(child, domain_name, n_blocks), daemon=True)
            p.start()
            self.conns.append(parent)
            self.procs.append(p)
        for c in self.conns:
            assert c.recv() == "ready"

    def step(self, counts, mode: str = "built", case=None) -> float:
        """Wall time for the workers to step counts[i] times each, in parallel."""
        if mode == "start":                      # place the scene first, outside the timing
            for c in self.conns:
                c.send((mode, case, 0))
            for c in self.conns:
                c.recv()
        t0 = time.perf_counter()
        for c, n in zip(self.conns, counts):
            c.send((mode, case, int(n)))
        for c in self.conns:
            c.recv()
        return time.perf_counter() - t0

    def close(self) -> None:
        for c in self.conns:
            c.send(None)
        for p in self.procs:
            p.join(10)


# -- measurements -------------------------------------------------------------------------
class StepTimer:
    """Counts the time spent inside pybullet.stepSimulation (patched for one block)."""

    def __init__(self) -> None:
        self.total = 0.0
        self._orig = None

    def __enter__(self):
        self._orig = pb.stepSimulation
        orig, perf = self._orig, time.perf_counter

        def timed(*a, **k):
            t = perf()
            out = orig(*a, **k)
            self.total += perf() - t
            return out

        pb.stepSimulation = timed
        return self

    def __exit__(self, *exc):
        pb.stepSimulation = self._orig


def leave_out_table(name_d: str, cases: dict, sizes: np.ndarray, rounds: int) -> dict:
    """(e): per action, seconds for the batch with every body and with leave-out (best of
    `rounds`, interleaved), mean steps, guard re-runs, and how far the outcomes differ."""
    table = {}
    for name in ACTIONS:
        start, action, traj, t0 = cases[name]
        best = {False: np.inf, True: np.inf}
        for _ in range(rounds):
            for flag in (False, True):
                shard = Shard(name_d, None, 1, leave_out=flag)
                adopted = action.partition("(")[0] in shard.domain.leave_out_actions
                shard.domain.leave_out_actions = ACTIONS         # forced on, to measure it
                shard.simulate(start, sizes[:2], action, traj, t0)          # warm up
                tic = time.perf_counter()
                out = shard.simulate(start, sizes, action, traj, t0)
                best[flag] = min(best[flag], time.perf_counter() - tic)
                if flag:
                    after, reruns = out, shard.worlds[0].reruns
                else:
                    before = out
                shard.close()
        dmeas = np.abs(after["measurements"] - before["measurements"])
        weighed = dmeas[:, np.asarray(load(name_d).measurement_model()[0])]
        table[name] = {"adopted": adopted, "dweighed": float(np.nanmax(weighed)) if np.isfinite(weighed).any() else 0.0,
                       "before": best[False], "after": best[True], "steps": before["steps"].mean(),
                       "steps_total": float(before["steps"].sum()), "reruns": int(reruns),
                       "same": float(np.mean(after["states"] == before["states"])),
                       "dmeas": float(np.nanmax(dmeas)) if np.isfinite(dmeas).any() else 0.0}
    return table


def reset_ms(domain, cases, n: int, seed: int) -> float:
    start = cases["push"][0]
    from sim_workers.configuration import Configuration
    config = Configuration.from_array(start)
    sizes = particle_sizes(domain, n, seed)
    with make_world(domain) as w:
        w.reset(config, {"block_sizes": sizes[0]})
        t0 = time.perf_counter()
        for row in sizes:
            w.reset(config, {"block_sizes": row})
        return (time.perf_counter() - t0) / n * 1e3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small batches, one round (< 1 minute)")
    ap.add_argument("--batch", type=int, default=None, help="particles per action (default 64, quick 32)")
    ap.add_argument("--rounds", type=int, default=None, help="rounds, best kept (default 3, quick 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--domain", default="container", metavar="NAME",
                    help=f"domain whose worlds are measured: {' or '.join(DOMAINS)} (default container)")
    args = ap.parse_args(argv)
    batch = args.batch or (32 if args.quick else 64)
    rounds = args.rounds or (2 if args.quick else 3)
    if batch < 2 or rounds < 1:
        ap.error("--batch must be at least 2 and --rounds at least 1")
    if args.domain not in DOMAINS:
        ap.error(f"--domain: no workload for {args.domain!r} (known: {', '.join(DOMAINS)})")
    name_d = args.domain
    t_start = time.perf_counter()

    domain = load(name_d)
    cases = make_cases(domain, args.seed)
    sizes = particle_sizes(domain, batch, args.seed + 1)
    halves = (slice(0, batch // 2), slice(batch // 2, batch))

    # (a) in-process, one world.
    shard = Shard(name_d, None, 1)
    local, steps, physics_share = {}, {}, {}
    for name in ACTIONS:
        start, action, traj, t0 = cases[name]
        shard.simulate(start, sizes[:2], action, traj, t0)          # warm up
        best = np.inf
        for _ in range(rounds):
            with StepTimer() as st:
                tic = time.perf_counter()
                out = shard.simulate(start, sizes, action, traj, t0)
                wall = time.perf_counter() - tic
            if wall < best:
                best, physics_share[name] = wall, st.total / wall
        local[name] = best
        steps[name] = out["steps"]
    local_node = shard.node()
    shard.close()
    leave = leave_out_table(name_d, cases, sizes, rounds)
    reset = reset_ms(domain, cases, 100 if args.quick else 300, args.seed + 2)

    # (c) raw stepping, 2 processes (before Ray starts, so nothing else competes).
    raw, raw_start = {}, {}
    pool = RawPool(2, name_d, domain.spec.n_blocks)
    try:
        pool.step([1000, 1000])                                     # warm up
        for name in ACTIONS:
            counts = [int(steps[name][h].sum()) for h in halves]
            raw[name] = min(pool.step(counts) for _ in range(rounds))
            raw_start[name] = min(pool.step(counts, "start", cases[name]) for _ in range(rounds))
    finally:
        pool.close()

    # (d) bare replay of the same physics, 2 processes: wall time = the slower half.
    import multiprocessing as mp

    replay = {}
    with mp.get_context("spawn").Pool(2) as rp:
        for name in ACTIONS:
            start, action, traj, t0 = cases[name]
            jobs = [(name_d, start, sizes[h], traj, t0, steps[name][h], action) for h in halves]
            best = np.inf
            for _ in range(rounds):
                tic = time.perf_counter()
                rp.map(_replay, jobs)
                best = min(best, time.perf_counter() - tic)
            replay[name] = best

    # (b) two shard actors on local Ray.
    import ray

    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    try:
        Actor = remote_shard(num_cpus=1)
        actors = [Actor.remote(name_d, None, 1) for _ in range(2)]
        ray.get([a.node.remote() for a in actors])                  # actors up, worlds built
        sharded = {}
        for name in ACTIONS:
            start, action, traj, t0 = cases[name]
            ray.get([a.simulate.remote(start, sizes[:2], action, traj, t0) for a in actors])
            best = np.inf
            for _ in range(rounds):
                tic = time.perf_counter()
                outs = ray.get([a.simulate.remote(start, sizes[h], action, traj, t0)
                                for a, h in zip(actors, halves)])
                best = min(best, time.perf_counter() - tic)
                got = np.concatenate([o["steps"] for o in outs])
                if not np.array_equal(got, steps[name]):
                    sys.exit(f"bench_worlds: {name}: actors' step counts differ from in-process")
            sharded[name] = best
        nodes = ray.get([a.node.remote() for a in actors])
    finally:
        ray.shutdown()

    # Report.
    print(f"bench_worlds: {name_d} domain, {batch} particles per action (sizes from the prior), "
          f"best of {rounds} round(s), {os.cpu_count()} cores, pybullet DIRECT, "
          f"dt {domain.spec.time_step:.5f} s, {domain.spec.solver_iterations} solver iterations")
    head = (f"{'action':<8}{'steps/pa':>9}{'in-proc':>9}{'physics':>9}{'ray x2':>9}{'raw x2':>9}"
            f"{'ray/raw':>9}{'raw@start':>11}{'ray/raw@start':>15}")
    print(head)
    print(f"{'':<8}{'':>9}{'pa/s':>9}{'share':>9}{'pa/s':>9}{'pa/s':>9}{'':>9}{'x2 pa/s':>11}")
    tot = {"local": 0.0, "ray": 0.0, "raw": 0.0, "start": 0.0}
    for name in ACTIONS:
        t = {"local": local[name], "ray": sharded[name], "raw": raw[name], "start": raw_start[name]}
        for k in tot:
            tot[k] += t[k]
        print(f"{name:<8}{steps[name].mean():>9.0f}{batch / t['local']:>9.1f}"
              f"{100 * physics_share[name]:>8.0f}%{batch / t['ray']:>9.1f}{batch / t['raw']:>9.1f}"
              f"{t['raw'] / t['ray']:>9.2f}{batch / t['start']:>11.1f}{t['start'] / t['ray']:>15.2f}")
    n_all = batch * len(ACTIONS)
    mean_steps = np.mean(np.concatenate([steps[n] for n in ACTIONS]))
    print(f"{'all':<8}{mean_steps:>9.0f}{n_all / tot['local']:>9.1f}{'':>9}{n_all / tot['ray']:>9.1f}"
          f"{n_all / tot['raw']:>9.1f}{tot['raw'] / tot['ray']:>9.2f}{n_all / tot['start']:>11.1f}"
          f"{tot['start'] / tot['ray']:>15.2f}")
    print("  physics share: time inside stepSimulation / in-process wall time (the rest: resets,")
    print("  per-step gripper commands, rest checks, Y^-1). raw x2: the scene as built, gripper")
    print("  static; raw@start x2: the scene put once in the action's start configuration, gripper")
    print("  static at the pre-pose (same contacts as the action starts with).")
    half_steps = sum(steps[n].sum() for n in ACTIONS) / 2
    physics_s = sum(physics_share[n] * local[n] for n in ACTIONS)
    print(f"raw stepping, per process: {1e6 * tot['raw'] / half_steps:.1f} us/step (as built), "
          f"{1e6 * tot['start'] / half_steps:.1f} us/step (at the start configurations); "
          f"in-process shard: {1e6 * tot['local'] / (2 * half_steps):.1f} us/step all included, "
          f"{1e6 * physics_s / (2 * half_steps):.1f} us/step inside stepSimulation")
    print(f"world reset (rebuild of the scene): {reset:.2f} ms")
    print(f"RSS per shard (peak, Shard.node()): in-process {local_node['rss_mb']:.0f} MB; "
          + "; ".join(f"actor pid {n['pid']} {n['rss_mb']:.0f} MB ({n['worlds']} world)" for n in nodes))
    rep = sum(replay.values())
    print("bare replay x2 (the same action physics and gripper commands, same steps, no framework):")
    for name in ACTIONS:
        print(f"  {name:<8}{batch / replay[name]:>7.1f} pa/s   ray/replay {replay[name] / sharded[name]:.2f}")
    print(f"  all     {n_all / rep:>7.1f} pa/s   ray/replay {rep / tot['ray']:.2f}")
    print("  raw x2 steps a resting scene, whose contacts converge in a few solver iterations;")
    print("  an action's moving contacts use all of them, so raw x2 is not reachable by any action.")
    print("(e) leave-out, in-process, same particles: every body (before) against the bodies the")
    print("    action can reach (after; sim_workers/reach.py, forced on for every action kind):")
    print(f"  {'action':<8}{'steps/pa':>9}{'before ms':>11}{'after ms':>10}{'speed-up':>10}"
          f"{'us/step':>9}{'->':>3}{'us/step':>8}{'reruns':>8}{'same Y^-1':>11}{'|dweighed|':>12}"
          f"{'|dmeas|':>10}{'adopted':>9}")
    for name in ACTIONS:
        e = leave[name]
        print(f"  {name:<8}{e['steps']:>9.0f}{1e3 * e['before'] / batch:>11.2f}{1e3 * e['after'] / batch:>10.2f}"
              f"{e['before'] / e['after']:>10.2f}{1e6 * e['before'] / e['steps_total']:>9.1f}{'':>3}"
              f"{1e6 * e['after'] / e['steps_total']:>8.1f}{e['reruns']:>8d}{e['same']:>11.3f}{e['dweighed']:>12.1e}"
              f"{e['dmeas']:>10.1e}{'yes' if e['adopted'] else 'no':>9}")
    before = sum(leave[n]["before"] for n in ACTIONS)
    after = sum(leave[n]["after" if leave[n]["adopted"] else "before"] for n in ACTIONS)
    print(f"  all three actions, as adopted: {1e3 * before / n_all:.2f} -> {1e3 * after / n_all:.2f} ms per "
          f"particle-action (x{before / after:.2f})")
    print(f"wall time {time.perf_counter() - t_start:.1f} s")
    # The headline compares with the physical limit of this very work: raw pybullet stepping
    # of the same scene, in the same states, for the same steps, in 2 plain processes (the
    # bare replay). The resting-scene figure is printed for reference, not as the limit.
    print(f"ratio_vs_static_scene={tot['raw'] / tot['ray']:.3f}")
    print(f"ratio_vs_raw={rep / tot['ray']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
