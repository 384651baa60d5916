"""`tmoc probe`: seeded physics trials of one action, to check a domain's physics.

    tmoc probe --domain container --action pickup --true-size 0.045 --believed-size 0.034 \\
        --trials 20 --seed 0 [--json]

Each trial builds a world with true block size S, jitters block placement (a few mm) and
friction (about 10 %) from the seed, takes the action's poses from Y with the believed
size B (default S) and reads the outcome through Y^-1. `--load K` is the number of blocks
in the container for `push` (piled as Y piles them at B: the container's two columns or
one) and the number of blocks stacked for `stack`.

`--robot ur5e` has the trials' actions done by the arm (`tmoc robots`): each action's joint
path planned from where the last one left the arm, its links moving in the world, tracked
as the simulated arm reality tracks it; an action the arm cannot do fails the trial.

Mass in Y (stack_and_push): `--true-density` sets the blocks' density in the world and
`--believed-density` the density Y sizes the grip force and the push's force limit from
(too light a belief: the block slips on the lift, the push stalls; too heavy: the push
throws the tower), e.g.

    tmoc probe --domain stack_and_push --action push --load 4 --true-size 0.045 \
        --true-density 2400 --believed-density 1650 --trials 12
"""
from __future__ import annotations

import argparse
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
                        "stack_and_push: pickup, stack, push, stand, built_stack, built_push: "
                        "onto / of a tower the agent's own actions built, as T* probes it, and "
                        "rail_pickup: a block lying on the rail with --load 0-2 beside it)")
    p.add_argument("--truth", action="append", default=None, metavar="NAME=VALUE[,NAME=VALUE]",
                   help="the probed world's hidden truth by the names of L (`tmoc domains`), e.g. "
                        "size=0.045 or friction=0.6 (default: the domain's default truth)")
    p.add_argument("--belief", action="append", default=None, metavar="NAME=VALUE[,NAME=VALUE]",
                   help="what Y believes, by the names of L (default: the truth); a belief the "
                        "domain's probe does not read is refused")
    p.add_argument("--true-size", type=float, default=None, metavar="S",
                   help="--truth size=S: the true block side length in the world (m)")
    p.add_argument("--believed-size", type=float, default=None, metavar="B",
                   help="--belief size=B: the block size Y computes the poses from (m)")
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
    p.add_argument("--robot", default="gripper", metavar="NAME",
                   help="the robot that does the trials' actions (`tmoc robots`; default gripper): an arm "
                        "plans each action's joint path from where the last one left it and its links "
                        "move in the world, tracked as the simulated arm reality tracks it; an action it "
                        "cannot do fails the trial")
    p.add_argument("--perception-sigma", type=float, default=0.0, metavar="M",
                   help="Y reads the objects' planar positions with N(0, M^2) per axis, drawn afresh "
                        "for each action, as `tmoc run`'s noisy reality reports them "
                        "(its --perception-sigma); default 0: exactly")
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


def _pairs(flag: str, items: list[str] | None) -> dict[str, float]:
    """``["size=0.04,density=2400"]`` -> {"size": 0.04, "density": 2400.0}; UsageError naming `flag`."""
    out: dict[str, float] = {}
    for item in items or []:
        for pair in filter(None, item.split(",")):
            name, sep, value = pair.partition("=")
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if not sep or not name.strip() or not math.isfinite(number):
                raise UsageError(f"{flag} {pair}: expected NAME=NUMBER")
            out[name.strip()] = number
    return out


def _with_alias(flag: str, values: dict, name: str, alias: str, value: float | None,
                spelled: dict) -> None:
    """`value` of an alias flag into `values[name]`; `spelled` notes the flag the user typed."""
    if value is None:
        return
    if name in values and values[name] != value:
        raise UsageError(f"{alias}: {value:g} disagrees with {flag} {name}={values[name]:g}")
    values[name] = value
    spelled[(flag, name)] = alias


