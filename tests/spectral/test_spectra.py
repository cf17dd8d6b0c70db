"""Wavelength grids, colour-matching functions, light spectra and resampling."""

from __future__ import annotations

from pathlib import Path

import colour
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.spectral.spectra import (
    REFERENCE_GRID,
    SpectralGrid,
    cmfs,
    illuminant_names,
    light_spectrum,
    resample,
)

CIE1931 = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]


# --- SpectralGrid -------------------------------------------------------------


def test_reference_grid() -> None:
    assert REFERENCE_GRID.size == 61
    wl = REFERENCE_GRID.wavelengths
    assert wl.dtype == np.float64 and wl[0] == 400.0 and wl[-1] == 700.0
    assert np.allclose(np.diff(wl), 5.0)


@pytest.mark.parametrize("step, size", [(10, 31), (20, 16), (30, 11), (50, 7), (100, 4)])
def test_coarse_grids(step: float, size: int) -> None:
    g = SpectralGrid(400, 700, step)
    assert g.size == size and g.wavelengths[-1] == 700.0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"step": 0}, "step must be > 0"),
        ({"step": -5}, "step must be > 0"),
        ({"step": 7}, "does not divide"),
        ({"start": 300}, "360"),
        ({"stop": 900}, "830"),
        ({"start": 700, "stop": 400}, "start < stop"),
        ({"step": float("nan")}, "finite"),
        ({"step": "5"}, "number"),
    ],
)
def test_grid_validation(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SpectralGrid(**kwargs)


# --- colour-matching functions -----------------------------------------------------


def test_cmfs_on_the_1nm_grid_are_the_cie_table() -> None:
    c = cmfs(SpectralGrid(360, 830, 1))
    assert np.allclose(c, CIE1931.values, rtol=0, atol=1e-15)


@pytest.mark.parametrize(
    "grid", [REFERENCE_GRID, SpectralGrid(400, 700, 10), SpectralGrid(400, 700, 20), SpectralGrid(380, 780, 40)]
)
def test_cmfs_partition_the_integral(grid: SpectralGrid) -> None:
    # the hat functions (extended at the ends) sum to 1 everywhere, so the
    # integral of a constant spectrum is the 1-nm total of the CIE tables.
    total = CIE1931.values.sum(axis=0) * 1.0
    assert np.allclose(cmfs(grid).sum(axis=0) * grid.step, total, rtol=1e-12)


def test_cmfs_integrate_linear_spectra_exactly() -> None:
    # a spectrum that is linear in wavelength is reproduced exactly by the
    # piecewise-linear reading of its samples, so every grid gives the 1-nm sum
    wl1 = CIE1931.wavelengths
    slope = lambda wl: 0.2 + 0.001 * (np.clip(wl, 400, 700) - 400)  # noqa: E731
    reference = slope(wl1) @ CIE1931.values
    for step in (5, 10, 20, 50, 100):
        g = SpectralGrid(400, 700, step)
        assert np.allclose(slope(g.wavelengths) @ cmfs(g) * step, reference, rtol=1e-9)


def test_cmfs_read_only_and_cached() -> None:
    c = cmfs(REFERENCE_GRID)
    assert c.shape == (61, 3) and not c.flags.writeable
    assert cmfs(SpectralGrid()) is c


# --- resample ------------------------------------------------------------------------


def test_resample_identity_and_linear_exactness() -> None:
    wl = REFERENCE_GRID.wavelengths
    v = np.sin(wl / 37.0) ** 2
    assert np.array_equal(resample(wl, v, REFERENCE_GRID), v)
    lin = 0.3 + 0.002 * (wl - 400)
    g = SpectralGrid(400, 700, 20)
    assert np.allclose(resample(wl, lin, g), 0.3 + 0.002 * (g.wavelengths - 400), atol=1e-14)
    assert np.allclose(resample(wl, lin, g, method="average"), 0.3 + 0.002 * (g.wavelengths - 400), atol=1e-12)


def test_resample_stack_and_arbitrary_targets() -> None:
    wl = np.array([400.0, 550.0, 700.0])
    vals = np.array([[0.0, 1.0, 0.0], [1.0, 1.0, 1.0]])
    out = resample(wl, vals, [475.0, 625.0])
    assert np.allclose(out, [[0.5, 0.5], [1.0, 1.0]])


def test_average_preserves_the_integral_of_a_narrow_line() -> None:
    # a 2-nm wide emission line on a 1-nm source: point sampling on a 20-nm grid
    # misses it; the hat average keeps its integral (the hats partition unity)
    wl = np.arange(380.0, 721.0, 1.0)
    line = np.exp(-0.5 * ((wl - 546.0) / 1.0) ** 2)
    g = SpectralGrid(400, 700, 20)
    integral = np.trapezoid(line, wl)
    assert resample(wl, line, g).sum() * 20 == pytest.approx(0.0, abs=1e-3)
    assert resample(wl, line, g, method="average").sum() * 20 == pytest.approx(integral, rel=1e-6)


@pytest.mark.parametrize(
    "src, vals, target, match",
    [
        ([450, 700], [1, 1], REFERENCE_GRID, "covers 450-700 nm"),
        ([700, 400], [1, 1], REFERENCE_GRID, "strictly increasing"),
        ([400, 700], [1, np.nan], REFERENCE_GRID, "NaN"),
        ([400, 700], [1, 1, 1], REFERENCE_GRID, "last axis"),
        ([400], [1], REFERENCE_GRID, "at least two"),
    ],
)
def test_resample_errors(src, vals, target, match) -> None:
    with pytest.raises(ValueError, match=match):
        resample(src, vals, target)


def test_resample_unknown_method() -> None:
    with pytest.raises(ValueError, match="'interpolate' or 'average'"):
        resample([400, 700], [1, 1], REFERENCE_GRID, method="cubic")


# --- light spectra -------------------------------------------------------------------


def test_d65_is_the_cie_table_normalised_at_560() -> None:
    e = light_spectrum("D65")
    d65 = colour.SDS_ILLUMINANTS["D65"]
    expected = np.array([d65[w] for w in REFERENCE_GRID.wavelengths]) / d65[560]
    assert np.allclose(e, expected, rtol=1e-12)
    assert e[32] == 1.0  # 560 nm


def test_names_are_case_insensitive_and_f_aliases() -> None:
    assert np.array_equal(light_spectrum("d65"), light_spectrum("D65"))
    assert np.array_equal(light_spectrum("f2"), light_spectrum("FL2"))
    assert {"A", "D50", "D65", "F2", "FL11"} <= set(illuminant_names())


def test_nearest_sample_to_560_when_not_on_grid() -> None:
    g = SpectralGrid(400, 700, 30)  # 550 and 580: 550 is nearest
    e = light_spectrum("A", g)
    assert e[list(g.wavelengths).index(550.0)] == 1.0


def test_planck_below_4000k_matches_colour_blackbody() -> None:
    sd = colour.sd_blackbody(3200, colour.SpectralShape(400, 700, 5))
    expected = sd.values / sd[560]
    for spec in ("3200K", "3200k", 3200, 3200.0, " 3200 K"):
        assert np.allclose(light_spectrum(spec), expected, rtol=1e-3)


def test_illuminant_a_is_planck_at_2856k() -> None:
    # CIE A: Planck at 2848 K with c2 = 1.435e-2, i.e. 2856 K with c2 = 1.4388e-2
    assert np.allclose(light_spectrum("2856K"), light_spectrum("A"), rtol=2e-3)


def test_daylight_from_4000k_and_6500k_is_d65() -> None:
    assert np.allclose(light_spectrum("6500K"), light_spectrum("D65"), rtol=1e-3)
    assert np.allclose(light_spectrum("5000K"), light_spectrum("D50"), rtol=1e-3)
    # daylight has the CIE daylight shape, not a blackbody
    assert not np.allclose(light_spectrum(4000), light_spectrum(3999), rtol=0.02)


def test_cct_ordering_blue_to_red() -> None:
    ratio = [light_spectrum(t)[0] / light_spectrum(t)[-1] for t in (2000, 3000, 5000, 10000, 25000)]
    assert all(a < b for a, b in zip(ratio, ratio[1:]))


@pytest.mark.parametrize("spec", ["999K", 25001, "0K"])
def test_cct_out_of_range(spec) -> None:
    with pytest.raises(ValueError, match="1000-25000 K"):
        light_spectrum(spec)


def test_unknown_light_lists_valid_names() -> None:
    with pytest.raises(ValueError, match=r"unknown light 'candle'.*D65.*3200K.*CSV"):
        light_spectrum("candle")


def test_light_rejects_bad_types_and_grid() -> None:
    with pytest.raises(ValueError, match="light spec"):
        light_spectrum(True)
    with pytest.raises(ValueError, match="light spec"):
        light_spectrum([1, 2])  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="SpectralGrid"):
        light_spectrum("D65", np.arange(400, 701, 5))  # type: ignore[arg-type]


