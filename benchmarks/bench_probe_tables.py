"""Every probe table of docs/BUILTIN_DOMAINS.md in both engines, same seeds (issue 27).

Each row is one ``tmoc probe`` (``sim_workers.probe.probe``) with the settings of the pages,
run in pybullet and in MuJoCo; printed as a markdown table with both counts side by side
(and JSON with ``--json FILE``). A claim that does not hold in MuJoCo shows here, with
the same seeded trials (placement and friction jitter are drawn before the engine is
chosen, so both engines face the same worlds).

    python benchmarks/bench_probe_tables.py                 # about 10 minutes on 2 cores
    python benchmarks/bench_probe_tables.py --json docs/results/probe-tables.json
"""
from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor

from sim_workers.engines import ENGINES
from sim_workers.probe import probe

C, SP = "container", "stack_and_push"


def row(table: str, label: str, domain: str, action: str, size: float, trials: int, seed: int, **kw):
    """(table, row label, probe kwargs)."""
    return table, label, dict(domain=domain, action=action, true_size=size, trials=trials, seed=seed, **kw)


T1, T2, T3 = "container (--seed 1)", "container, 54 mm (--seed 0)", "container, 60 mm (--seed 0)"
T4 = "stack_and_push, 40 mm (--seed 0)"
T5, T6 = "weights, 45 mm, 2400 kg/m^3 (--seed 0)", "weights, 45 mm, 700 kg/m^3 (--seed 0)"
HEAVY = {"density": 2400.0}
# The pages' settings, row by row.
ROWS = [
    row(T1, "pickup, believed = true 45 mm", C, "pickup", 0.045, 20, 1),
    *[row(T1, f"pickup, believed {b * 1000:.1f} mm", C, "pickup", 0.045, 16, 1, believed_size=b)
      for b in (0.0315, 0.03375, 0.05625, 0.0585)],
    row(T1, "pickup, a 30 mm block believed 50 mm (1.67 x)", C, "pickup", 0.030, 16, 1, believed_size=0.050),
    row(T1, "stack the first 4 blocks, true size", C, "stack", 0.045, 12, 1, load_k=4),
    *[row(T1, f"push with {k} blocks loaded", C, "push", 0.045, 16, 1, load_k=k) for k in (2, 4, 6, 8)],
    *[row(T2, f"stack {k} blocks", C, "stack", 0.054, 10, 0, load_k=k) for k in (2, 4, 6)],
    *[row(T2, f"push {k} blocks", C, "push", 0.054, 10, 0, load_k=k) for k in (2, 3, 4)],
    row(T3, "stack 4 blocks", C, "stack", 0.060, 10, 0, load_k=4),
    row(T4, "pickup, believed = true 40 mm", SP, "pickup", 0.040, 16, 0),
    *[row(T4, f"pickup, believed {b * 1000:.0f} mm", SP, "pickup", 0.040, 16, 0, believed_size=b) for b in (0.050, 0.030)],
    row(T4, "pickup, a 30 mm block believed 50 mm (1.67 x)", SP, "pickup", 0.030, 16, 0, believed_size=0.050),
    row(T4, "stack onto a tower of 4, true size", SP, "stack", 0.040, 16, 0, load_k=4),
    row(T4, "tower of 8 left alone 2 s", SP, "stand", 0.040, 16, 0, load_k=8),
    *[row(T4, f"push a tower of {k}", SP, "push", 0.040, 16, 0, load_k=k) for k in range(1, 9)],
    *[row(T5, f"pickup, believed {d:g} kg/m^3", SP, "pickup", 0.045, 16, 0, options=HEAVY, believed_density=d)
      for d in (1000.0, 1300.0, 1650.0, 2400.0, 3000.0)],
    *[row(T5, f"push a tower of 4, believed {d:g} kg/m^3", SP, "push", 0.045, 16, 0, load_k=4, options=HEAVY,
          believed_density=d) for d in (1200.0, 1650.0, 2000.0, 2400.0, 3000.0)],
    *[row(T6, f"push a tower of 6, believed {d:g} kg/m^3", SP, "push", 0.045, 16, 0, load_k=6, believed_density=d)
      for d in (300.0, 700.0, 1650.0, 3000.0)],
]


def one(job) -> int:
    kwargs, engine = job
    kw = dict(kwargs)
    action, true_size = kw.pop("action"), kw.pop("true_size")
    believed = kw.pop("believed_size", None)
    options = {**kw.pop("options", {}), "engine": engine}
    return probe(action, true_size, believed, options=options, **kw).successes


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--json", default=None, metavar="FILE")
    p.add_argument("--workers", type=int, default=2)
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    jobs = [(kw, e) for _, _, kw in ROWS for e in ENGINES]
    with ProcessPoolExecutor(args.workers) as pool:
        counts = list(pool.map(one, jobs))
    rows = []
    for k, (table, label, kw) in enumerate(ROWS):
        pb, mj = counts[2 * k], counts[2 * k + 1]
        rows.append({"table": table, "probe": label, "trials": kw["trials"], "pybullet": pb, "mujoco": mj})
    current = None
    for r in rows:
        if r["table"] != current:
            current = r["table"]
            print(f"\n{current}\n\n| probe | trials | pybullet | MuJoCo |\n|---|---|---|---|")
        flag = "" if abs(r["pybullet"] - r["mujoco"]) <= max(2, r["trials"] // 5) else " **differs**"
        print(f"| {r['probe']} | {r['trials']} | {r['pybullet']} | {r['mujoco']}{flag} |")
    print(f"\n{len(ROWS)} probes x 2 engines in {time.perf_counter() - t0:.0f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"rows": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
