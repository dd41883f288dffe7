"""How a sub-command reports a failure it can name (bad file, field or value)."""

from __future__ import annotations

import sys

USER_ERRORS = (ValueError, KeyError, OSError)
"""The failures a command reports as ``error: <message>`` (exit status 1), not a traceback."""


def report_error(command: str, error: Exception) -> int:
    """Print ``eit-skin <command>: error: <message>`` to stderr; returns the exit status, 1.

    A ``KeyError``'s message is its argument as written, not its quoted ``repr``.
    """
    message = error.args[0] if isinstance(error, KeyError) and error.args else error
    print(f"eit-skin {command}: error: {message}", file=sys.stderr)
    return 1
