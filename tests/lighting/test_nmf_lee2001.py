"""A few non-negative spectra that a map's spectra mix: exact mixtures recovered, colour kept, bad input named."""

from __future__ import annotations

import numpy as np
import pytest

from processing.lighting.nmf_lee2001 import (
    COLOUR_WEIGHT,
    NonnegativeBasisError,
    nonnegative_basis,
    nonnegative_coefficients,
)
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import SpectralGrid

G = SpectralGrid(400, 700, 10)


def _parts(centres=(450, 530, 600, 650)) -> np.ndarray:
    wl = G.wavelengths
    return np.stack([0.05 + np.exp(-0.5 * ((wl - c) / 30) ** 2) for c in centres])


def _mixes(parts: np.ndarray, n: int = 800, seed: int = 0) -> np.ndarray:
    # the parts themselves (a room's saturated walls) and random non-negative mixes of them
    rng = np.random.default_rng(seed)
    return np.vstack([parts, rng.uniform(0, 1, (n, len(parts))) ** 3 @ parts])


@pytest.mark.parametrize("k", [3, 4])
def test_an_exact_mixture_is_recovered(k):
    # k non-negative parts and their mixes: k basis spectra hold every spectrum within 3 % of its peak (measured
    # 0.4 % for 3 parts, 2.5 % for 4: the factorisation is not unique and stops near, not at, the parts)
    v = _mixes(_parts()[:k])
    b = nonnegative_basis(v, k, G)
    c = nonnegative_coefficients(v, b, G)
    assert b.shape == (k, G.size) and (b >= 0).all() and (c >= 0).all()
    err = np.abs(c.astype(np.float64) @ b - v).max(axis=1) / v.max(axis=1)
    assert err.max() < 0.03, err.max()


def test_fewer_basis_spectra_than_parts_keep_the_colour_first():
    # four parts held by three basis spectra: the spectra cannot all be kept.  On the same basis, the
    # coefficients with the colour weighted keep the colour and luminance of most spectra (measured median xy
    # 0.0001 against 0.031 without it, luminance 0.01 % against 2.7 %) at some cost in spectral error (median
    # 22 % against 17 %); colours outside the basis's cone stay off either way (90th percentile 0.04)
    v = _mixes(_parts())
    b = nonnegative_basis(v, 3, G)
    xyz_v = spectra_to_xyz(v, G)
    figures = {}
    for weight in (0.0, COLOUR_WEIGHT):
        kept = nonnegative_coefficients(v, b, G, colour_weight=weight).astype(np.float64) @ b
        xyz_k = spectra_to_xyz(kept, G)
        dxy = np.linalg.norm(xyz_v[:, :2] / xyz_v.sum(1, keepdims=True) - xyz_k[:, :2] / xyz_k.sum(1, keepdims=True),
                             axis=1)
        figures[weight] = (np.median(dxy), np.median(np.abs(xyz_k[:, 1] / xyz_v[:, 1] - 1)),
                           np.median(np.abs(kept - v).sum(1) / v.sum(1)))
    (dxy0, lum0, spec0), (dxy1, lum1, spec1) = figures[0.0], figures[COLOUR_WEIGHT]
    assert dxy1 < 0.002 < dxy0 / 5 and lum1 < 0.002 < lum0 / 5
    assert spec1 >= spec0


@pytest.mark.parametrize("scale", [1e-12, 1e12])
def test_extreme_scales_change_nothing_but_the_scale(scale):
    # a map's radiance spans lamps and shadows: the fit is the same at any overall scale
    v = _mixes(_parts()[:3])
    b1 = nonnegative_basis(v, 3, G)
    b2 = nonnegative_basis(v * scale, 3, G)
    np.testing.assert_allclose(b2, b1, rtol=1e-6, atol=1e-9)
    c1 = nonnegative_coefficients(v, b1, G)
    c2 = nonnegative_coefficients(v * scale, b2, G)
    np.testing.assert_allclose(c2 / scale, c1, rtol=1e-4, atol=1e-6 * float(c1.max()))


def test_black_pixels_get_zero():
    v = np.vstack([_mixes(_parts()[:3]), np.zeros((5, G.size))])
    c = nonnegative_coefficients(v, nonnegative_basis(v, 3, G), G)
    assert np.all(c[-5:] == 0)


@pytest.mark.parametrize("spectra, k, needle", [
    (np.zeros((10, 31)), 3, "all black"),
    (np.full((10, 31), np.nan), 3, "NaN"),
    (np.ones((10, 30)), 3, "(n >= 1, 31)"),
    (np.ones((10, 31)), 0, "1-6"),
    (np.ones((10, 31)), 7, "1-6"),
    (np.ones((10, 31)), True, "1-6"),
])
def test_bad_input_is_named(spectra, k, needle):
    with pytest.raises(NonnegativeBasisError, match=None) as e:
        nonnegative_basis(spectra, k, G)
    assert needle in str(e.value)
    assert "\n" not in str(e.value)
