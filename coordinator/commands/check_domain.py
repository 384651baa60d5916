"""`tmoc check-domain NAME`: the conformance checks of a domain (the same the test suite
runs for every registered domain): initial state well formed and not a goal, `place`
keeps Y^-1 across the prior, refused properties name the field, bit-identical results in
fresh worlds, with a past and on two Ray actors, the planner reaches the goal with an
objective equal to the Python expected utility, Y finite and in the workspace, and the
measurement channels. Exit 0 when all pass, 1 naming each failed check."""
from __future__ import annotations

import argparse
import json

from . import UsageError


def register(sub) -> None:
    p = sub.add_parser("check-domain", help="run the conformance checks of a domain",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", metavar="NAME", help="a registered domain (see tmoc domains)")
    p.add_argument("--no-ray", action="store_true",
                   help="skip the two-Ray-actor part of the determinism check")
    p.add_argument("--engine", default=None, metavar="pybullet|mujoco",
                   help="the physics engine the worlds are built in (default: pybullet where installed)")
    p.add_argument("--robot", default=None, metavar="NAME",
                   help="also check that this robot (ur5e, a plugin's arm) stands where the domain declares "
                        "(robot_base) and plans the first action's tool path from there at the prior's ends")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=main)


def main(args) -> int:
    from coordinator.conformance import check_domain
    from coordinator.domains import names

    known = names()
    if args.name not in known:
        raise UsageError(f"NAME: unknown domain {args.name!r} (known: {', '.join(known)})")
    from sim_workers.engines import EngineError, check_engine

    try:
        engine = check_engine(args.engine, "--engine")
    except EngineError as exc:
        raise UsageError(str(exc)) from None
    if args.robot is not None:
        from sim_workers.robots import RobotError, robot

        try:
            robot(args.robot)
        except RobotError as exc:
            raise UsageError(f"--robot: {exc}") from None
    results = check_domain(args.name, ray_actors=not args.no_ray, engine=engine, robot=args.robot)
    failed = [r for r in results if not r.ok]
    if args.json:
        print(json.dumps({"domain": args.name, "engine": engine, "ok": not failed,
                          "checks": [r.to_dict() for r in results]}, indent=2))
    else:
        for r in results:
            print(f"{'ok  ' if r.ok else 'FAIL'} {r.name:<20} {r.detail}  ({r.seconds:.2f} s)")
        print(f"{args.name} ({engine}): {len(results) - len(failed)}/{len(results)} checks passed"
              + (f"; failed: {', '.join(r.name for r in failed)}" if failed else ""))
    return 1 if failed else 0