def test_light_range_outside_source() -> None:
    with pytest.raises(ValueError, match="FL2.*380-780 nm"):
        light_spectrum("F2", SpectralGrid(360, 800, 10))


# --- CSV lights ------------------------------------------------------------------------


def _write(tmp_path: Path, text: str, name: str = "lamp.csv") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_csv_with_header_comments_and_separators(tmp_path: Path) -> None:
    rows = "\n".join(f"{w:g}; {0.5 + 0.001 * (w - 380):g}" for w in range(380, 781, 10))
    p = _write(tmp_path, "# measured lamp\nwavelength_nm;power\n\n" + rows + "\n")
    e = light_spectrum(p)
    wl = REFERENCE_GRID.wavelengths
    expected = (0.5 + 0.001 * (wl - 380)) / (0.5 + 0.001 * 180)
    assert np.allclose(e, expected, rtol=1e-12)
    q = _write(tmp_path, rows.replace(";", "\t"), "lamp.tsv")
    assert np.allclose(light_spectrum(str(q)), expected)


def test_csv_without_power_at_560_is_normalised_to_its_peak(tmp_path: Path) -> None:
    p = _write(tmp_path, "400,0\n600,0\n620,2\n640,0\n700,0\n")
    e = light_spectrum(p)
    assert e.max() == 1.0 and e[32] == 0.0


