"""The `tmoc` command line: one sub-command per module under `coordinator.commands`.

Every sub-command module exposes ``register(subparsers)`` which adds its parser and sets
``func`` (a callable taking the parsed namespace and returning an exit code). Input a user
can get wrong raises :class:`UsageError`; it is printed as one line and exits with code 2,
like argparse's own errors, never as a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

# Order is the order shown in `tmoc --help`.
COMMAND_MODULES = ("run", "probe", "plan", "serve", "experiment", "domains", "check_domain")


class UsageError(ValueError):
    """Bad input from the user; the message names what is wrong."""


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
    # `python -m coordinator.cli`: run the imported module's main, so that the UsageError
    # the commands raise (coordinator.cli.UsageError) is the one caught there.
    from coordinator.cli import main as _main

    sys.exit(_main())
