"""`tmoc domains [--json]`: every registered domain (built-in or installed plugin) with its
objects, L (names, units, prior), measurement channels, actions, T contexts and utility
terms; then every installed plugin left out as broken, with why (JSON: "broken")."""
from __future__ import annotations

import argparse
import json


def register(sub) -> None:
    p = sub.add_parser("domains", help="list the registered domains (built-in and plugins)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=main)


def _contexts_text(contexts: list) -> str:
    by_action: dict[str, list[int]] = {}
    for name, k in contexts:
        by_action.setdefault(name, []).append(k)
    return ", ".join(f"{a} {ks[0]}" if len(ks) == 1 else f"{a} {ks[0]}..{ks[-1]}"
                     for a, ks in by_action.items())


def main(args) -> int:
    from coordinator.domains import broken, describe, names

    described, left_out = {}, broken()
    for name in names():
        try:
            described[name] = describe(name)
        except Exception as exc:  # noqa: BLE001 - one broken plugin must not hide the others
            left_out[name] = f"{type(exc).__name__}: {exc}"
    if args.json:
        print(json.dumps({"domains": described, "broken": left_out}, indent=2, sort_keys=True))
        return 0
    for name, d in described.items():
        props = "; ".join(f"{p['name']} [{p['unit']}] ~ U({p['prior']['low']:g}, {p['prior']['high']:g})"
                          for p in d["properties"])
        weighed = ", ".join(f"{c['name']} (sigma {c['sigma']:g} {c['unit']})"
                            for c in d["measurements"]["weighed"])
        print(f"{name}  ({d['id']}, {d['source']})  {d['description']}")
        print(f"  objects       {', '.join(d['objects'])}")
        print(f"  L             {props}")
        print(f"  measurements  {d['measurements']['count']} values; weighed: {weighed or 'none'}")
        print(f"  actions       {', '.join(d['actions'])}")
        print(f"  T contexts    {_contexts_text(d['contexts'])}")
        print(f"  utility       {', '.join(f'{k} {v:g}' for k, v in d['utility'].items())}")
    for name, why in sorted(left_out.items()):
        print(f"{name}  (broken plugin, left out)  {why}")
    return 0
