"""Spectra -> XYZ -> sRGB against colour-science, white normalisation,
adaptation, coarse grids and the out-of-gamut policy."""

from __future__ import annotations

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from processing.spectral.display import (
    SRGB_LUMINANCE,
    delta_e00,
    encode_srgb8,
    gamut_map,
    spectra_to_xyz,
    white_xyz,
    xyz_scale,
    xyz_to_linear_srgb,
    xyz_to_srgb8,
)
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, cmfs, light_spectrum, resample

CIE1931 = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
CHECKER = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
D65_XYZ = colour.xy_to_XYZ(colour.RGB_COLOURSPACES["sRGB"].whitepoint)
SHAPE_1NM = colour.SpectralShape(360, 830, 1)

# colour-science reports every alignment of a spectral shape it performs
pytestmark = pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")


def _render_checker(light: str, grid: SpectralGrid) -> tuple[np.ndarray, np.ndarray]:
    """Radiance of the 24 patches (Lambertian, normal incidence) -> scaled XYZ, white."""
    e = light_spectrum(light, grid)
    refl = np.array([resample(sd.wavelengths, sd.values, grid) for sd in CHECKER.values()])
    xyz = xyz_scale(e, grid) * spectra_to_xyz(refl * e / np.pi, grid)
    return xyz, white_xyz(e, grid)


def _reference_checker(light: str) -> tuple[np.ndarray, np.ndarray]:
    ill = colour.SDS_ILLUMINANTS[{"F2": "FL2"}.get(light, light)].copy().align(SHAPE_1NM)
    xyz = np.array(
        [colour.sd_to_XYZ(sd.copy().align(SHAPE_1NM), CIE1931, ill, method="Integration") for sd in CHECKER.values()]
    )
    white = colour.sd_to_XYZ(colour.sd_ones(SHAPE_1NM), CIE1931, ill, method="Integration")
    return xyz / 100.0, white / 100.0


# --- white normalisation ---------------------------------------------------------


@pytest.mark.parametrize("grid", [SpectralGrid(360, 780, 1), REFERENCE_GRID, SpectralGrid(400, 700, 20)])
def test_xyz_scale_makes_white_diffuser_y_one(grid: SpectralGrid) -> None:
    e = light_spectrum("D65", grid)
    # independent: Y of radiance E/pi is sum(E ybar) dl / pi
    y = float(np.sum(e * cmfs(grid)[:, 1]) * grid.step / np.pi)
    assert xyz_scale(e, grid) == pytest.approx(1.0 / y, rel=1e-12)
    assert white_xyz(e, grid)[1] == pytest.approx(1.0, abs=1e-12)


def test_spectra_to_xyz_on_1nm_grid_is_plain_sum() -> None:
    g = SpectralGrid(360, 830, 1)
    rng = np.random.default_rng(1)
    s = rng.random((4, g.size))
    assert np.allclose(spectra_to_xyz(s, g), s @ CIE1931.values, rtol=1e-12)


def test_white_diffuser_under_d65_is_srgb_white() -> None:
    w = white_xyz(light_spectrum("D65"))
    assert np.allclose(xyz_to_linear_srgb(w, w), 1.0, atol=1e-3)
    # without adaptation the 5-nm D65 white is already within the grid error of sRGB white
    assert np.allclose(xyz_to_linear_srgb(w, w, adapt=False), 1.0, atol=2e-3)
    assert xyz_to_srgb8(w, w).tolist() == [255, 255, 255]


@pytest.mark.parametrize("method", ["CAT02", "Bradford", "bradford"])
def test_white_under_a_adapts_to_white(method: str) -> None:
    w = white_xyz(light_spectrum("A"))
    assert np.allclose(xyz_to_linear_srgb(w, w, method=method), 1.0, atol=1e-9)
    raw = xyz_to_linear_srgb(w, w, adapt=False)
    assert raw[0] > 1.2 and raw[2] < 0.5  # tungsten seen with daylight balance: orange


