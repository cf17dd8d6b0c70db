"""Camera spectral sensitivities and the camera response to reflectance under a light.

A camera channel c records ``rho_c = sum_lambda R(lambda) E(lambda)
s_c(lambda) step`` for a surface of reflectance R under light E (the linear
signal model of EMVA Standard 1288); several exposures under different lights
stack into one channel matrix ``K (L, 3 n_lights)`` with ``rho = R @ K``.
Sensitivities come by name from colour-science or from a CSV file.
docs/colour-pipeline.md, "The camera model", describes the sources.

References
----------
EMVA Standard 1288, release 4.0, section 2: the linear signal model (no DOI).
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError
from processing.spectral.spectra import SpectralGrid, resample

__all__ = [
    "DEFAULT_CAMERA",
    "CameraResponseError",
    "camera_names",
    "camera_sensitivities",
    "channel_matrix",
    "camera_rgb",
]

#: Default reference camera (a key of ``colour.MSDS_CAMERA_SENSITIVITIES``).
DEFAULT_CAMERA = "Nikon 5100 (NPL)"


class CameraResponseError(InputError):
    """A camera, light or spectrum given to the camera model is not valid; the message names it."""


def camera_names() -> list[str]:
    """Names of the cameras with measured sensitivities in colour-science.

    colour-science ships 'Nikon 5100 (NPL)' and 'Sigma SDMerill (NPL)',
    measured by the National Physical Laboratory.

    Returns
    -------
    list of str
        Keys of ``colour.MSDS_CAMERA_SENSITIVITIES``, sorted.

    Examples
    --------
    >>> "Nikon 5100 (NPL)" in camera_names()
    True
    """
    import colour

    return sorted(colour.MSDS_CAMERA_SENSITIVITIES.keys())


#: Largest sensitivity a CSV may give (relative units).  Sensitivities are products of squares and sums
#: over the grid in the estimators, so values near the float limit (1e300) overflow to inf and NaN; a peak
#: of 1 (as colour-science's), a percentage or 16-bit counts all lie far below.
MAX_SENSITIVITY = 1e6


def _sensitivity_problem(col: int, v: float) -> str | None:
    """Why a CSV sensitivity ``v`` is refused, or None."""
    if v < 0:
        return f"a sensitivity must be >= 0, got {v:g}"
    if v > MAX_SENSITIVITY:
        return (f"a sensitivity must be at most {MAX_SENSITIVITY:g} (relative units), got {v:g}; "
                "scale the sensitivities, e.g. to a peak of 1")
    return None


def _read_sensitivity_csv(path: Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Wavelengths (nm) and ``(N, 3)`` sensitivities in [0, MAX_SENSITIVITY] of a CSV file ``wavelength_nm, r, g, b``."""
    from processing.spectral.tables import read_wavelength_table

    table = read_wavelength_table(
        path, what="camera sensitivity", error=CameraResponseError, columns=4, layout="'wavelength_nm, r, g, b'",
        check=_sensitivity_problem)
    return table.wavelengths, table.values


@functools.lru_cache(maxsize=16)
def _named(name: str, start: float, stop: float, step: float) -> NDArray[np.float64]:
    """The colour-science sensitivities ``name`` on the grid ``(start, stop, step)``."""
    import colour

    try:
        msds = colour.MSDS_CAMERA_SENSITIVITIES[name]
    except KeyError:
        raise CameraResponseError(
            f"unknown camera sensitivities {name!r}; choose one of: {', '.join(camera_names())} "
            "or give a CSV file 'wavelength_nm, r, g, b'"
        ) from None
    wl = np.asarray(msds.wavelengths, dtype=np.float64)
    values = np.asarray(msds.values, dtype=np.float64)
    return _on_grid(name, wl, values, SpectralGrid(start, stop, step))


def _on_grid(label: str, wl: NDArray[np.float64], values: NDArray[np.float64], grid: SpectralGrid) -> NDArray[np.float64]:
    """Sensitivities resampled onto ``grid`` (read-only), refused if the grid leaves their range or a channel is 0."""
    lo, hi = float(wl[0]), float(wl[-1])
    if grid.start < lo or grid.stop > hi:
        raise CameraResponseError(
            f"camera sensitivities {label!r} cover {lo:g}-{hi:g} nm; the spectral grid "
            f"{grid.start:g}-{grid.stop:g} nm must lie inside"
        )
    out = resample(wl, values.T, grid).T
    if not np.all(out.max(axis=0) > 0):
        raise CameraResponseError(f"camera sensitivities {label!r}: a channel is zero over the whole grid")
    out.setflags(write=False)
    return out


def camera_sensitivities(grid: SpectralGrid, camera: str | os.PathLike[str] = DEFAULT_CAMERA) -> NDArray[np.float64]:
    """Spectral sensitivities ``(L, 3)`` (R, G, B) of a camera on ``grid``, linearly interpolated.

    Parameters
    ----------
    grid
        Wavelength grid; must lie inside the range the sensitivities cover.
    camera
        A name of :func:`camera_names`, or a CSV file path (``.csv``) of rows
        ``wavelength_nm, r, g, b`` (one header line allowed, '#' comments), each
        sensitivity in [0, 1e6] (:data:`MAX_SENSITIVITY`, relative units).

    Returns
    -------
    ndarray
        Read-only float64 array ``(grid.size, 3)`` (relative units).

    Raises
    ------
    CameraResponseError
        Not a SpectralGrid, an unknown camera name, a bad CSV file (the
        message names the line and column; a sensitivity < 0 or > 1e6), a grid outside the range of the
        sensitivities, or a channel that is zero over the grid.

    Examples
    --------
    >>> s = camera_sensitivities(SpectralGrid(400, 700, 10))
    >>> s.shape, int(np.argmax(s[:, 1]) * 10 + 400) in range(510, 560)
    ((31, 3), True)
    """
    if not isinstance(grid, SpectralGrid):
        raise CameraResponseError(f"grid must be a processing.spectral.spectra.SpectralGrid, got {type(grid).__name__}")
    if isinstance(camera, os.PathLike) or (isinstance(camera, str) and camera.lower().endswith(".csv")):
        path = Path(camera)
        wl, values = _read_sensitivity_csv(path)
        return _on_grid(str(path), wl, values, grid)
    if not isinstance(camera, str):
        raise CameraResponseError(f"camera must be a name or a CSV path, got {type(camera).__name__}")
    return _named(camera, grid.start, grid.stop, grid.step)


