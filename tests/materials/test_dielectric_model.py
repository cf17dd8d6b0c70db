"""Dielectric / lacquer model (Matsuda eq. 5): Fresnel factor, pigment
reflectance, the urushi spectra and the material builder."""

from __future__ import annotations

import math

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.materials.dielectric_model import (
    DielectricFresnel,
    PigmentReflectance,
    dielectric_material,
    urushi_black_reflectance,
    urushi_red_reflectance,
)
from processing.materials.lobes import SpectralFactor, material_brdf
from processing.spectral.display import spectra_to_xyz, white_xyz, xyz_scale
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, light_spectrum

WL = SpectralGrid(400, 700, 20).wavelengths


@settings(max_examples=80, deadline=None)
@given(cos=st.one_of(st.just(0.0), st.just(1.0), st.floats(0.0, 1.0)), n=st.floats(0.01, 10.0))
def test_dielectric_fresnel_bounded(cos: float, n: float) -> None:
    r = DielectricFresnel(n).reflectance(cos, WL)
    assert r.shape == (WL.size,) and np.all(np.isfinite(r)) and np.all((r >= 0) & (r <= 1))
    if cos == 0.0:
        assert np.all(r == 1.0)
    else:
        assert np.allclose(r, r[0])  # no dispersion: grey


def test_dielectric_fresnel_closed_forms() -> None:
    f = DielectricFresnel(1.5)
    assert np.allclose(f.reflectance(1.0, WL), ((1.5 - 1) / 2.5) ** 2)
    theta_b = math.atan(1.5)
    assert np.allclose(f.reflectance(math.cos(theta_b), WL), 0.5 * ((1.5**2 - 1) / (1.5**2 + 1)) ** 2)
    assert isinstance(f, SpectralFactor) and f.angle_dependent