def test_xyz_to_linear_srgb_matches_colour_science_adaptation() -> None:
    w = white_xyz(light_spectrum("A"))
    xyz = np.array([[0.2, 0.3, 0.1], [0.5, 0.4, 0.2]])
    adapted = colour.chromatic_adaptation(xyz, w, D65_XYZ, method="Von Kries", transform="CAT02")
    expected = colour.XYZ_to_RGB(
        adapted, "sRGB", apply_cctf_encoding=False
    )
    assert np.allclose(xyz_to_linear_srgb(xyz, w), expected, atol=5e-4)


def test_vectorised_over_images_and_float32() -> None:
    w = white_xyz(light_spectrum("D65"))
    img = np.random.default_rng(0).random((5, 7, 3)).astype(np.float32)
    out = xyz_to_linear_srgb(img, w)
    assert out.shape == (5, 7, 3) and out.dtype == np.float32
    assert np.allclose(out[2, 3], xyz_to_linear_srgb(img[2, 3].astype(np.float64), w), atol=1e-6)
    spectra = np.ones((2, 3, 61), dtype=np.float32)
    assert spectra_to_xyz(spectra).dtype == np.float32


# --- against colour-science -----------------------------------------------------------


def test_colorchecker_under_d65_matches_colour_science() -> None:
    xyz, w = _render_checker("D65", REFERENCE_GRID)
    ref_xyz = np.array([colour.sd_to_XYZ(sd, CIE1931, colour.SDS_ILLUMINANTS["D65"]) for sd in CHECKER.values()]) / 100
    ref_rgb = colour.XYZ_to_sRGB(ref_xyz, apply_cctf_encoding=False)
    assert np.abs(xyz_to_linear_srgb(xyz, w) - ref_rgb).max() < 2e-3
    assert delta_e00(xyz, ref_xyz, D65_XYZ).max() < 0.15


@pytest.mark.parametrize("light", ["D65", "A", "F2"])
@pytest.mark.parametrize("step, adapted_bound, absolute_bound", [(5, 0.1, 0.1), (10, 0.25, 1.2), (20, 1.0, 3.0)])
def test_coarse_grids_against_1nm_reference(light, step, adapted_bound, absolute_bound) -> None:
    """Stated accuracy of coarse grids (CIEDE2000 on the 24 ColorChecker patches,
    docs/materials.md): of the displayed colour (each side adapted from its own
    white to D65) and of the absolute XYZ."""
    xyz, w = _render_checker(light, SpectralGrid(400, 700, step))
    ref, ref_w = _reference_checker(light)
    assert delta_e00(xyz, ref, ref_w).max() < absolute_bound
    shown = colour.sRGB_to_XYZ(xyz_to_linear_srgb(xyz, w), apply_cctf_decoding=False)
    shown_ref = colour.sRGB_to_XYZ(xyz_to_linear_srgb(ref, ref_w), apply_cctf_decoding=False)
    assert delta_e00(shown, shown_ref, D65_XYZ).max() < adapted_bound


def test_delta_e00_against_sharma_test_data() -> None:
    # Sharma, Wu & Dalal (2005), CIEDE2000 test pairs 1 and 17
    lab_a = np.array([[50.0, 2.6772, -79.7751], [50.0, 2.5, 0.0]])
    lab_b = np.array([[50.0, 0.0, -82.7485], [73.0, 25.0, -18.0]])
    xy = colour.XYZ_to_xy(D65_XYZ)
    de = delta_e00(colour.Lab_to_XYZ(lab_a, xy), colour.Lab_to_XYZ(lab_b, xy), D65_XYZ)
    assert np.allclose(de, [2.0425, 27.1492], atol=1e-4)
    # a white with Y != 1 is rescaled
    assert np.allclose(delta_e00(colour.Lab_to_XYZ(lab_a, xy) * 3, colour.Lab_to_XYZ(lab_b, xy) * 3, D65_XYZ * 3), de)


# --- gamut mapping and encoding ------------------------------------------------------


RGB = arrays(np.float64, (16, 3), elements=st.floats(-5.0, 5.0))


