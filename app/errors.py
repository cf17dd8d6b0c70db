"""The one error type the command line turns into a one-line message and exit code 2."""

from __future__ import annotations

from processing.errors import InputError

__all__ = ["UsageError"]


class UsageError(InputError):
    """Bad input from the user: the message names the file or parameter and what to do."""
