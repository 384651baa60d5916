"""`tmoc robots [--json]`: every registered robot (built-in or installed plugin): its joints
with their limits, and for an arm its Denavit-Hartenberg parameters, base pose, flange-to-tool
transform and home, so that a client can check a trajectory with its own kinematics; then
every installed plugin left out as broken, with why (JSON: "broken")."""
from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    p = sub.add_parser("robots", help="list the registered robots (built-in and plugins)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=main)


def _limit(x: float | None, unbounded: str = "-") -> str:
    return unbounded if x is None else f"{x:g}"


def main(args) -> int:
    from coordinator.robots import broken, describe, names

    described = {name: describe(name) for name in names()}
    left_out = broken()
    if args.json:
        print(json.dumps({"robots": described, "broken": left_out}, indent=2, sort_keys=True))
        return 0
    for name, d in described.items():
        print(f"{name}  ({d['kind']})  {d['description']}")
        for j in d["joints"]:
            print(f"  {j['name']:20s} [{_limit(j['low'], '-inf')}, {_limit(j['high'], 'inf')}]"
                  f"  speed {_limit(j['max_velocity'])}"
                  f"  acceleration {_limit(j['max_acceleration'])}")
        if "dh" in d:
            print("  DH            " + ", ".join(f"{k} {v:g}" for k, v in d["dh"].items()))
            print(f"  tool          {d['flange_to_tool'][2][3]:g} m beyond the flange")
    for name, why in sorted(left_out.items()):
        print(f"{name}  (broken plugin, left out)  {why}")
    return 0
