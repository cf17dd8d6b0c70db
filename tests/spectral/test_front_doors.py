"""The spectral front doors export their modules' public names; METHODS maps each method to its fit."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import processing.spectral as spectral
import processing.spectral.estimation as estimation
from processing.camera.response import camera_sensitivities
from processing.spectral.estimation import estimator
from processing.spectral.estimation.root_polynomial_finlayson import fit_rootpoly
from processing.spectral.reflectance_database import load_reflectances
from processing.spectral.spectra import SpectralGrid, light_spectrum


@pytest.mark.parametrize("door", [spectral, estimation], ids=lambda d: d.__name__)
def test_a_front_door_exports_each_name_of_its_modules(door):
    for name in door.__all__:
        obj = getattr(door, name)
        home = getattr(obj, "__module__", None)
        if home and home.startswith(door.__name__):
            assert getattr(importlib.import_module(home), name) is obj


def test_methods_keep_their_names_and_order():
    assert tuple(estimation.METHODS) == ("paper", "wiener", "rootpoly", "more-basis", "twolight")
    assert estimation.METHODS is estimator.METHODS
    assert estimation.METHODS["paper"] is estimation.fit_paper
    assert estimation.METHODS["more-basis"] is estimation.fit_more_basis


def test_more_basis_is_root_polynomial_regression_of_degree_one():
    g = SpectralGrid(400, 700, 20)
    db = load_reflectances("training", g).spectra
    s, e = camera_sensitivities(g), light_spectrum("D65", g)
    fit = estimation.fit_estimator("more-basis", db, s, e, g, p=5)
    same = fit_rootpoly(db, s, e, g, p=5, degree=1)
    assert (fit.method, fit.expansion) == ("more-basis", "linear")
    assert np.array_equal(fit.matrix, same.matrix) and np.array_equal(fit.basis, same.basis)
