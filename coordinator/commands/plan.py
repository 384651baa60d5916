"""`tmoc plan`: print the task plan of maximum expected utility under a given T.

    tmoc plan --domain container --blocks 8 --p-pickup 1 --p-stack 1,1,1,1,1,1,1,1 \\
        --p-push 1,1,1,0.9,0.8,0.6,0.4,0.3 [--state FILE] [--json]

T is given as success probabilities: --p-pickup (one number, or CLASS=P,... with --class),
--p-stack p_0,...,p_{N-1} (index = blocks already in the container, or the tower height
before the stack) and --p-push p_1,...,p_N (index = load of the push to goal, or the
tower height pushed); lists left out mean "always succeeds". --domain is any registered
domain whose T has these three fields (container, stack_and_push).
The plan starts from all blocks at init, or from the atoms in --state FILE (one per line,
or separated by whitespace or periods; `%` starts a comment).
"""
from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path

from sim_workers.domains import DEFAULT_DOMAIN

from . import UsageError

# Planner fields -> the flag a user of this command wrote them with.
_FLAGS = {"pickup": "--p-pickup", "stack": "--p-stack", "push": "--p-push", "costs": "--cost",
          "block_classes": "--class", "max_steps": "--max-steps", "time_limit": "--time-limit"}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "plan", help="print the task plan of maximum expected utility for a transition model",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--domain", default=DEFAULT_DOMAIN, metavar="NAME",
                   help="planning domain (default: container)")
    p.add_argument("--blocks", "--objects", default=None, metavar="N",
                   help="number of objects (default: from --state, else the domain's own count)")
    p.add_argument("--p-pickup", default="1", metavar="P",
                   help="pickup success probability, or CLASS=P,... per block class (default 1)")
    p.add_argument("--p-stack", default=None, metavar="P0,P1,...",
                   help="stack success by blocks already in the container (N values; default all 1)")
    p.add_argument("--p-push", default=None, metavar="P1,P2,...",
                   help="push-to-goal success by load 1..N (N values; default all 1)")
    p.add_argument("--class", dest="classes", action="append", default=[], metavar="BLOCK=CLASS",
                   help="block class for the sizes variation, e.g. b5=large (repeatable)")
    p.add_argument("--cost", dest="costs", action="append", default=[], metavar="NAME=VALUE",
                   help="override a utility figure: pickup, stack, push, fail, deliver (repeatable)")
    p.add_argument("--max-steps", default=None, metavar="K", help="longest plan allowed")
    p.add_argument("--time-limit", default="30", metavar="SECONDS",
                   help="planning time limit (default 30)")
    p.add_argument("--state", default=None, metavar="FILE", help="plan from the atoms in FILE")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


# --------------------------------------------------------------------------- parsing

def _number(flag: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{flag}: {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise UsageError(f"{flag}: {text.strip()!r} is not a finite number")
    return value


def _integer(flag: str, text: str, minimum: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise UsageError(f"{flag}: {text!r} is not an integer") from None
    if value < minimum:
        raise UsageError(f"{flag}: {value} must be at least {minimum}")
    return value


def _probability_list(flag: str, text: str | None, n: int) -> list[float]:
    """Comma-separated numbers; all ones (always succeeds) when the flag is left out."""
    if text is None:
        return [1.0] * n
    items = [t for t in text.replace(" ", "").split(",")]
    if any(not t for t in items):
        raise UsageError(f"{flag}: {text!r} has an empty entry (expected p,p,...)")
    return [_number(flag, t) for t in items]     # the planner checks length and range


def _pairs(flag: str, items: list[str]) -> dict[str, str]:
    pairs = {}
    for item in items:
        for part in item.split(","):
            key, sep, value = part.partition("=")
            if not sep or not key.strip() or not value.strip():
                raise UsageError(f"{flag}: {part!r} is not of the form NAME=VALUE")
            pairs[key.strip()] = value.strip()
    return pairs


def _pickup(text: str) -> float | dict[str, float]:
    if "=" not in text:
        return _number("--p-pickup", text)
    return {name: _number("--p-pickup", v) for name, v in _pairs("--p-pickup", [text]).items()}


def _read_state(path: str, task):
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise UsageError(f"--state: cannot read {path!r}: {exc.strerror or exc}") from None
    text = "\n".join(line.split("%", 1)[0] for line in text.splitlines())
    try:
        return task.parse_state(text)
    except ValueError as exc:
        raise UsageError(f"--state {path}: {exc}") from None


def _flag_message(message: str) -> str:
    """Name the command-line flag in a planner message ("push: ..." -> "--p-push: ...")."""
    match = re.match(r"[a-z_]+", message)
    if match and match.group() in _FLAGS:
        return _FLAGS[match.group()] + message[match.end():]
    return message


# --------------------------------------------------------------------------- output

def _listing(result, n_blocks: int, domain: str) -> str:
    proof = "optimal (proven)" if result.optimal else "best found (optimality not proven)"
    lines = [f"{domain} plan for {n_blocks} blocks: {len(result.actions)} actions, {proof}, "
             f"{result.solve_ms:.1f} ms"]
    loads = iter(result.loads)
    width = len(str(len(result.actions)))
    for i, action in enumerate(result.actions, start=1):
        # a push to goal (the container's return push ends at init) carries a load
        note = f"   load {next(loads)}" if action.startswith("push(") and action.endswith(",goal)") else ""
        lines.append(f"  {i:>{width}}  {action}{note}")
    lines.append(f"loads: {' + '.join(map(str, result.loads)) or '-'}")
    lines.append(f"expected utility: {result.expected_utility:.3f}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from coordinator import domains
    from planner.blocks.model import PlanningError

    try:
        task = domains.task_half(args.domain)
    except ValueError as exc:
        raise UsageError(f"--{exc}") from None
    if args.state is not None:
        state = _read_state(args.state, task)
        n_blocks = len(task.blocks(state))
        if args.blocks is not None and _integer("--blocks", args.blocks, 1) != n_blocks:
            raise UsageError(f"--blocks: {args.blocks} does not match the {n_blocks} blocks "
                             f"in {args.state}")
    else:
        n_blocks = (domains.load(args.domain).n_objects if args.blocks is None
                    else _integer("--blocks", args.blocks, 1))
        state = task.initial_state(n_blocks)
    transition = {"pickup": _pickup(args.p_pickup),
                  "stack": _probability_list("--p-stack", args.p_stack, n_blocks),
                  "push": _probability_list("--p-push", args.p_push, n_blocks)}
    costs = {k: _number("--cost", v) for k, v in _pairs("--cost", args.costs).items()}
    classes = _pairs("--class", args.classes) or None
    max_steps = None if args.max_steps is None else _integer("--max-steps", args.max_steps, 0)
    time_limit = _number("--time-limit", args.time_limit)
    try:
        result = task.plan(state, transition, costs, block_classes=classes,
                           max_steps=max_steps, time_limit=time_limit)
    except PlanningError as exc:
        raise UsageError(_flag_message(str(exc))) from None
    if args.json:
        print(json.dumps({"domain": args.domain, "blocks": n_blocks, **result.to_dict()}, indent=2))
    else:
        print(_listing(result, n_blocks, args.domain))
    return 0
