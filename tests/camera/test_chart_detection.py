"""Chart detection on simulated DNG shots against the simulation's labels; manual corners; errors."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mocks.chart_scene import ChartPlacement, chart_corners
from processing.camera.chart_detection import (
    ChartDetectionError,
    ChartNotFoundError,
    ChartOutsideError,
    chart_from_corners,
    detect_chart,
    parse_corners,
)
from processing.camera.chart_layout import chart_layout
from processing.camera.chart_sampling import check_patches, sample_patches
from processing.camera.raw_decode import decode_raw, preview_srgb8
from tests.camera.chart_shots import chart_shot

PLACEMENTS = [
    ChartPlacement(),
    ChartPlacement(size=0.5, rotation_deg=25, tilt_deg=(20, 10)),
    ChartPlacement(size=0.6, rotation_deg=180),
    ChartPlacement(size=0.45, rotation_deg=-70, tilt_deg=(-25, 0), center=(0.45, 0.55)),
]


@pytest.mark.parametrize("placement", PLACEMENTS, ids=["square", "tilted", "upside-down", "steep"])
def test_classic_chart_found_at_its_labels(tmp_path, placement):
    shot = chart_shot(tmp_path, "classic24", chart_placement=placement)
    img = decode_raw(shot.path, mode="bin2x2")
    det = detect_chart(img, "classic24")
    truth = shot.label_centres()
    err = np.linalg.norm(det.centres - truth, axis=1)
    # patch 1 is dark skin wherever the chart lies: mcc resolves the orientation by colour
    assert err.max() < 1.5, err
    assert det.image_size == (600, 400) and det.method == "mcc" and det.confidence >= 0.9
    np.testing.assert_allclose(det.corners, shot.frame.chart_corners, atol=3.0)
    # each patch's quad encloses its labelled pixels' centroid
    assert np.all(det.quads.min(axis=1) < truth) and np.all(det.quads.max(axis=1) > truth)


def test_demosaiced_image_and_a_preview_array_map_to_the_same_sensor_pixels(tmp_path):
    shot = chart_shot(tmp_path, "classic24", chart_placement=PLACEMENTS[1])
    truth = shot.label_centres()
    demo = detect_chart(decode_raw(shot.path, mode="demosaic"))
    binned = decode_raw(shot.path, mode="bin2x2")
    from_array = detect_chart(preview_srgb8(binned), scale=2)
    for det in (demo, from_array):
        assert np.linalg.norm(det.centres - truth, axis=1).max() < 1.5


@pytest.mark.parametrize("layout", ["sg140", "vinyl18"])
def test_other_charts_found_at_their_labels(tmp_path, layout):
    shot = chart_shot(tmp_path, layout, chart_placement=ChartPlacement(size=0.6, rotation_deg=15, tilt_deg=(10, 0)))
    img = decode_raw(shot.path, mode="demosaic")
    det = detect_chart(img, layout)
    err = np.linalg.norm(det.centres - shot.label_centres(), axis=1)
    assert det.centres.shape[0] == {"sg140": 140, "vinyl18": 18}[layout]
    assert err.max() < 1.5, err
    # a good shot of either chart passes the checks: its neutral and hue orders hold
    assert check_patches(sample_patches(img, det)).usable.all()


@settings(max_examples=60, deadline=None)
@given(st.sampled_from(["classic24", "sg140", "vinyl18"]), st.floats(0.05, 3.0), st.floats(-180, 180),
       st.floats(-65, 65), st.floats(-65, 65), st.floats(-1, 2), st.floats(-1, 2))
def test_manual_corners_geometry_at_extreme_placements(chart, size, rot, tx, ty, cx, cy):
    """Any placement, however steep: the frame's corners come back, every centre lies inside its patch."""
    import cv2

    layout = chart_layout(chart)
    corners = chart_corners(layout, 640, 480, ChartPlacement((cx, cy), size, rot, (tx, ty)))
    det = chart_from_corners(corners, chart)
    np.testing.assert_allclose(det.corners, corners, atol=1e-6 * max(1.0, np.abs(corners).max()))
    assert np.all(np.isfinite(det.quads))
    for k in (0, layout.size // 2, layout.size - 1):
        quad = det.quads[k].astype(np.float32)
        assert cv2.pointPolygonTest(quad, tuple(float(v) for v in det.centres[k]), False) > 0


def test_manual_corners_reproduce_the_labels(tmp_path):
    shot = chart_shot(tmp_path, "classic24", width=300, height=200, chart_placement=PLACEMENTS[3])
    det = chart_from_corners(shot.frame.chart_corners, "classic24", image_size=(300, 200))
    assert det.method == "manual" and det.confidence == 1.0
    assert np.linalg.norm(det.centres - shot.label_centres(), axis=1).max() < 0.5
    # every labelled pixel of patch k lies in quad k
    import cv2

    lab = shot.frame.labels
    for k in (0, 11, 23):
        ys, xs = np.nonzero(lab == k)
        inside = [cv2.pointPolygonTest(det.quads[k].astype(np.float32), (float(x), float(y)), True) > -0.75
                  for x, y in zip(xs[::7], ys[::7])]
        assert all(inside)


def test_no_chart_in_view(tmp_path):
    shot = chart_shot(tmp_path, "classic24", chart_present=False)
    with pytest.raises(ChartNotFoundError, match=r"no classic24 chart found.*exposed.*--chart-corners x1,y1"):
        detect_chart(decode_raw(shot.path))


def test_chart_partly_outside_the_frame(tmp_path):
    shot = chart_shot(tmp_path, "classic24", chart_placement=ChartPlacement(size=0.6, center=(0.85, 0.5)))
    with pytest.raises(ChartOutsideError, match=r"partly outside the frame \(patches 5, 6, 11, 12"):
        detect_chart(decode_raw(shot.path))
    with pytest.raises(ChartOutsideError, match="reframe"):
        chart_from_corners(shot.frame.chart_corners, image_size=(600, 400))


def test_bad_corners_and_inputs():
    with pytest.raises(ChartDetectionError, match="4 finite"):
        chart_from_corners([[0, 0], [1, 1]])
    with pytest.raises(ChartDetectionError, match="convex quadrilateral"):
        chart_from_corners([[0, 0], [100, 100], [100, 0], [0, 100]])        # crossed (bow-tie)
    with pytest.raises(ChartDetectionError, match="convex quadrilateral"):
        chart_from_corners([[0, 0], [1, 0], [1, 1], [0, 1]])                 # a speck
    with pytest.raises(ChartDetectionError, match="need 8 numbers"):
        parse_corners("1,2,3")
    with pytest.raises(ChartDetectionError, match="not numbers"):
        parse_corners("a,b,c,d,e,f,g,h")
    with pytest.raises(ValueError, match="unknown chart 'classic42'"):
        chart_from_corners([[0, 0], [100, 0], [100, 70], [0, 70]], chart="classic42")
    with pytest.raises(ChartDetectionError, match="uint8"):
        detect_chart(np.zeros((50, 50, 3), np.float32))
