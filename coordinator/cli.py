"""The `tmoc` command line: one sub-command per module under `coordinator.commands`.

Every sub-command module exposes ``register(subparsers)`` which adds its parser and sets
``func`` (a callable taking the parsed namespace and returning an exit code). Input a user
can get wrong raises :class:`UsageError` (defined in ``coordinator.commands``, so the
commands never import this module); it is printed as one line and exits with code 2, like
argparse's own errors, never as a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

from coordinator.commands import UsageError

__all__ = ["COMMAND_MODULES", "UsageError", "build_parser", "main"]   # UsageError: old home

# Order is the order shown in `tmoc --help`.
COMMAND_MODULES = ("run", "probe", "plan", "serve", "experiment", "domains", "robots", "check_domain", "export")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tmoc",
        description="TMOC: task-motion object-centric planning with particle worlds on Ray.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(f"coordinator.commands.{name}").register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
    except UsageError as exc:
        print(f"tmoc {args.command}: error: {exc}", file=sys.stderr)
        return 2
    return int(code or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