@pytest.mark.parametrize(
    "text, match",
    [
        ("400,1\n500,abc\n700,1\n", r"lamp.csv, line 2: expected two numbers"),
        ("nm,value\nnm,value\n400,1\n700,1\n", r"line 2"),
        ("400,1\n500,2,3\n700,1\n", r"line 2: expected two columns"),
        ("400,1\n600,1\n500,1\n700,1\n", r"line 3: wavelength 500 nm does not increase"),
        ("400,1\n500,-1\n700,1\n", r"line 2: spectral power must be >= 0"),
        ("400,1\n", r"at least two"),
        ("400,0\n700,0\n", r"every spectral power value is zero"),
        ("450,1\n700,1\n", r"covers 450-700 nm"),
        ("0.4,1\n0.7,1\n", r"wavelengths are in nm|covers 0.4-0.7 nm"),
    ],
)
def test_csv_errors_name_file_and_line(tmp_path: Path, text: str, match: str) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(ValueError, match=match):
        light_spectrum(p)


def test_missing_csv_file(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="does not exist"):
        light_spectrum(tmp_path / "nothing.csv")


@settings(max_examples=30, deadline=None)
@given(t=st.floats(1000, 25000))
def test_any_temperature_is_finite_positive(t: float) -> None:
    e = light_spectrum(t, SpectralGrid(400, 700, 20))
    assert np.all(np.isfinite(e)) and np.all(e > 0)
