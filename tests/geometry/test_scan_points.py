"""Profiles -> table-frame point clouds: closed-form scans of a cylinder, a sphere and the table
through a deliberately non-ideal station; positions, normals, cropping, confidence, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.geometry.calibration import ScannerCalibration, calibrate_sphere, ideal_sensor_to_room
from processing.geometry.scan_points import ScanPoints, profiles_to_points

# ---------------------------------------------------------------------------- closed-form scanner
from tests.geometry.closed_form_scanner import Scan, gauge_fixed, rotation_error_deg, rz, scan, tilted_pose  # noqa: F401

ANGLES = np.arange(180) * 2.0
CYL = (10.0, -5.0, 30.0, 60.0)          # cx, cy, radius, height (mm), table frame
POST = (-95.0, 20.0, 4.0, 30.0)         # a thin post far from the axis
TOL = 0.5                               # table tolerance, mm


@pytest.fixture(scope="module")
def station():
    return tilted_pose()


@pytest.fixture(scope="module")
def noisy(station):
    s = scan(station, ANGLES, cylinders=[CYL], table_radius=150.0, noise=0.05, max_incidence_deg=85.0, seed=4)
    return s, profiles_to_points(s.x, s.z, ANGLES, station)


def on_side(points, margin=1.0):
    h = CYL[3]
    return (points[:, 2] > margin) & (points[:, 2] < h - margin)


def test_cylinder_points_land_on_its_surface(noisy):
    s, sp = noisy
    cx, cy, rc, h = CYL
    assert np.all(np.isfinite(sp.points)) and sp.points.shape == (sp.n_kept, 3)
    r = np.hypot(sp.points[:, 0] - cx, sp.points[:, 1] - cy)
    side = (s.label == 0)[sp.step, sp.column]
    assert side.all()                       # the table is cropped, the top cap is out of the sensor's view
    err = r - rc
    # 0.05 mm range noise; its radial part is smaller
    assert np.sqrt(np.mean(err**2)) < 0.055
    assert np.abs(err).max() < 0.3
    assert abs(err.mean()) < 0.005
    assert sp.points[:, 2].min() >= TOL and sp.points[:, 2].max() <= h + 0.3


def test_positions_match_the_exact_hits(station):
    s = scan(station, ANGLES, cylinders=[CYL], table_radius=150.0)
    sp = profiles_to_points(s.x, s.z, ANGLES, station)
    np.testing.assert_allclose(sp.points, s.point[sp.step, sp.column], atol=1e-9)


def test_normals_point_outward_and_toward_the_sensor(noisy):
    _, sp = noisy
    cx, cy, _, _ = CYL
    radial = np.stack([sp.points[:, 0] - cx, sp.points[:, 1] - cy, np.zeros(sp.n_kept)], 1)
    radial /= np.linalg.norm(radial, axis=1)[:, None]
    np.testing.assert_allclose(np.linalg.norm(sp.normals, axis=1), 1.0, atol=1e-9)
    err_deg = np.degrees(np.arccos(np.clip(np.sum(sp.normals * radial, axis=1), -1.0, 1.0)))
    inner = on_side(sp.points)
    assert sp.normal_estimated.all()
    # 0.05 mm range noise averaged over the default +-1.5 mm patch
    assert np.median(err_deg[inner]) < 0.8
    assert np.percentile(err_deg[inner], 99) < 2.5
    assert err_deg.max() < 10.0          # including the one-sided patches at the top and bottom edges
    to_sensor = sp.sensor_origins[sp.step] - sp.points
    assert np.all(np.sum(sp.normals * to_sensor, axis=1) > 0)


def test_sensor_origins_in_the_table_frame(station):
    s = scan(station, ANGLES[:4], cylinders=[CYL])
    sp = profiles_to_points(s.x, s.z, ANGLES[:4], station)
    a = np.radians(ANGLES[:4])
    o = station[:3, 3]
    want = np.stack([np.cos(a) * o[0] + np.sin(a) * o[1], -np.sin(a) * o[0] + np.cos(a) * o[1],
                     np.full(4, o[2])], 1)                      # Rz(-a) o
    np.testing.assert_allclose(sp.sensor_origins, want, atol=1e-12)


def test_table_and_radius_cropping_counts(station):
    s = scan(station, ANGLES, cylinders=[CYL, POST], table_radius=150.0)
    sp = profiles_to_points(s.x, s.z, ANGLES, station, table_tolerance_mm=TOL, max_radius_mm=80.0)
    valid = s.label >= 0
    z_true = s.point[..., 2]
    r_true = np.hypot(s.point[..., 0], s.point[..., 1])
    table = valid & (z_true < TOL)
    post = valid & ~table & (r_true > 80.0)
    assert (s.label == 4).sum() > 1000 and (s.label == 2).sum() > 100      # the table and the post are seen
    assert sp.n_cropped_table == table.sum() >= (s.label == 4).sum()
    assert sp.n_cropped_radius == post.sum() == ((s.label == 2) & ~table).sum()
    assert sp.n_invalid == (~valid).sum()
    assert sp.n_kept == (valid & ~table & ~post).sum()
    assert sp.n_total == s.x.size == sp.n_invalid + sp.n_cropped_table + sp.n_cropped_radius + sp.n_kept
    assert sp.points[:, 2].min() >= TOL
    assert np.hypot(sp.points[:, 0], sp.points[:, 1]).max() <= 80.0
    assert not np.isin(s.label[sp.step, sp.column], [2, 3, 4]).any()


def test_confidence_matches_incidence_and_range(noisy, station):
    s, sp = noisy
    # independent formula from the exact geometry: cos(incidence) x (1 - u^2)
    n_true = s.normal[sp.step, sp.column]
    to_sensor = sp.sensor_origins[sp.step] - s.point[sp.step, sp.column]
    cos_i = np.sum(n_true * to_sensor, axis=1) / np.linalg.norm(to_sensor, axis=1)
    u = (s.z[sp.step, sp.column] - 200.0) / 100.0
    want = cos_i * (1.0 - u * u)
    inner = on_side(sp.points)
    assert np.all((sp.confidence >= 0) & (sp.confidence <= 1))
    assert np.abs(sp.confidence - want)[inner].max() < 0.03
    assert np.median(np.abs(sp.confidence - want)) < 0.005


def test_confidence_ordering(station):
    # an off-axis cylinder crosses the laser plane at every incidence, frontal to grazing
    cyl = (35.0, 0.0, 20.0, 60.0)
    s = scan(station, ANGLES, cylinders=[cyl], table_radius=150.0, max_incidence_deg=89.0)
    sp = profiles_to_points(s.x, s.z, ANGLES, station)
    to_sensor = sp.sensor_origins[sp.step] - sp.points
    cos_i = np.sum(s.normal[sp.step, sp.column] * to_sensor, axis=1) / np.linalg.norm(to_sensor, axis=1)
    rng = s.z[sp.step, sp.column]
    side = on_side(sp.points)
    frontal = side & (cos_i > np.cos(np.radians(15.0)))
    # at similar ranges (140..180 mm: range factor 0.64..0.96) frontal beats grazing (> 70 deg)
    similar = side & (np.abs(rng - 160.0) < 20.0)
    grazing = similar & (cos_i < np.cos(np.radians(70.0)))
    assert (frontal & similar).sum() > 100 and grazing.sum() > 100
    assert sp.confidence[frontal & similar].min() > sp.confidence[grazing].max()
    # frontal at mid-range (180..220 mm) beats frontal near the far end of the range (> 270 mm)
    mid = frontal & (np.abs(rng - 200.0) < 20.0)
    far = scan(station, ANGLES, cylinders=[(-90.0, 0.0, 12.0, 60.0)], max_incidence_deg=89.0)
    spf = profiles_to_points(far.x, far.z, ANGLES, station)
    to_f = spf.sensor_origins[spf.step] - spf.points
    cos_f = np.sum(far.normal[spf.step, spf.column] * to_f, axis=1) / np.linalg.norm(to_f, axis=1)
    front_far = on_side(spf.points) & (cos_f > np.cos(np.radians(15.0))) & (far.z[spf.step, spf.column] > 270.0)
    assert mid.sum() > 100 and front_far.sum() > 50
    assert spf.confidence[front_far].max() < sp.confidence[mid].min()


def test_accepts_a_calibration_and_float32(station):
    s = scan(station, ANGLES, cylinders=[CYL], table_radius=150.0)
    cal = ScannerCalibration(station, 12.7, np.zeros(3), 0.0, 0.0, 10, 100, 100, 0.0, 12.7,
                             np.arange(3), np.zeros(3))
    a = profiles_to_points(s.x.astype(np.float32), s.z.astype(np.float32), ANGLES.astype(np.float32), cal)
    b = profiles_to_points(s.x, s.z, ANGLES, station)
    assert a.n_kept == b.n_kept
    # float32 storage: micrometre-level rounding of ~200 mm ranges
    np.testing.assert_allclose(a.points, b.points, atol=5e-5)


def test_end_to_end_with_a_calibrated_station(station):
    """Calibrate on a sphere, then scan the cylinder with the calibrated pose (room gauge differs, the
    cylinder must still be a cylinder about the same axis position relative to the gauge)."""
    ball = (np.array([45.0, 40.0, 12.7]), 12.7)
    sc = scan(station, ANGLES, spheres=[ball], table_radius=150.0, noise=0.05, seed=5)
    cal = calibrate_sphere(sc.x, sc.z, ANGLES, 12.7)
    s = scan(station, ANGLES, cylinders=[CYL], table_radius=150.0, noise=0.05, max_incidence_deg=85.0, seed=6)
    sp = profiles_to_points(s.x, s.z, ANGLES, cal)
    g = rz(np.array(-np.arctan2(station[1, 3], station[0, 3])))     # the calibration's gauge
    cx, cy, _ = g @ np.array([CYL[0], CYL[1], 0.0])
    r = np.hypot(sp.points[:, 0] - cx, sp.points[:, 1] - cy)
    assert np.sqrt(np.mean((r - CYL[2]) ** 2)) < 0.06
    assert sp.points[:, 2].min() > 0.4


@settings(max_examples=10, deadline=None)
@given(tilt=st.tuples(*[st.floats(-5.0, 5.0)] * 3), cx=st.floats(-40.0, 40.0), cy=st.floats(-40.0, 40.0),
       radius=st.floats(10.0, 30.0), max_inc=st.sampled_from([60.0, 85.0, 89.99, 90.0]))
def test_spheres_anywhere_up_to_grazing(tilt, cx, cy, radius, max_inc):
    station = tilted_pose(tilt_deg=tilt)
    c = np.array([cx, cy, radius + 5.0])
    a = np.arange(120) * 3.0
    s = scan(station, a, spheres=[(c, radius)], n_points=200, max_incidence_deg=max_inc)
    if not (s.label >= 0).any():
        with pytest.raises(ValueError, match="no valid point"):
            profiles_to_points(s.x, s.z, a, station)
        return
    sp = profiles_to_points(s.x, s.z, a, station)
    assert np.all(np.isfinite(sp.points)) and np.all(np.isfinite(sp.normals))
    assert np.all(np.isfinite(sp.confidence)) and sp.confidence.min() >= 0 and sp.confidence.max() <= 1
    np.testing.assert_allclose(np.linalg.norm(sp.points - c, axis=1), radius, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(sp.normals, axis=1), 1.0, atol=1e-9)
    to_sensor = sp.sensor_origins[sp.step] - sp.points
    assert np.all(np.sum(sp.normals * to_sensor, axis=1) >= 0)
    # where estimated, the normal is radial (the neighbourhood spans a few mm of a sphere of >= 10 mm radius)
    radial = (sp.points - c) / radius
    dots = np.sum(sp.normals * radial, axis=1)[sp.normal_estimated]
    if dots.size > 20:
        assert np.median(dots) > 0.99


def test_single_profile_has_no_surface_normals():
    m = ideal_sensor_to_room(200.0, 30.0)
    th = np.radians(np.linspace(-10.0, 10.0, 50))
    x, z = (150.0 / np.cos(th) * np.sin(th))[None], np.full((1, 50), 150.0)
    sp = profiles_to_points(x, z, [0.0], m)
    assert sp.n_kept == 50 and not sp.normal_estimated.any()
    assert np.all(sp.confidence == 0.0)
    to_sensor = sp.sensor_origins[0] - sp.points
    np.testing.assert_allclose(sp.normals, to_sensor / np.linalg.norm(to_sensor, axis=1)[:, None], atol=1e-12)


def test_depth_jump_keeps_surfaces_apart(station):
    # a thin post in front of the cylinder: the cylinder's normals next to the post's shadow stay radial
    s = scan(station, ANGLES, cylinders=[CYL, (55.0, 0.0, 3.0, 60.0)], noise=0.0, max_incidence_deg=85.0)
    sp = profiles_to_points(s.x, s.z, ANGLES, station)
    lab = s.label[sp.step, sp.column]
    big = (lab == 0) & on_side(sp.points)
    cx, cy, _, _ = CYL
    radial = np.stack([sp.points[:, 0] - cx, sp.points[:, 1] - cy, np.zeros(sp.n_kept)], 1)
    radial /= np.linalg.norm(radial, axis=1)[:, None]
    assert (lab == 2).sum() > 100
    assert np.sum(sp.normals * radial, axis=1)[big].min() > 0.999    # mixing the two would tilt them by ~100 deg


def test_as_open3d(noisy):
    pc = noisy[1].as_open3d()
    assert len(pc.points) == noisy[1].n_kept and pc.has_normals()


# ---------------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def small(station):
    a = ANGLES[:10]
    s = scan(station, a, cylinders=[CYL], n_points=50)
    return s.x, s.z, a


def test_bad_shapes_and_values(small, station):
    x, z, a = small
    with pytest.raises(ValueError, match="x_mm must be a"):
        profiles_to_points(x[0], z[0], a[:1], station)
    with pytest.raises(ValueError, match="z_mm must have the shape"):
        profiles_to_points(x, z[:-1], a, station)
    with pytest.raises(ValueError, match="one angle per profile"):
        profiles_to_points(x, z, a[:-1], station)
    bad = a.copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match=r"NaN or infinite values at step\(s\) \[2\]"):
        profiles_to_points(x, z, bad, station)
    xi = x.copy()
    xi[1, 1] = -np.inf
    with pytest.raises(ValueError, match="x_mm contains infinite"):
        profiles_to_points(xi, z, a, station)


@pytest.mark.parametrize("kwargs, match", [
    ({"table_tolerance_mm": -1.0}, "table_tolerance_mm"),
    ({"max_radius_mm": 0.0}, "max_radius_mm"),
    ({"range_mm": (300.0, 100.0)}, "range_mm"),
    ({"normal_window": (0, 0)}, "normal_window"),
    ({"normal_span_mm": 0.0}, "normal_span_mm"),
    ({"max_jump_mm": -2.0}, "max_jump_mm"),
    ({"normal_window": (1.5, 3)}, "normal_window"),
])
def test_bad_options(small, station, kwargs, match):
    x, z, a = small
    with pytest.raises(ValueError, match=match):
        profiles_to_points(x, z, a, station, **kwargs)


def test_bad_calibration(small):
    x, z, a = small
    with pytest.raises(ValueError, match="calibration"):
        profiles_to_points(x, z, a, np.eye(3))
    with pytest.raises(ValueError, match="calibration.*rotation"):
        profiles_to_points(x, z, a, np.diag([1.0, 1.0, -1.0, 1.0]))


def test_no_valid_points(station):
    nan = np.full((5, 20), np.nan)
    with pytest.raises(ValueError, match="no valid point"):
        profiles_to_points(nan, nan, np.zeros(5), station)


def test_everything_cropped(station):
    s = scan(station, ANGLES[:20], table_radius=150.0)
    with pytest.raises(ValueError, match="all .* valid points were cropped"):
        profiles_to_points(s.x, s.z, ANGLES[:20], station)


def test_explicit_window_and_radius(station):
    s = scan(station, ANGLES, cylinders=[CYL], noise=0.05, seed=7)
    sp = profiles_to_points(s.x, s.z, ANGLES, station, normal_window=(2, 8), max_jump_mm=3.0)
    assert isinstance(sp, ScanPoints) and sp.normal_estimated.all()
    cx, cy, _, _ = CYL
    radial = np.stack([sp.points[:, 0] - cx, sp.points[:, 1] - cy, np.zeros(sp.n_kept)], 1)
    radial /= np.linalg.norm(radial, axis=1)[:, None]
    assert np.percentile(np.sum(sp.normals * radial, axis=1)[on_side(sp.points)], 1) > 0.99
