"""The one error type the command line turns into a one-line message and exit code 2, and Ctrl-C's disguise."""

from __future__ import annotations

from processing.errors import InputError

__all__ = ["UsageError", "caused_by_ctrl_c"]


class UsageError(InputError):
    """Bad input from the user: the message names the file or parameter and what to do."""


def caused_by_ctrl_c(exc: BaseException) -> bool:
    """Whether ``exc`` is a Ctrl-C or was caused by one (its ``__cause__`` / ``__context__`` chain).

    A Ctrl-C that lands while a compiled module initialises (Open3D's, on its first ``import``) surfaces
    as ``ImportError: initialization failed`` caused by the ``KeyboardInterrupt``: an interruption, not
    a failure.

    Parameters
    ----------
    exc
        The exception caught.

    Returns
    -------
    bool

    Examples
    --------
    >>> try:
    ...     try:
    ...         raise KeyboardInterrupt
    ...     except KeyboardInterrupt as ki:
    ...         raise ImportError("initialization failed") from ki
    ... except ImportError as exc:
    ...     caused_by_ctrl_c(exc), caused_by_ctrl_c(ValueError("bad"))
    (True, False)
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False
