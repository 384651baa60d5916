"""The coordinator's own serial time per particle per action, physics excluded.

    python benchmarks/bench_coordinator.py [--domain container] [--option KEY=VALUE ...] [--repeats 5]

Before each action the coordinator computes Y for every particle and the real pose x (the
heaviest mode of the belief); after it, it scores the particles' outcomes (symbolic match
and measurement likelihood), reweights, adds the simulated experience and resamples.
That serial part caps how far particles scale over a cluster (Amdahl). Measured here at
N = 100, 1000 and 5000 with the shard results replayed from one real simulation (the
physics is excluded on purpose), once with the per-particle Y loop (the old path) for
the ratio. Prints ``coordinator_us_per_particle=`` per N and its parts (Y, the pose mode,
the KLD budget's count, and reweighting with experience and resampling).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from coordinator.particle_filter.belief import Belief, mode_mask  # noqa: E402
from coordinator.commands.run import parse_options  # noqa: E402
from coordinator.loop.real_pose import mode_scale  # noqa: E402
from coordinator.loop.reality import Observation  # noqa: E402
from coordinator.run_config import RunConfig  # noqa: E402
from coordinator.loop.session import PendingStep, Session  # noqa: E402
from sim_workers.shard import Shard, decode_state  # noqa: E402


def one_action(session: Session, start: Observation, action: str, res: dict, loop_y: bool) -> dict:
    """Seconds of each coordinator part of one action (no physics, no planning)."""
    t = {}
    config = start.configuration
    t0 = time.perf_counter()
    if loop_y:
        poses = np.array([session.domain.action_pose(session.props_of(s), config, action)
                          for s in session.belief.particles])
    else:
        poses = session.domain.action_poses(session.belief.particles, config, action)
    t["y"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    b = session.belief
    keep = mode_mask(b.particles, b.weights, session.config.mode_bandwidth, scale=mode_scale(session.low, session.high))
    Belief(b.particles[keep], b.log_weights[keep], b.low, b.high).weighted_mean(poses[keep], angular=(3,))
    t["mode"] = time.perf_counter() - t0
    expected = session.task.apply(start.state, action)
    step = PendingStep(action, poses[0], np.zeros((2, 6)), expected, 0.0, poses)
    t0 = time.perf_counter()
    states = [decode_state(s) for s in res["states"]]
    loglik = session._symbolic_loglik(step, expected, states)
    session.reweighting.weigh(session.belief, action, loglik, res["measurements"][0], res["measurements"])
    session.experience.add_simulated(start.state, action, states, expected, session.belief.weights)
    session.reweighting.resample(session.belief, session.rng, action)
    t["reweight"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    session.filter.kld_count()
    t["budget"] = time.perf_counter() - t0
    return t


def measure(domain: str, options: dict, sizes: list[int], repeats: int,
            with_loop: bool = True) -> tuple[dict[int, float], float]:
    """Prints the coordinator's time per particle per action at each N in `sizes` (prior
    and converged belief; with `with_loop`, the old per-particle Y loop too); returns
    ({N: ms per action, prior belief}, ms of physics per particle-action of the action)."""
    base = Session(RunConfig(domain=domain, particles=8, seed=0, options=options))
    truth = base.domain.true_properties()
    config = base.domain.initial_configuration(truth)
    start = Observation(config, base.domain.symbolic_state(config), base.domain.measurements(config))
    action = base.task.plan(start.state, base.task.optimistic_transition(base.n_blocks)).actions[0]
    # One real simulation of 8 particles, tiled to N (the physics is not what is measured).
    shard = Shard(domain, {"n_blocks": base.n_blocks, **options})
    key = base.domain.action_pose(truth, config, action)
    traj = base.domain.action_trajectory(config, action, key)
    t_pre = base.domain.transit_end_time(config, action, key)
    t0 = time.perf_counter()
    real = shard.simulate(config.to_array(), base.belief.particles, action, traj, t_pre)
    phys_ms = (time.perf_counter() - t0) / len(base.belief.particles) * 1e3
    shard.close()
    per_action_ms: dict[int, float] = {}
    for n in sizes:
        reps = np.arange(n) % len(real["states"])
        res = {"states": real["states"][reps], "measurements": real["measurements"][reps]}
        for loop_y, belief in ([(False, "prior"), (False, "converged")]
                               + ([(True, "prior")] if n <= 1000 and with_loop else [])):
            parts = {"y": [], "mode": [], "budget": [], "reweight": []}
            for r in range(repeats):
                session = Session(RunConfig(domain=domain, particles=n, seed=r, options=options,
                                            particle_budget="kld"))
                if belief == "converged":      # 1 % of the prior wide (0.3 mm of size), as after an episode or two
                    b = session.belief
                    half = 0.005 * (b.high - b.low)
                    b.particles = session.truth_row() + session.rng.uniform(-half, half, b.particles.shape)
                for k, v in one_action(session, start, action, res, loop_y).items():
                    parts[k].append(v)
            med = {k: float(np.median(v)) for k, v in parts.items()}
            total = sum(med.values())
            label = ("per-particle Y loop (before)" if loop_y else "vectorised Y") + f", {belief} belief"
            print(f"N={n} {label}: coordinator_us_per_particle={total / n * 1e6:.1f} "
                  f"(Y {med['y'] / n * 1e6:.2f}, mode {med['mode'] / n * 1e6:.2f}, "
                  f"budget {med['budget'] / n * 1e6:.2f}, "
                  f"reweight+experience+resample {med['reweight'] / n * 1e6:.2f} us) "
                  f"per action {total * 1e3:.1f} ms", flush=True)
            if not loop_y and belief == "prior":
                per_action_ms[n] = total * 1e3
    return per_action_ms, phys_ms


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--domain", default="container")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--sizes", default="100,1000,5000")
    ap.add_argument("--option", action="append", default=[], metavar="KEY=VALUE",
                    help="a domain option, as on tmoc run (e.g. unknown_density=true)")
    args = ap.parse_args()
    per_action_ms, phys_ms = measure(args.domain, parse_options(args.option),
                                     [int(v) for v in args.sizes.split(",")], args.repeats)
    amdahl(per_action_ms, phys_ms, *ray_call_costs())
    return 0


def ray_call_costs(calls: int = 200) -> tuple[float, float]:
    """(ms of the coordinator's time to submit one shard call, ms of one round trip) on
    local Ray: what each action pays per shard and once, on top of the particles."""
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)

    @ray.remote
    class Echo:
        def simulate(self, a):
            return a

    actor = Echo.remote()
    payload = np.zeros((8, 6))
    ray.get(actor.simulate.remote(payload))
    t0 = time.perf_counter()
    refs = [actor.simulate.remote(payload) for _ in range(calls)]
    submit = (time.perf_counter() - t0) / calls
    ray.get(refs)
    trips = []
    for _ in range(50):
        t0 = time.perf_counter()
        ray.get(actor.simulate.remote(payload))
        trips.append(time.perf_counter() - t0)
    ray.shutdown()
    return submit * 1e3, float(np.median(trips)) * 1e3


CORES = (16, 64, 256, 1024)


def action_ms(n: int, cores: int, coord_ms: float, trip_ms: float, call_ms: float, phys_ms: float,
              dispatch: str = "node", cores_per_node: int = 16, node_call_ms: float | None = None) -> float:
    """Predicted milliseconds of one action of `n` particles on `cores` cores, one shard per
    core: the coordinator's serial time, the physics of ceil(n / cores) particle-actions,
    and the Ray calls. dispatch "shard": the driver submits one call per shard (`cores`
    calls) and waits one round trip. dispatch "node": the driver submits one call per node
    (cores / cores_per_node), each node's dispatcher submits its cores_per_node shard calls
    (the nodes at once), two round trips."""
    physics = math.ceil(n / cores) * phys_ms
    if dispatch == "shard" or cores == 1:
        return coord_ms + trip_ms + cores * call_ms + physics
    nodes = math.ceil(cores / cores_per_node)
    per_node = min(cores, cores_per_node)
    node_call = call_ms if node_call_ms is None else node_call_ms
    return coord_ms + 2 * trip_ms + nodes * call_ms + per_node * node_call + physics


def efficiency(n: int, cores: int, coord_ms: float, trip_ms: float, call_ms: float, phys_ms: float,
               **kw) -> float:
    """Throughput on `cores` cores over `cores` x the throughput of one core (one call,
    all n particle-actions)."""
    one = action_ms(n, 1, coord_ms, trip_ms, call_ms, phys_ms)
    return one / (cores * action_ms(n, cores, coord_ms, trip_ms, call_ms, phys_ms, **kw))


def amdahl(per_action_ms: dict[int, float], phys_ms: float, call_ms: float, trip_ms: float,
           node_call_ms: float | None = None, cores_per_node: int = 16) -> None:
    """Predicted efficiency at 16 to 1024 cores (nodes of `cores_per_node`), one call per
    shard (before issue 42) and one call per node (now)."""
    node_call_ms = call_ms if node_call_ms is None else node_call_ms
    print(f"Amdahl (measured: physics {phys_ms:.1f} ms per particle-action of this action, "
          f"driver call {call_ms * 1e3:.0f} us to submit, dispatcher call {node_call_ms * 1e3:.0f} us, "
          f"round trip {trip_ms:.2f} ms; nodes of {cores_per_node} cores):")
    for n, coord in per_action_ms.items():
        for dispatch in ("shard", "node"):
            kw = {"dispatch": dispatch, "cores_per_node": cores_per_node, "node_call_ms": node_call_ms}
            effs = " ".join(f"efficiency_{c}={efficiency(n, c, coord, trip_ms, call_ms, phys_ms, **kw):.2f}"
                            for c in CORES)
            print(f"  N={n} one call per {dispatch}: coordinator {coord:.1f} ms + physics "
                  f"{n * phys_ms:.0f} ms per action on one core; {effs}")


if __name__ == "__main__":
    sys.exit(main())