def run(args: argparse.Namespace) -> int:
    from sim_workers import domains
    from sim_workers.probe import probe, probe_actions, probe_keywords, probe_loads

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
    if args.trials < 1:
        raise UsageError(f"--trials: {args.trials} must be at least 1")
    if args.seed < 0:
        raise UsageError(f"--seed: {args.seed} must not be negative")
    if not (math.isfinite(args.perception_sigma) and 0.0 <= args.perception_sigma <= 0.05):
        raise UsageError(f"--perception-sigma: {args.perception_sigma!r} must be within [0, 0.05] m")

    from coordinator.domains import checked_options, options_of

    from .run import parse_options

    try:
        options, world_domain = checked_options(args.domain, parse_options(args.options))
    except ValueError as exc:
        raise UsageError(f"--option: {exc}") from None
    n_blocks = world_domain.spec.n_blocks
    loads = probe_loads(world_domain, args.action)
    if args.load not in loads:
        raise UsageError(f"--load: {args.load} is outside {loads.start}..{loads.stop - 1} "
                         f"for {args.action}")
    L = world_domain.L
    truth, belief = _pairs("--truth", args.truth), _pairs("--belief", args.belief)
    spelled: dict[tuple[str, str], str] = {}     # (--truth|--belief, name) -> the alias typed

    def _flag(flag: str, name: str) -> str:
        """How the user wrote a truth or belief: its alias (``--believed-density``) or ``--belief NAME``."""
        return spelled.get((flag, name), f"{flag} {name}")

    for flag, values, alias, value, checked in (
            ("--truth", truth, "--true-size", args.true_size, _check_size),
            ("--belief", belief, "--believed-size", args.believed_size, _check_size),
            ("--truth", truth, "--true-density", args.true_density, _check_density),
            ("--belief", belief, "--believed-density", args.believed_density, _check_density)):
        _with_alias(flag, values, alias.split("-")[-1], alias, None if value is None else checked(alias, value),
                    spelled)
    for flag, values in (("--truth", truth), ("--belief", belief)):
        if "size" in values:
            _check_size(f"{flag} size", values["size"])
    if "size" not in L.names:
        for flag, given in (("--true-size", args.true_size), ("--believed-size", args.believed_size)):
            if given is not None:
                raise UsageError(f"{flag}: the {args.domain} domain has no size in L (properties: "
                                 f"{', '.join(L.names)}); set --truth/--belief NAME=VALUE")
    takes = probe_keywords(world_domain)
    floats = {k for k, v in options_of(world_domain).items() if isinstance(v, float)}
    # A truth outside L that the physics holds as an option (the density without
    # unknown_density) is the probed world's option, as in `tmoc run`.
    for name in [n for n in truth if n not in L.names]:
        if name not in floats:
            raise UsageError(f"{_flag('--truth', name)}: not a property of L for domain {args.domain!r} "
                             f"(properties: {', '.join(L.names)})")
        options[name] = truth.pop(name)
    for name in truth:
        if name != "size" and not ({"*", "truth"} & takes) and name not in floats:
            raise UsageError(f"{_flag('--truth', name)}: the {args.domain} domain's probe does not read it")
        if name != "size" and name in floats and not ({"*", "truth"} & takes):
            options[name] = truth[name]
    for name in belief:
        if name not in L.names and f"believed_{name}" not in takes:
            raise UsageError(f"{_flag('--belief', name)}: the {args.domain} domain's probe does not read a "
                             f"belief of {name}: it is not a property of L (properties: {', '.join(L.names)}) "
                             f"and does not enter Y")
        if name != "size" and not ({"*", "belief"} & takes) and f"believed_{name}" not in takes:
            raise UsageError(f"{_flag('--belief', name)}: the {args.domain} domain's probe does not read a belief of it")
    try:
        options, world_domain = checked_options(args.domain, options)
    except ValueError as exc:
        raise UsageError(f"--truth: {exc}") from None
    defaults = dict(zip(L.names, map(float, L.truth)))
    full_truth = {**defaults, **truth, **{n: float(options[n]) for n in L.names if n in options and n not in truth}}
    full_belief = {**full_truth, **{n: v for n, v in belief.items() if n in L.names}}
    from sim_workers.properties import PropertyError

    for flag, row in (("--truth", full_truth), ("--belief", full_belief)):
        try:
            world_domain.properties(world_domain.props_from_row(L.truth_row(row, n_blocks, False)))
        except PropertyError as exc:
            raise UsageError(f"{flag} {str(exc).removeprefix('truth.')}") from None
    # A belief the probe reads by its own keyword (stack_and_push: believed_density).
    believed_kw = {f"believed_{n}": v for n, v in belief.items() if f"believed_{n}" in takes}
    believed_density = believed_kw.pop("believed_density", None)
    if believed_density is not None:
        _check_density(_flag("--belief", "density"), believed_density)
    from sim_workers.engines import EngineError, check_engine

    try:
        engine = check_engine(args.engine, "--engine")
    except EngineError as exc:
        raise UsageError(str(exc)) from None
    options["engine"] = engine
    from coordinator.robots import RobotError, fits, names, options_for

    try:
        fitting = fits(args.robot, world_domain)
    except RobotError:
        raise UsageError(f"--robot: no robot {args.robot!r} (known: {', '.join(names())}; tmoc robots)") from None
    if not fitting:
        raise UsageError(f"--robot: the {args.domain} domain declares no robot_base, so the arm "
                         f"{args.robot!r} has nowhere to stand")
    options = options_for(args.robot, world_domain, options)
    sized = "size" in L.names
    true_size = full_truth["size"] if sized else math.nan
    believed = full_belief["size"] if sized else math.nan
    from coordinator.loop.arm_trials import with_robot

    try:
        with with_robot(args.robot) as doing:
            result = probe(args.action, true_size, believed, load_k=args.load, trials=args.trials,
                           seed=args.seed, n_blocks=n_blocks, domain=args.domain, options=options,
                           believed_density=believed_density, truth=full_truth, belief=full_belief,
                           believed_kw=believed_kw, perception_m=args.perception_sigma)
        doing.check_used(args.domain)
    except ValueError as exc:
        if str(exc).startswith("robot:"):
            raise UsageError(f"--robot: {str(exc).split(': ', 1)[1]}") from None
        if str(exc).startswith("believed_density:"):
            raise UsageError(f"--believed-density: {str(exc).split(': ', 1)[1]}") from None
        raise
    if args.json:
        out = {"domain": args.domain, **result.to_dict(), "seed": args.seed, "n_blocks": n_blocks,
               "engine": engine, "truth": full_truth, "belief": full_belief, "robot": args.robot,
               "perception_sigma": args.perception_sigma}
        if not sized:
            out["true_size"] = out["believed_size"] = None
        print(json.dumps(out, sort_keys=True))
        return 0
    load = f", load {result.load}" if args.action != "pickup" else ""
    dens = ""
    if result.true_density is not None:
        dens = f", density {result.true_density:g}"
        if result.believed_density is not None:
            dens += f" believed {result.believed_density:g}"
        dens += " kg/m^3"
    if sized:
        what = f"true size {true_size:g} m, believed {believed:g} m"
    else:
        what = ("truth " + ", ".join(f"{n}={v:g}" for n, v in full_truth.items())
                + "; belief " + ", ".join(f"{n}={v:g}" for n, v in full_belief.items()))
    print(f"{args.domain} {args.action}: {result.successes}/{result.trials} succeeded, "
          f"success rate {result.success_rate:.3f} ({what}{load}{dens}, seed {args.seed}"
          f"{', engine ' + engine if args.engine else ''}"
          f"{', robot ' + args.robot if args.robot != 'gripper' else ''}"
          f"{f', perception {args.perception_sigma * 1000:g} mm' if args.perception_sigma else ''})")
    return 0
