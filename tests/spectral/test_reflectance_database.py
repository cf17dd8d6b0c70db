"""Reflectance databases: built-in sets against colour-science, user CSV errors, near-duplicate removal."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from processing.spectral.reflectance_database import (
    ReflectanceDatabaseError,
    combine,
    load_reflectances,
    near_duplicates,
    read_reflectance_csv,
    without_near_duplicates,
)
from processing.spectral.spectra import SpectralGrid

G = SpectralGrid(400, 700, 10)


def test_builtin_sets_sample_the_colour_science_tables():
    train = load_reflectances("training", G)
    assert train.spectra.shape == (190, G.size)
    td = colour.characterisation.read_training_data_rawtoaces_v1()
    col = td.values[:, 5]
    assert np.allclose(train.spectra[5], np.interp(G.wavelengths, td.wavelengths, col))
    chart = load_reflectances("colorchecker", G)
    red = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["red"]
    i = chart.names.index("red")
    assert np.allclose(chart.spectra[i], np.interp(G.wavelengths, red.wavelengths, red.values))


def test_near_duplicates_of_the_chart_are_removed_and_nothing_else():
    train, chart = load_reflectances("training", G), load_reflectances("colorchecker", G)
    held = without_near_duplicates(train, chart)
    d = np.sqrt(((held.spectra[:, None, :] - chart.spectra[None]) ** 2).mean(-1)).min(1)
    assert d.min() >= 0.0125
    removed = len(train) - len(held)
    assert 5 <= removed <= 20
    # the GFC criterion only adds removals
    assert len(without_near_duplicates(train, chart, gfc=0.9999)) <= len(held)


def test_near_duplicates_threshold_is_rmse_over_the_grid():
    a = np.full((1, 10), 0.5)
    assert near_duplicates(a, a + 0.0124).tolist() == [True]
    assert near_duplicates(a, a + 0.0126).tolist() == [False]
    assert near_duplicates(a, 2 * a, rmse=0.0, gfc=0.999).tolist() == [True]     # same shape, other level


def test_user_csv_combines_with_a_builtin_set(tmp_path):
    p = tmp_path / "lacquers.csv"
    rows = ["nm,black,red"] + [f"{w:g},0.02,{0.05 + 0.8 * (w > 600):g}" for w in range(380, 781, 5)]
    p.write_text("\n".join(rows))
    mine = read_reflectance_csv(p, G)
    assert mine.names == ("black", "red") and np.allclose(mine.spectra[0], 0.02)
    both = combine(load_reflectances("colorchecker", G), load_reflectances(p, G))
    assert len(both) == 26 and both.names[-1] == "red"


@pytest.mark.parametrize(
    "text, words",
    [
        ("nm,a\n400,0.1\n500,x\n700,0.2\n", "line 3, column 2: not a number"),
        ("400,0.1,0.2\n500,0.1\n700,0.1,0.2\n", "line 2: 2 columns"),
        ("400,0.1\n550,nan\n700,0.2\n", "line 2, column 2: NaN"),
        ("400,0.1\n550,45\n700,0.2\n", "line 2, column 2: reflectance 45 outside"),
        ("400,0.1\n350,0.1\n700,0.2\n", "line 2, column 1: wavelength 350"),
        ("450,0.1\n700,0.2\n", "do not cover the grid"),
        ("400,0.1\n", "at least two"),
    ],
)
def test_bad_csv_names_the_line_and_column(tmp_path, text, words):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(ReflectanceDatabaseError, match=words):
        read_reflectance_csv(p, G)


def test_unknown_database_and_bad_arrays_raise():
    with pytest.raises(ReflectanceDatabaseError, match="unknown reflectance database"):
        load_reflectances("munsell", G)
    with pytest.raises(ReflectanceDatabaseError, match="NaN"):
        near_duplicates(np.full((2, 3), np.nan), np.ones((1, 3)))
    with pytest.raises(ReflectanceDatabaseError, match="non-empty"):
        near_duplicates(np.ones((0, 3)), np.ones((1, 3)))
    with pytest.raises(ReflectanceDatabaseError, match="differ in length"):
        near_duplicates(np.ones((2, 3)), np.ones((1, 4)))
