"""Checks of camera values and spectra shared by camera calibration and spectral estimation.

:mod:`processing.camera.transfer`, :mod:`processing.camera.from_chart` and the
estimators of :mod:`processing.spectral.estimation` refuse bad input with the
same error and the same messages; the checks live here, below both, so that
the camera modules need not import the estimation package (which imports
them).  :mod:`processing.spectral.estimation.fit` re-exports every name.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.spectral.spectra import SpectralGrid

__all__ = ["SpectralEstimationError", "checked_channels", "checked_spectra"]


class SpectralEstimationError(InputError):
    """An input to spectral estimation is not valid; the message names it and what to do."""


def checked_channels(
    name: str, rgb: ArrayLike, channels: int | None = None, *, check_values: bool = True
) -> NDArray[np.floating]:
    """Validate camera channels ``(..., c)``: non-empty, finite, >= 0, ``c == channels`` when given.

    Parameters
    ----------
    name
        What the values are, for messages ("chart_rgb", "camera channels").
    rgb
        Linear camera values ``(..., c)`` (integer or float; relative units).
    channels
        The number of channels c required on the last axis; None: any.
    check_values
        False checks only type and shape (the values are then checked block
        by block by the caller).

    Returns
    -------
    ndarray
        ``rgb`` as an array, not copied or converted.

    Raises
    ------
    SpectralEstimationError
        Not numeric, empty, the wrong number of channels, NaN, infinite or
        negative values.

    Examples
    --------
    >>> checked_channels("rgb", [[0.1, 0.2, 0.3]], 3).shape
    (1, 3)
    """
    a = np.asarray(rgb)
    if a.dtype.kind not in "fiu":
        raise SpectralEstimationError(f"{name} must be a numeric array, got dtype {a.dtype}")
    if a.ndim == 0 or a.size == 0:
        raise SpectralEstimationError(f"{name} is empty (shape {a.shape}); give camera values (..., channels)")
    if channels is not None and a.shape[-1] != channels:
        raise SpectralEstimationError(
            f"{name} must have {channels} channels on its last axis, got shape {a.shape}"
        )
    if check_values and a.dtype.kind in "fi":
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise SpectralEstimationError(f"{name} contains NaN or infinite values; mask those pixels first")
        if (a < 0).any():
            raise SpectralEstimationError(
                f"{name} has negative values (min {float(a.min()):.3g}); clip the black-subtracted image at 0"
            )
    return a


def checked_spectra(name: str, spectra: ArrayLike, grid: SpectralGrid | None = None) -> NDArray[np.float64]:
    """Validate spectra ``(n, L)``: non-empty, finite, on ``grid`` when given.

    Parameters
    ----------
    name
        What the spectra are, for messages ("database", "chart_reflectance").
    spectra
        ``(n, L)`` spectra (reflectance, a fraction).
    grid
        The wavelength grid the L samples must match; None: any L.

    Returns
    -------
    ndarray
        ``(n, L)`` float64.

    Raises
    ------
    SpectralEstimationError
        Not two-dimensional, empty, not on ``grid``, NaN or infinite values.

    Examples
    --------
    >>> checked_spectra("s", [[0.1, 0.2]]).shape
    (1, 2)
    """
    s = np.asarray(spectra, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] == 0 or s.shape[1] == 0:
        raise SpectralEstimationError(f"{name} must be a non-empty (n, L) array of spectra, got shape {s.shape}")
    if grid is not None and s.shape[1] != grid.size:
        raise SpectralEstimationError(f"{name} has {s.shape[1]} wavelengths, the grid {grid.size}")
    if not np.isfinite(s).all():
        raise SpectralEstimationError(f"{name} contains NaN or infinite values")
    return s
