"""A bad swatch geometry file is refused in one line naming the field and its physical range."""

from __future__ import annotations

import json

import pytest

from app.cli import main
from processing.cloth.swatch_geometry import SwatchGeometry, SwatchGeometryError


@pytest.mark.parametrize("data, words", [
    ([1, 2, 3], ("must be a JSON table", "got a list")),
    ({"light_direction": "up"}, ("light_direction must be three numbers", "'up'")),
    ({"fov_deg": 1e-9}, ("fov_deg must be a number in [0.5, 170]", "degrees")),
    ({"fov_deg": 179.0}, ("fov_deg must be a number in [0.5, 170]",)),
    ({"swatch_mm": 1e300}, ("swatch_mm must be a number in [1, 1000]", "mm")),
    ({"camera_distance_mm": 1e300}, ("camera_distance_mm must be a number in [10, 10000]", "10 m")),
    ({"camera_distance_mm": "far"}, ("camera_distance_mm must be a number",)),
    ({"warp_angle_deg": "x"}, ("warp_angle_deg must be a finite number of degrees",)),
    ({"light": 3}, ("light must be a name",)),
    ({"pass_light_directions": ["up"]}, ("the light of pass 2 must be three numbers",)),
])
def test_bad_fields_are_named_with_their_range(data, words):
    with pytest.raises(SwatchGeometryError) as err:
        SwatchGeometry.from_dict(data)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_sensible_set_ups_are_kept():
    g = SwatchGeometry.from_dict({"width": 64, "height": 48, "swatch_mm": 60, "fov_deg": 0.5,
                                  "camera_distance_mm": 10_000, "light_direction": [0, 0, 2]})
    assert g.light_direction == (0.0, 0.0, 1.0) and SwatchGeometry.from_dict(g.to_dict()) == g


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """An empty swatch session: the geometry file is read before any frame."""
    from app.capture.runner import CapturePlan
    from app.session import Session

    root = tmp_path_factory.mktemp("swatch") / "s"
    Session.create(root, plan={**CapturePlan("swatch", steps=4, passes=1).to_dict(), "kind": "swatch"}).close()
    return root


@pytest.mark.parametrize("text, words", [
    (json.dumps({"light_direction": "up"}), ("light_direction",)),
    (json.dumps([1, 2]), ("must be a JSON table",)),
    (json.dumps({"swatch_mm": 1e300}), ("swatch_mm", "[1, 1000]")),
])
def test_cloth_fit_refuses_a_bad_geometry_file_in_one_line(session, tmp_path, capsys, text, words):
    bad = tmp_path / "geometry.json"
    bad.write_text(text)
    capsys.readouterr()
    assert main(["cloth", "fit", str(session), "--geometry", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    assert "geometry.json" in err, err
    assert all(w in err for w in words), err
