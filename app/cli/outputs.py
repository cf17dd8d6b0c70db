"""Output files named on the command line: checked before the work, and a failed write as one line.

Every command option that names a file to write (``--out``, ``--json``, ``--xyz``, ``--poses``,
``--gltf``) goes through :func:`check_output_file` before the command does any work, so a path
that cannot be written ends at once with a one-line :class:`OutputPathError`, not after a long
registration or render, and never after another of the command's outputs has been written.  The
check: the path is not an existing folder; its folder exists (or, for a command that creates it,
the nearest existing ancestor is a writable folder); and a file can be created in the folder
itself when it exists (tried for real, since ``os.access`` says yes to root on ``/proc`` or a
read-only mount; an ancestor is only asked, so that nothing is written outside the folder named).
An option naming an output *folder* goes through :func:`check_output_folder`.

What the check cannot foresee (the disk fills up, the folder is removed meanwhile) is caught by
:func:`writing` around the write: an :class:`OSError` there becomes one line naming the option,
the file and the system's reason.  Only :class:`OSError` is turned, and only inside that block.

Examples
--------
>>> import tempfile, pathlib
>>> folder = pathlib.Path(tempfile.mkdtemp())
>>> check_output_file(str(folder / "a.json"), "--json").name
'a.json'
>>> check_output_file(str(folder), "--json")  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
app.cli.outputs.OutputPathError: --json ...: is a folder; give a file name (a path inside it, or another name)
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from app.errors import UsageError

__all__ = ["OutputPathError", "check_output_file", "check_output_folder", "writing"]


class OutputPathError(UsageError):
    """An output path the command cannot write; the message names the option, the path and the remedy."""


def _nearest_existing(folder: Path) -> Path:
    """``folder`` itself if it exists, else its nearest existing ancestor (``.`` for a relative path)."""
    for candidate in (folder, *folder.parents):
        if os.path.lexists(candidate):
            return candidate
    return Path(".")


def _try_create(folder: Path, flag: str, path: Path) -> None:
    """Create and remove an empty file in ``folder``; an :class:`OutputPathError` if that fails."""
    probe = folder / f".kogei-write-check.{secrets.token_hex(4)}"
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        os.close(os.open(probe, flags, 0o600))
    except OSError as exc:
        raise OutputPathError(f"{flag} {path}: cannot write in the folder {folder} ({exc.strerror or exc}); "
                              "give a path in a writable folder") from None
    try:
        os.unlink(probe)
    except OSError:
        pass


def _check_folder(folder: Path, flag: str, path: Path, make_parents: bool) -> None:
    """The folder an output goes into: existing (or creatable with ``make_parents``) and writable."""
    existing = _nearest_existing(folder)
    if not existing.is_dir():
        raise OutputPathError(f"{flag} {path}: {existing} is a file, not a folder; give a path in a folder")
    if existing != folder and not make_parents:
        raise OutputPathError(f"{flag} {path}: the folder {folder} does not exist; create it first")
    if existing == folder:
        _try_create(folder, flag, path)
    elif not os.access(existing, os.W_OK | os.X_OK):        # nothing is written outside the folder named
        raise OutputPathError(f"{flag} {path}: cannot create the folder {folder} in {existing} (not writable); "
                              "give a path in a writable folder")


def check_output_file(path: str | os.PathLike[str], flag: str, *, suffixes: tuple[str, ...] = (),
                      make_parents: bool = False) -> Path:
    """The output file ``path`` of option ``flag``, checked before any work; its :class:`Path`.

    Parameters
    ----------
    path
        The file the option names.
    flag
        The option as the message names it (``"--out"``).
    suffixes
        Accepted endings, lower case with the dot (``(".png",)``); empty: any.
    make_parents
        The command creates a missing folder: then only the nearest existing ancestor must be a
        writable folder.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputPathError
        A wrong ending, an existing folder, a parent that is a file, a missing folder (without
        ``make_parents``) or a folder in which no file can be created.
    """
    out = Path(path)
    if not str(path) or out.name in ("", ".", ".."):
        raise OutputPathError(f"{flag} {path!r}: give a file name")
    if suffixes and out.suffix.lower() not in suffixes:
        raise OutputPathError(f"{flag} {out}: must end in {' or '.join(suffixes)}")
    if out.is_dir():
        raise OutputPathError(f"{flag} {out}: is a folder; give a file name (a path inside it, or another name)")
    _check_folder(out.parent if str(out.parent) else Path("."), flag, out, make_parents)
    return out


def check_output_folder(path: str | os.PathLike[str], flag: str) -> Path:
    """The output folder ``path`` of option ``flag`` (created by the command if missing), checked first.

    Parameters
    ----------
    path
        The folder the option names.
    flag
        The option as the message names it.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputPathError
        ``path`` or an ancestor is a file, or no file can be created where the folder is or would be.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise OutputPathError(f"{flag} {out}: is a file, not a folder; give a folder")
    _check_folder(out, flag, out, make_parents=True)
    return out


@contextmanager
def writing(path: str | os.PathLike[str], flag: str) -> Iterator[None]:
    """Turn an :class:`OSError` while writing output ``path`` into one :class:`OutputPathError` line.

    Parameters
    ----------
    path
        The output the block writes.
    flag
        Its option as the message names it.

    Examples
    --------
    >>> with writing("/no/such/folder/a.json", "--json"):  # doctest: +ELLIPSIS
    ...     _ = open("/no/such/folder/a.json", "w")
    Traceback (most recent call last):
    ...
    app.cli.outputs.OutputPathError: --json /no/such/folder/a.json: cannot be written (No such file or directory); ...
    """
    try:
        yield
    except OSError as exc:
        raise OutputPathError(f"{flag} {path}: cannot be written ({exc.strerror or exc}); "
                              "check the folder exists, is writable and has space") from None