def test_dispersive_index() -> None:
    f = DielectricFresnel([1.52, 1.50], wavelengths=[400.0, 700.0])
    n = f.index([400.0, 550.0, 700.0])
    assert np.allclose(n, [1.52, 1.51, 1.50])
    r = f.reflectance(np.array([1.0, 0.5]), [400.0, 700.0])
    assert r.shape == (2, 2) and r[0, 0] == pytest.approx(((1.52 - 1) / 2.52) ** 2)
    assert f.constant_index is None
    with pytest.raises(ValueError, match="400-700 nm"):
        f.index([380.0])


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        ((0.0,), {}, "finite and > 0"),
        ((np.nan,), {}, "finite and > 0"),
        (([1.5, 1.6],), {}, "matching wavelengths"),
        (([1.5, 1.6],), {"wavelengths": [400.0]}, "same length"),
        (([1.5, 1.6],), {"wavelengths": [700.0, 400.0]}, "strictly increasing"),
    ],
)
def test_dielectric_fresnel_errors(args, kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        DielectricFresnel(*args, **kwargs)


# --- pigment ---------------------------------------------------------------------------


def test_pigment_is_angle_independent_and_resampled() -> None:
    s = PigmentReflectance([400.0, 700.0], [0.2, 0.5])
    assert not s.angle_dependent and isinstance(s, SpectralFactor)
    r = s.reflectance(np.array([0.0, 0.3, 1.0]), WL)
    assert r.shape == (3, WL.size)
    assert np.allclose(r[0], r[2])
    assert np.allclose(r[0], 0.2 + 0.3 * (WL - 400) / 300)
    assert not r.flags.writeable


@pytest.mark.parametrize(
    "wl, vals, match",
    [
        ([400.0, 700.0], [0.2, 1.2], r"\[0, 1\]"),
        ([400.0, 700.0], [0.2, -0.1], r"\[0, 1\]"),
        ([400.0, 700.0], [0.2], "same length"),
        ([700.0, 400.0], [0.2, 0.3], "strictly increasing"),
        ([400.0, 700.0], [0.2, np.nan], r"\[0, 1\]"),
    ],
)
def test_pigment_errors(wl, vals, match) -> None:
    with pytest.raises(ValueError, match=match):
        PigmentReflectance(wl, vals)


def test_pigment_out_of_range_grid() -> None:
    with pytest.raises(ValueError, match="pigment reflectance: the spectrum covers 450-650 nm"):
        PigmentReflectance([450.0, 650.0], [0.1, 0.2]).reflectance(1.0, WL)


# --- urushi spectra ----------------------------------------------------------------------


def test_urushi_spectra_plausible() -> None:
    wl = np.arange(360.0, 831.0, 5.0)
    black = urushi_black_reflectance().on(wl)
    red = urushi_red_reflectance().on(wl)
    assert np.all((black > 0.005) & (black < 0.03))
    assert np.all((red > 0.0) & (red < 0.7))
    # vermilion: dark below its band edge, bright above, edge (half rise) near 600 nm
    assert red[wl == 650][0] / red[wl == 500][0] > 5
    half = 0.5 * (red.min() + red.max())
    assert 590 <= wl[np.argmax(red >= half)] <= 610
    # smooth: no kinks larger than a gentle curve
    for s in (black, red):
        assert np.abs(np.diff(s, 2)).max() < 0.02


def test_urushi_red_looks_vermilion_under_d65() -> None:
    e = light_spectrum("D65")
    s = urushi_red_reflectance().on(REFERENCE_GRID.wavelengths)
    xyz = xyz_scale(e) * spectra_to_xyz(s * e / np.pi)
    lab = colour.XYZ_to_Lab(xyz, colour.XYZ_to_xy(white_xyz(e)))
    hue = math.degrees(math.atan2(lab[2], lab[1]))
    assert 15 < hue < 60 and lab[1] > 30  # orange-red, strongly chromatic
    e_black = urushi_black_reflectance().on(REFERENCE_GRID.wavelengths)
    y_black = (xyz_scale(e) * spectra_to_xyz(e_black * e / np.pi))[1]
    assert y_black < 0.03


# --- material ------------------------------------------------------------------------------


def test_dielectric_material_lobes() -> None:
    m = dielectric_material("urushi-red", urushi_red_reflectance(), n=1.5, diffuse=0.7, gloss=0.15, mirror=0.15)
    kinds = [(lobe.kind, lobe.weight, lobe.mirror) for lobe in m.lobes]
    assert kinds == [("lambert", 0.7, False), ("microfacet", 0.15, False), ("microfacet", 0.15, True)]
    assert m.family == "dielectric"
    assert set(m.parameters) == {"n", "diffuse", "gloss", "roughness", "mirror", "mirror_roughness", "shadowing"}
    # Lambert part: diffuse * S / pi, independent of angle, away from the highlight
    brdf = material_brdf(m, 0.5, 0.9, 0.2, 0.2, WL)  # cos_h small: gloss lobes vanish
    assert np.allclose(brdf, 0.7 * urushi_red_reflectance().on(WL) / np.pi, rtol=1e-9)


def test_highlight_has_the_colour_of_the_light() -> None:
    m = dielectric_material("urushi-black", urushi_black_reflectance(), diffuse=0.0, gloss=1.0, mirror=0.0)
    peak = material_brdf(m, 0.8, 0.8, 1.0, 0.8, WL)
    assert np.allclose(peak, peak[0])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"diffuse": 0.9, "gloss": 0.1, "mirror": 0.1}, "exceeds 1"),
        ({"n": 0.5}, r"n must be in \[1, 3\]"),
        ({"n": 5.0}, r"n must be in \(0, 3\]"),
        ({"roughness": 0.0}, "roughness"),
        ({"shadowing": "none"}, "smith, torrance-sparrow"),
        ({"diffuse": -0.1}, r"diffuse must be in \[0, 1\]"),
    ],
)
def test_dielectric_material_errors(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        dielectric_material("x", urushi_black_reflectance(), **kwargs)


def test_reflectance_argument_checked() -> None:
    with pytest.raises(ValueError, match="PigmentReflectance"):
        dielectric_material("x", [0.1, 0.2])  # type: ignore[arg-type]


def test_dispersive_index_accepted() -> None:
    f = DielectricFresnel([1.52, 1.50], wavelengths=[380.0, 780.0])
    m = dielectric_material("x", urushi_black_reflectance(), n=f)
    assert m.parameters["n"] == "dispersive" and m.lobes[1].spectral is f
