r"""Reading a table of values against wavelength from a CSV file, with errors that name the line.

Users bring their own spectral data as plain text (a camera's sensitivities, a set of
reflectances): one row per wavelength, the wavelength in nm first, then one column per curve,
separated by commas, semicolons, tabs or spaces.  Blank lines and lines starting with ``#`` are
skipped; one header line (its first field not a number) may name the columns.  Every fault is
reported with the file, the line and, where it applies, the column, so the file can be fixed.

Examples
--------
>>> import tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "t.csv"
>>> _ = p.write_text("nm,a,b\n400,0.1,0.2\n# a comment\n700,0.3,0.4\n")
>>> t = read_wavelength_table(p, what="test")
>>> t.header, t.wavelengths.tolist(), t.values.tolist()
(('a', 'b'), [400.0, 700.0], [[0.1, 0.2], [0.3, 0.4]])
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["WavelengthTable", "read_wavelength_table"]

_SPLIT = re.compile(r"[,;\s]+")


@dataclass(frozen=True)
class WavelengthTable:
    """The rows of a wavelength table.

    Parameters
    ----------
    wavelengths, values, header
        The attributes below, in this order.

    Attributes
    ----------
    wavelengths
        ``(N,)`` strictly increasing wavelengths (nm).
    values
        ``(N, C)`` values, one column per curve.
    header
        The header line's column names after the wavelength column (None without a header).
    """

    wavelengths: NDArray[np.float64]
    values: NDArray[np.float64]
    header: tuple[str, ...] | None


def read_wavelength_table(
    path: str | Path,
    *,
    what: str,
    error: type[ValueError] = ValueError,
    columns: int | None = None,
    layout: str = "",
    check: Callable[[int, float], str | None] | None = None,
) -> WavelengthTable:
    """Read a CSV table of values against wavelength, refusing bad rows with ``error``.

    Parameters
    ----------
    path
        The CSV file.
    what
        What the file holds, for messages ("camera sensitivity", "reflectance").
    error
        The exception class raised (a ``ValueError`` subclass of the caller's module).
    columns
        The number of columns every row must have, wavelength included; None: at least two, and
        as many as the first data row.
    layout
        The expected row, for messages, e.g. ``"'wavelength_nm, r, g, b'"``.
    check
        Called with the 1-based column (>= 2) and each value; a returned text is the fault.

    Returns
    -------
    WavelengthTable
        The wavelengths (nm), the ``(N, C)`` values and the header's names.

    Raises
    ------
    error
        Unreadable file, a field that is not a number, NaN or infinity, a wrong column count, a
        ``check`` fault, wavelengths that do not increase, fewer than two rows.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"cannot read {what} file '{path}': {exc}") from exc
    header: tuple[str, ...] | None = None
    rows: list[list[float]] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f for f in _SPLIT.split(line.strip(",; \t")) if f]
        at = f"{path}, line {lineno}"
        if header is None and not rows:
            try:
                float(fields[0])
            except ValueError:
                header = tuple(fields[1:])
                continue
        nums: list[float] = []
        for col, field in enumerate(fields, start=1):
            try:
                v = float(field)
            except ValueError:
                raise error(f"{at}, column {col}: not a number: {field!r}") from None
            if not math.isfinite(v):
                raise error(f"{at}, column {col}: NaN or infinite value in {line!r}")
            fault = check(col, v) if check is not None and col > 1 else None
            if fault:
                raise error(f"{at}, column {col}: {fault}")
            nums.append(v)
        if len(nums) < 2:
            raise error(f"{at}: needs a wavelength and at least one value {layout}".rstrip())
        if columns is not None and len(nums) != columns:
            raise error(f"{at}: expected {columns} columns {layout}, got {len(nums)}".replace("  ", " "))
        if rows and len(nums) != len(rows[0]):
            raise error(f"{at}: {len(nums)} columns, but the first data line has {len(rows[0])}")
        if rows and nums[0] <= rows[-1][0]:
            raise error(f"{at}, column 1: wavelength {nums[0]:g} nm does not increase; sort the rows")
        rows.append(nums)
    if len(rows) < 2:
        raise error(f"{path}: needs at least two wavelength rows {layout}, found {len(rows)}".replace("  ", " "))
    arr = np.asarray(rows, dtype=np.float64)
    return WavelengthTable(arr[:, 0], arr[:, 1:], header)
