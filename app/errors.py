"""The one error type the command line turns into a one-line message and exit code 2."""

from __future__ import annotations

__all__ = ["UsageError"]


class UsageError(ValueError):
    """Bad input from the user: the message names the file or parameter and what to do."""
