"""`tmoc probe`: seeded physics trials of one action, to check a domain's physics.

    tmoc probe --domain container --action pickup --true-size 0.045 --believed-size 0.034 \\
        --trials 20 --seed 0 [--json]

Each trial builds a world with true block size S, jitters block placement (a few mm) and
friction (about 10 %) from the seed, takes the action's poses from Y with the believed
size B (default S) and reads the outcome through Y^-1. `--load K` is the number of blocks
in the container for `push` and the number of blocks stacked for `stack`.

Mass in Y (stack_and_push): `--true-density` sets the blocks' density in the world and
`--believed-density` the density Y sizes the grip force and the push's force limit from
(too light a belief: the block slips on the lift, the push stalls; too heavy: the push
throws the tower), e.g.

    tmoc probe --domain stack_and_push --action push --load 4 --true-size 0.045 \
        --true-density 2400 --believed-density 1650 --trials 12
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math

from sim_workers.domains import DEFAULT_DOMAIN

from . import UsageError

ACTIONS = ("pickup", "stack", "push")   # the container's; each domain lists its own (stack_and_push adds stand)
DEFAULT_LOAD = 4


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "probe", help="run seeded physics trials of one action and print its success rate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Example: tmoc probe --domain container --action push --true-size 0.045 "
               "--load 8 --trials 20 --seed 1 --json")
    p.add_argument("--domain", default=DEFAULT_DOMAIN, metavar="NAME",
                   help="domain to probe (default: container)")
    p.add_argument("--action", required=True, metavar="ACTION",
                   help="the domain's probe actions (container: pickup, stack, push; "
                        "stack_and_push: pickup, stack, push, stand, and built_stack, built_push: "
                        "onto / of a tower the agent's own actions built, as T* probes it)")
    p.add_argument("--true-size", required=True, type=float, metavar="S",
                   help="true block side length in the world (m)")
    p.add_argument("--believed-size", type=float, default=None, metavar="B",
                   help="block size Y computes the poses from (m; default: the true size)")
    p.add_argument("--load", type=int, default=DEFAULT_LOAD, metavar="K",
                   help="container: blocks loaded (push) or stacked (stack); stack_and_push: the "
                        "tower height before a stack (0..N-1), pushed or left alone (1..N); "
                        f"default {DEFAULT_LOAD}")
    p.add_argument("--true-density", type=float, default=None, metavar="RHO",
                   help="the blocks' density in the world (kg/m^3; stack_and_push; default the "
                        "domain's, 700)")
    p.add_argument("--believed-density", type=float, default=None, metavar="RHO",
                   help="the density Y believes (kg/m^3): the grip force and the push's force "
                        "limit come from the believed mass (stack_and_push; default: mass does "
                        "not enter Y)")
    p.add_argument("--option", action="append", default=None, metavar="KEY=VALUE", dest="options",
                   help="a domain option of the probed world, repeatable (`tmoc domains`), e.g. "
                        "--option true_friction=0.6 for the chute, whose truth is not a size")
    p.add_argument("--engine", default=None, metavar="pybullet|mujoco",
                   help="the physics engine of the trials (default: pybullet where installed, else mujoco)")
    p.add_argument("--trials", type=int, default=20, metavar="N", help="number of trials (default 20)")
    p.add_argument("--seed", type=int, default=0, metavar="SEED", help="random seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a line")
    p.set_defaults(func=run)


def _check_size(flag: str, value: float) -> float:
    from sim_workers.properties import MAX_SIZE_M, MIN_SIZE_M

    if not math.isfinite(value):
        raise UsageError(f"{flag}: {value!r} is not a finite number")
    if not MIN_SIZE_M <= value <= MAX_SIZE_M:
        raise UsageError(f"{flag}: {value!r} m is outside the property range "
                         f"[{MIN_SIZE_M}, {MAX_SIZE_M}] m")
    return value


def _check_density(flag: str, value: float) -> float:
    from sim_workers.properties import MAX_DENSITY, MIN_DENSITY

    if not math.isfinite(value):
        raise UsageError(f"{flag}: {value!r} is not a finite number")
    if not MIN_DENSITY <= value <= MAX_DENSITY:
        raise UsageError(f"{flag}: {value!r} kg/m^3 is outside [{MIN_DENSITY:g}, {MAX_DENSITY:g}] kg/m^3")
    return value


def run(args: argparse.Namespace) -> int:
    from sim_workers import domains
    from sim_workers.probe import probe, probe_actions, probe_loads

    known = domains.names()
    if args.domain not in known:
        raise UsageError(f"--domain: unknown domain {args.domain!r} (known: {', '.join(known)})")
    actions = probe_actions(args.domain)
    if not actions:
        available = [d for d in known if probe_actions(d)]
        raise UsageError(f"--domain: probing is not available for {args.domain!r} "
                         f"(available: {', '.join(available)})")
    if args.action not in actions:
        raise UsageError(f"--action: {args.action!r} is not one of {', '.join(actions)}")
    true_size = _check_size("--true-size", args.true_size)
    believed = true_size if args.believed_size is None else _check_size("--believed-size", args.believed_size)
    world_domain = domains.load(args.domain)
    n_blocks = world_domain.spec.n_blocks
    loads = probe_loads(world_domain, args.action)
    if args.load not in loads:
        raise UsageError(f"--load: {args.load} is outside {loads.start}..{loads.stop - 1} "
                         f"for {args.action}")
    if args.trials < 1:
        raise UsageError(f"--trials: {args.trials} must be at least 1")
    if args.seed < 0:
        raise UsageError(f"--seed: {args.seed} must not be negative")

    from coordinator.domains import checked_options

    from .run import parse_options

    try:
        options, _ = checked_options(args.domain, parse_options(args.options), n_blocks)
    except ValueError as exc:
        raise UsageError(f"--option: {exc}") from None
    for flag, value in (("--true-density", args.true_density), ("--believed-density", args.believed_density)):
        if value is not None:
            _check_density(flag, value)
            if "density" not in {f.name for f in dataclasses.fields(world_domain.spec)}:
                raise UsageError(f"{flag}: the {args.domain} domain has no block density to set")
    if args.true_density is not None:
        options["density"] = args.true_density
    from sim_workers.engines import EngineError, check_engine

    try:
        engine = check_engine(args.engine, "--engine")
    except EngineError as exc:
        raise UsageError(str(exc)) from None
    options["engine"] = engine
    try:
        result = probe(args.action, true_size, believed, load_k=args.load, trials=args.trials,
                       seed=args.seed, n_blocks=n_blocks, domain=args.domain, options=options,
                       believed_density=args.believed_density)
    except ValueError as exc:
        if str(exc).startswith("believed_density:"):
            raise UsageError(f"--believed-density: {str(exc).split(': ', 1)[1]}") from None
        raise
    if args.json:
        out = {"domain": args.domain, **result.to_dict(), "seed": args.seed, "n_blocks": n_blocks,
               "engine": engine}
        print(json.dumps(out, sort_keys=True))
        return 0
    load = f", load {result.load}" if args.action != "pickup" else ""
    dens = ""
    if result.true_density is not None:
        dens = f", density {result.true_density:g}"
        if result.believed_density is not None:
            dens += f" believed {result.believed_density:g}"
        dens += " kg/m^3"
    print(f"{args.domain} {args.action}: {result.successes}/{result.trials} succeeded, "
          f"success rate {result.success_rate:.3f} (true size {true_size:g} m, "
          f"believed {believed:g} m{load}{dens}, seed {args.seed}"
          f"{', engine ' + engine if args.engine else ''})")
    return 0
