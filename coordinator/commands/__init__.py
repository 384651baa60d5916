"""The `tmoc` sub-commands, one module each (``register(subparsers)``; see coordinator.cli).

:class:`UsageError` lives here, not in ``coordinator.cli``, so that the commands import
nothing from the module that imports them.
"""


class UsageError(ValueError):
    """Bad input from the user; the message names what is wrong (exit code 2, one line)."""
