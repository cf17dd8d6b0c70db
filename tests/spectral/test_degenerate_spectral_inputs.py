"""Non-physical sensitivities, all-zero reflectance sets and singular systems are refused in one line."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from app.cli import main
from app.cli.spectral import _refuse_non_finite
from app.errors import UsageError
from processing.camera.response import CameraResponseError, camera_sensitivities
from processing.spectral.estimation.estimator import fit_estimator
from processing.spectral.estimation.fit import SpectralEstimationError
from processing.spectral.reflectance_database import ReflectanceDatabaseError, read_reflectance_csv
from processing.spectral.spectra import SpectralGrid, light_spectrum
from tests.spectral.spectral_shots import board_dng, chart_dng

GRID = SpectralGrid(400, 700, 10)
WL = np.arange(380, 781, 10)


def _csv(path: Path, columns: list[np.ndarray]) -> Path:
    rows = np.column_stack([WL, *columns])
    path.write_text("\n".join(",".join(f"{v:.6g}" for v in row) for row in rows) + "\n")
    return path


def test_sensitivities_that_overflow_are_refused_by_line(tmp_path):
    huge = _csv(tmp_path / "cam.csv", [np.full(WL.size, 1e300)] * 3)
    with pytest.raises(CameraResponseError, match=r"cam.csv, line 1, column 2: a sensitivity must be at most 1e\+06"):
        camera_sensitivities(GRID, huge)


def test_sensitivities_of_ordinary_size_are_kept(tmp_path):
    ok = _csv(tmp_path / "cam.csv", [np.full(WL.size, 100.0), np.ones(WL.size), np.full(WL.size, 0.5)])
    assert camera_sensitivities(GRID, ok)[0].tolist() == [100.0, 1.0, 0.5]


def test_an_all_zero_reflectance_set_is_refused_by_name(tmp_path):
    zero = _csv(tmp_path / "zero.csv", [np.zeros(WL.size)] * 4)
    with pytest.raises(ReflectanceDatabaseError, match="zero.csv: every reflectance is 0 over 400-700 nm"):
        read_reflectance_csv(zero, GRID)
    one_black = _csv(tmp_path / "black.csv", [np.zeros(WL.size), np.full(WL.size, 0.5)])
    assert read_reflectance_csv(one_black, GRID).spectra.shape == (2, GRID.size)


def test_a_singular_training_set_is_a_one_line_error():
    db = np.zeros((30, GRID.size))
    sens = camera_sensitivities(GRID)
    with pytest.raises(SpectralEstimationError, match="system is singular.*30 training reflectances"):
        fit_estimator("rootpoly", db, sens, light_spectrum("D65", GRID), GRID)


def test_a_result_with_nan_is_not_written():
    good = SimpleNamespace(weights=np.zeros((2, 2, 3)), camera=np.zeros((2, 2, 3)), metadata={"chart_rmse": 0.01})
    _refuse_non_finite(good, "r.npz")
    bad = SimpleNamespace(weights=np.full((2, 2, 3), np.nan), camera=np.zeros((2, 2, 3)),
                          metadata={"chart_rmse": float("nan")})
    with pytest.raises(UsageError, match=r"--out r.npz: not written: the estimate's basis weights and chart RMSE"):
        _refuse_non_finite(bad, "r.npz")


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    d = tmp_path_factory.mktemp("degenerate")
    return {"chart": chart_dng(d / "chart.dng", "D65", seed=1), "board": board_dng(d / "board.dng", "D65", seed=2)[0]}


@pytest.mark.parametrize("flag, columns, words", [
    ("--camera", [np.full(WL.size, 1e300)] * 3, ("--camera", "cam.csv", "at most 1e+06")),
    ("--chart-reflectances", [np.zeros(WL.size)] * 24, ("--chart-reflectances", "cam.csv", "every reflectance is 0")),
    ("--database", [np.zeros(WL.size)] * 30, ("--database", "cam.csv", "every reflectance is 0")),
])
def test_estimate_refuses_degenerate_files(shots, tmp_path, capsys, flag, columns, words):
    path = _csv(tmp_path / "cam.csv", columns)
    out = tmp_path / "r.npz"
    capsys.readouterr()
    assert main(["spectral", "estimate", str(shots["board"]), "--chart", str(shots["chart"]), flag, str(path),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    assert all(w in err for w in words), err
    assert not out.exists()