def _checked_sensitivities(sensitivities: ArrayLike, grid: SpectralGrid) -> NDArray[np.float64]:
    """Sensitivities as a finite, non-negative float64 ``(L, channels)`` array on ``grid``."""
    s = np.asarray(sensitivities, dtype=np.float64)
    if s.ndim != 2 or s.shape[0] != grid.size or s.shape[1] < 1:
        raise CameraResponseError(
            f"sensitivities must be (L, channels) with L = {grid.size} wavelengths of the grid, got shape {s.shape}"
        )
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise CameraResponseError("sensitivities must be finite and >= 0")
    return s


def channel_matrix(
    sensitivities: ArrayLike, lights: ArrayLike | Sequence[ArrayLike], grid: SpectralGrid
) -> NDArray[np.float64]:
    """The matrix ``K (L, c n)`` with camera response ``rho = R @ K`` for reflectances R ``(..., L)``.

    ``K[:, k c + j] = E_k(lambda) s_j(lambda) step`` for light k and channel j:
    one exposure per light, the channels of each exposure side by side.

    Parameters
    ----------
    sensitivities
        ``(L, c)`` camera sensitivities on ``grid`` (relative units, >= 0).
    lights
        One light ``(L,)`` or several ``(n, L)`` (relative spectral power, >= 0).
    grid
        The wavelength grid (``step`` in nm is the integration weight).

    Returns
    -------
    ndarray
        ``(L, c n)`` float64.

    Raises
    ------
    CameraResponseError
        Sensitivities or lights of the wrong shape, not finite, negative, or
        a light that is zero everywhere.

    References
    ----------
    EMVA Standard 1288, release 4.0, section 2 (no DOI).

    Examples
    --------
    >>> g = SpectralGrid(400, 700, 100)
    >>> channel_matrix(np.ones((4, 3)), [np.ones(4), 2 * np.ones(4)], g).shape
    (4, 6)
    """
    s = _checked_sensitivities(sensitivities, grid)
    e = np.asarray(lights, dtype=np.float64)
    if e.ndim == 1:
        e = e[None, :]
    if e.ndim != 2 or e.shape[1] != grid.size or e.shape[0] < 1:
        raise CameraResponseError(
            f"lights must be (L,) or (n, L) with L = {grid.size} wavelengths of the grid, got shape {e.shape}"
        )
    if not np.all(np.isfinite(e)) or np.any(e < 0) or np.any(e.max(axis=1) <= 0):
        raise CameraResponseError("each light spectrum must be finite, >= 0 and not all zero")
    return np.concatenate([s * (ek * grid.step)[:, None] for ek in e], axis=1)


def camera_rgb(
    reflectance: ArrayLike,
    light: ArrayLike | Sequence[ArrayLike],
    sensitivities: ArrayLike,
    grid: SpectralGrid,
) -> NDArray[np.float64]:
    """Linear camera response ``(..., c n)`` of reflectances ``(..., L)`` under one or more lights.

    Parameters
    ----------
    reflectance
        Spectral reflectance (a fraction, or any non-negative spectral factor)
        ``(..., L)`` on ``grid``.
    light
        ``(L,)`` light (relative spectral power), or ``(n, L)`` for n
        exposures (channels concatenated).
    sensitivities
        ``(L, c)`` camera sensitivities on ``grid`` (relative units).
    grid
        The wavelength grid.

    Returns
    -------
    ndarray
        ``(..., c n)`` float64 linear camera values (units of the
        sensitivities times the light times nm).

    Raises
    ------
    CameraResponseError
        Bad sensitivities or lights (:func:`channel_matrix`), or a
        reflectance that is empty, off the grid, not finite or negative.

    Examples
    --------
    >>> from processing.spectral.spectra import light_spectrum
    >>> g = SpectralGrid(400, 700, 10)
    >>> s = camera_sensitivities(g)
    >>> white = camera_rgb(np.ones(g.size), light_spectrum("D65", g), s, g)
    >>> grey = camera_rgb(np.full(g.size, 0.2), light_spectrum("D65", g), s, g)
    >>> np.allclose(grey, 0.2 * white)
    True
    """
    k = channel_matrix(sensitivities, light, grid)
    r = np.asarray(reflectance, dtype=np.float64)
    if r.ndim == 0 or r.shape[-1] != grid.size:
        raise CameraResponseError(
            f"reflectance must have the {grid.size} wavelengths of the grid on its last axis, got shape {r.shape}"
        )
    if r.size == 0:
        raise CameraResponseError("reflectance is empty")
    if not np.all(np.isfinite(r)) or np.any(r < 0):
        raise CameraResponseError("reflectance must be finite and >= 0")
    return r @ k