@settings(max_examples=60, deadline=None)
@given(rgb=RGB, policy=st.sampled_from(["desaturate", "clip"]))
def test_gamut_map_output_in_unit_cube(rgb: np.ndarray, policy: str) -> None:
    out = gamut_map(rgb, policy)
    assert out.shape == rgb.shape
    assert np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() <= 1.0


@settings(max_examples=60, deadline=None)
@given(rgb=arrays(np.float64, (16, 3), elements=st.floats(-1.0, 1.0)))
def test_desaturate_keeps_luminance_and_hue_line(rgb: np.ndarray) -> None:
    out = gamut_map(rgb)
    y = rgb @ SRGB_LUMINANCE
    for src, dst, lum in zip(rgb, out, y):
        if src.min() >= 0:
            assert np.allclose(dst, src)  # in gamut: untouched
        elif lum <= 0:
            assert np.all(dst == 0.0)
        elif dst.max() < 1.0:  # no highlight clipping happened
            assert dst @ SRGB_LUMINANCE == pytest.approx(lum, abs=1e-12)
            assert dst.min() == pytest.approx(0.0, abs=1e-12)
            # on the segment from the grey of equal luminance to the source colour
            t = (dst - lum) / (src - lum + 1e-300)
            assert np.allclose(t[np.abs(src - lum) > 1e-9], t[np.argmax(np.abs(src - lum))], atol=1e-9)


def test_clip_policy_and_highlight_clip() -> None:
    assert gamut_map([1.5, 0.5, -0.2], "clip").tolist() == [1.0, 0.5, 0.0]
    assert gamut_map([2.0, 2.0, 2.0]).tolist() == [1.0, 1.0, 1.0]


def test_encode_srgb8_matches_colour_cctf() -> None:
    v = np.linspace(0, 1, 1001)
    expected = np.round(colour.cctf_encoding(v, function="sRGB") * 255).astype(np.uint8)
    assert np.array_equal(encode_srgb8(v), expected)
    assert encode_srgb8([-1.0, 2.0]).tolist() == [0, 255]


def test_xyz_to_srgb8_out_of_gamut_is_finite() -> None:
    w = white_xyz(light_spectrum("D65"))
    spectral_locus_green = np.array([0.1, 0.8, 0.05])  # far outside sRGB
    out = xyz_to_srgb8(spectral_locus_green, w)
    assert out.dtype == np.uint8 and out[1] > out[0] and out[1] > out[2]


# --- errors -----------------------------------------------------------------------------


def test_errors() -> None:
    w = white_xyz(light_spectrum("D65"))
    with pytest.raises(ValueError, match="61 wavelengths"):
        spectra_to_xyz(np.ones(31))
    with pytest.raises(ValueError, match="NaN"):
        spectra_to_xyz(np.full(61, np.nan))
    with pytest.raises(ValueError, match="shape \\(61,\\)"):
        xyz_scale(np.ones(10))
    with pytest.raises(ValueError, match=">= 0"):
        xyz_scale(-np.ones(61))
    with pytest.raises(ValueError, match="Y = 0"):
        xyz_scale(np.zeros(61))
    with pytest.raises(ValueError, match="source_white"):
        xyz_to_linear_srgb([0.5, 0.5, 0.5], [1.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="CAT02"):
        xyz_to_linear_srgb([0.5, 0.5, 0.5], w, method="magic")
    with pytest.raises(ValueError, match="last axis"):
        xyz_to_linear_srgb([0.5, 0.5], w)
    with pytest.raises(ValueError, match="desaturate, clip"):
        gamut_map([0.5, 0.5, 0.5], "compress")
    with pytest.raises(ValueError, match="NaN"):
        gamut_map([np.nan, 0.5, 0.5])
    with pytest.raises(ValueError, match="NaN"):
        encode_srgb8([np.inf])
    with pytest.raises(ValueError, match="SpectralGrid"):
        spectra_to_xyz(np.ones(61), grid=np.arange(400, 701, 5))  # type: ignore[arg-type]
