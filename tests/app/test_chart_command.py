"""``kogei chart``: report on a simulated chart frame, manual corners, one-line errors with exit code 2."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.cli import main
from mocks.chart_scene import ChartPlacement
from tests.camera.chart_shots import chart_shot

PLACEMENT = ChartPlacement(size=0.6, rotation_deg=-8, tilt_deg=(0, 12))


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    return chart_shot(tmp_path_factory.mktemp("cli"), "classic24", chart_placement=PLACEMENT)


def test_detects_samples_and_writes_json(shot, tmp_path, capsys):
    out = tmp_path / "chart.json"
    assert main(["chart", str(shot.path), "--json", str(out)]) == 0
    line = capsys.readouterr().out
    assert "classic24 chart found by mcc" in line and "24 of 24 patches usable" in line
    report = json.loads(out.read_text())
    assert report["format"] == "kogei-chart" and report["iso"] == 100 and report["white_level"] == 16383
    centres = np.array([p["centre"] for p in report["patches"]])
    assert np.linalg.norm(centres - shot.label_centres(), axis=1).max() < 1.5
    assert report["patches"][18]["name"] == "white 9.5" and report["patches"][18]["usable"]


def test_manual_corners(shot, capsys):
    corners = ",".join(f"{v:.2f}" for v in shot.frame.chart_corners.ravel())
    assert main(["chart", str(shot.path), "--chart-corners", corners, "--mode", "demosaic"]) == 0
    assert "from the given corners; 24 of 24 patches usable" in capsys.readouterr().out


def test_corners_in_the_wrong_order_exit_2(shot, capsys):
    c = shot.frame.chart_corners[[2, 3, 0, 1]]
    assert main(["chart", str(shot.path), "--chart-corners", ",".join(f"{v:.2f}" for v in c.ravel())]) == 2
    err = capsys.readouterr().err
    assert "out of order" in err and len(err.strip().splitlines()) == 1


def test_bad_inputs_exit_2(tmp_path, capsys):
    jpeg = tmp_path / "frame.dng"
    jpeg.write_bytes(b"\xff\xd8\xff\xe0" + bytes(200))
    assert main(["chart", str(jpeg)]) == 2
    assert "this is a JPEG, not a RAW file" in capsys.readouterr().err
    blank = chart_shot(tmp_path, "classic24", chart_present=False, width=200, height=140)
    assert main(["chart", str(blank.path)]) == 2
    assert "no classic24 chart found" in capsys.readouterr().err
    assert main(["chart", str(blank.path), "--chart-corners", "1,2,3"]) == 2
    assert "need 8 numbers" in capsys.readouterr().err


@pytest.mark.parametrize("wrong", ["sg140", "vinyl18"])
def test_the_wrong_chart_type_is_one_short_line_that_suggests_the_others(shot, capsys, wrong):
    """A ColorChecker frame read as another chart: one short line that names the other chart types."""
    corners = ",".join(f"{v:.2f}" for v in shot.frame.chart_corners.ravel())
    for extra in ([], ["--chart-corners", corners]):
        assert main(["chart", str(shot.path), "--chart", wrong, *extra]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and len(err) < 450, err
        assert "other types: classic24" in err, err
