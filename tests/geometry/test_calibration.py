"""Scanner calibration from a reference sphere: pose recovery against closed-form scans of a
deliberately non-ideal station, the Open3D profiler emulator, the JSON round trip and every bad input."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from processing.geometry.calibration import (
    CalibrationError,
    ScannerCalibration,
    calibrate_sphere,
    check_sensor_to_room,
    ideal_sensor_to_room,
    profile_points_room,
)

# ---------------------------------------------------------------------------- closed-form scanner
from tests.geometry.closed_form_scanner import Scan, gauge_fixed, rotation_error_deg, rz, scan, tilted_pose  # noqa: F401

R_BALL = 12.7                     # a 1-inch reference ball, mm
ANGLES = np.arange(180) * 2.0     # one revolution, 2 deg steps


def ball_centre(rho=60.0, phi_deg=40.0, height=R_BALL):
    p = np.radians(phi_deg)
    return np.array([rho * np.cos(p), rho * np.sin(p), height])


@pytest.fixture(scope="module")
def noisy_cal():
    truth = tilted_pose()
    s = scan(truth, ANGLES, spheres=[(ball_centre(), R_BALL)], table_radius=150.0, noise=0.05, seed=1)
    return truth, s, calibrate_sphere(s.x, s.z, ANGLES, R_BALL)


# ---------------------------------------------------------------------------- frames
def test_ideal_pose_and_room_points():
    m = ideal_sensor_to_room(200.0, 30.0)
    # X_s = +Z, Y_s = +Y, Z_s = -X, origin (200, 0, 30)
    np.testing.assert_array_equal(m[:3, 0], [0, 0, 1])
    np.testing.assert_array_equal(m[:3, 1], [0, 1, 0])
    np.testing.assert_array_equal(m[:3, 2], [-1, 0, 0])
    # range 150 straight ahead and 10 up: 50 mm in front of the axis, 40 mm high
    np.testing.assert_allclose(profile_points_room([10.0], [150.0], m), [[50.0, 0.0, 40.0]])
    with pytest.raises(ValueError, match="same shape"):
        profile_points_room([1.0, 2.0], [1.0], m)
    with pytest.raises(ValueError, match="standoff_mm"):
        ideal_sensor_to_room(-1.0)


@pytest.mark.parametrize("bad, match", [
    (np.eye(3), r"\(4, 4\)"),
    (np.full((4, 4), np.nan), "NaN"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), "rotation"),
    (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "last row"),
])
def test_check_sensor_to_room_rejects(bad, match):
    with pytest.raises(ValueError, match=match):
        check_sensor_to_room(bad)


# ---------------------------------------------------------------------------- pose recovery
def test_noise_free_recovery_is_exact():
    truth = tilted_pose()
    s = scan(truth, ANGLES, spheres=[(ball_centre(), R_BALL)], table_radius=150.0)
    cal = calibrate_sphere(s.x, s.z, ANGLES, R_BALL)
    want = gauge_fixed(truth)
    assert rotation_error_deg(cal.sensor_to_room, want) < 1e-4
    np.testing.assert_allclose(cal.sensor_to_room[:3, 3], want[:3, 3], atol=1e-4)
    # the sphere centre in the table frame, in the same gauge
    np.testing.assert_allclose(cal.sphere_center_mm, gauge_fixed_point(truth, ball_centre()), atol=1e-4)
    assert cal.rms_mm < 1e-5 and cal.table_rms_mm < 1e-5
    assert abs(cal.fitted_radius_mm - R_BALL) < 1e-5


def gauge_fixed_point(truth, p):
    return rz(np.array(-np.arctan2(truth[1, 3], truth[0, 3]))) @ p


def test_noisy_recovery_within_tolerance(noisy_cal):
    truth, _, cal = noisy_cal
    want = gauge_fixed(truth)
    # targets: sub-0.05 deg and sub-0.05 mm
    assert rotation_error_deg(cal.sensor_to_room, want) < 0.05
    assert np.linalg.norm(cal.sensor_to_room[:3, 3] - want[:3, 3]) < 0.05
    assert np.linalg.norm(cal.sphere_center_mm - gauge_fixed_point(truth, ball_centre())) < 0.05
    # the residual reflects the 0.05 mm range noise (projected on the sphere normal: <= 0.05)
    assert 0.02 < cal.rms_mm < 0.06
    assert cal.max_mm < 0.35
    assert cal.table_rms_mm < 0.06 and cal.n_table_points > 1000
    assert abs(cal.fitted_radius_mm - R_BALL) < 0.01


def test_gauge_and_bookkeeping(noisy_cal):
    _, s, cal = noisy_cal
    o = cal.sensor_to_room[:3, 3]
    assert abs(o[1]) < 1e-9 and o[0] > 0
    np.testing.assert_allclose(cal.sensor_to_room[:3, :3].T @ cal.sensor_to_room[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_array_equal(cal.sensor_to_room[3], [0, 0, 0, 1])
    # profiles used: exactly those with sphere hits and enough points
    seen = np.flatnonzero((s.label == 0).sum(1) >= 10)
    assert set(cal.step_indices.tolist()) <= set(np.flatnonzero((s.label == 0).any(1)).tolist())
    assert cal.n_profiles == cal.step_indices.size >= seen.size - 2
    assert cal.n_sphere_points <= (s.label == 0).sum()
    assert cal.n_sphere_points > 0.9 * (s.label == 0).sum()
    assert cal.step_rms_mm.shape == cal.step_indices.shape and np.all(cal.step_rms_mm < 0.1)


def test_without_table_uses_the_sphere_height():
    truth = tilted_pose(height=35.0, tilt_deg=(-1.5, 2.5, -2.0), offset=(-2.0, 3.0, -1.0))
    c = ball_centre(rho=70.0, phi_deg=-100.0, height=25.0)   # on a 25 mm post
    s = scan(truth, ANGLES, spheres=[(c, R_BALL)], noise=0.05, seed=2)
    with pytest.raises(CalibrationError, match="sphere_height_mm"):
        calibrate_sphere(s.x, s.z, ANGLES, R_BALL)
    cal = calibrate_sphere(s.x, s.z, ANGLES, R_BALL, sphere_height_mm=25.0)
    want = gauge_fixed(truth)
    assert cal.n_table_points == 0
    assert rotation_error_deg(cal.sensor_to_room, want) < 0.05
    assert np.linalg.norm(cal.sensor_to_room[:3, 3] - want[:3, 3]) < 0.05


def test_laser_line_pointing_down_is_resolved_by_the_table():
    # the profiler mounted upside down (X_s = -Z): only the table tells up from down
    flip = np.diag([-1.0, -1.0, 1.0])    # rotation by 180 deg about Z_s
    truth = tilted_pose()
    truth[:3, :3] = truth[:3, :3] @ flip
    s = scan(truth, ANGLES, spheres=[(ball_centre(), R_BALL)], table_radius=150.0)
    cal = calibrate_sphere(s.x, s.z, ANGLES, R_BALL)
    assert rotation_error_deg(cal.sensor_to_room, gauge_fixed(truth)) < 1e-3
    assert cal.sensor_to_room[2, 0] < 0


@settings(max_examples=6, deadline=None)
@given(tilt=st.tuples(*[st.floats(-5.0, 5.0)] * 3), offset=st.tuples(*[st.floats(-5.0, 5.0)] * 3),
       rho=st.floats(35.0, 70.0), phi=st.floats(-180.0, 180.0), radius=st.floats(10.0, 15.0))
def test_random_stations_noise_free(tilt, offset, rho, phi, radius):
    truth = tilted_pose(tilt_deg=tilt, offset=offset)
    # a fan pitched up 5 deg sees the table at up to 80 deg incidence: accept up to 85
    s = scan(truth, ANGLES, spheres=[(ball_centre(rho, phi, radius), radius)], table_radius=150.0,
             max_incidence_deg=85.0)
    cal = calibrate_sphere(s.x, s.z, ANGLES, radius)
    want = gauge_fixed(truth)
    assert rotation_error_deg(cal.sensor_to_room, want) < 1e-3
    np.testing.assert_allclose(cal.sensor_to_room[:3, 3], want[:3, 3], atol=1e-3)


def test_profiler_emulator_sphere_on_table():
    """A UV-sphere mesh on a table disk, ray cast by the project's profiler emulator."""
    o3d = pytest.importorskip("open3d")
    from mocks.profiler_firmware import RaycastSource

    radius = 15.0
    ball = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=120)
    ball.translate(ball_centre(55.0, 30.0, radius))
    table = o3d.geometry.TriangleMesh.create_cylinder(150.0, 4.0, resolution=90, split=1)
    table.translate((0.0, 0.0, -2.0))                      # top face at z = 0
    mesh = ball + table
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    if "sensor_to_room" in inspect.signature(RaycastSource).parameters:
        truth = tilted_pose(height=45.0, tilt_deg=(1.0, -2.0, -5.0), offset=(-3.0, 2.0, 0.0))
        src = RaycastSource(v, f, lambda: 0.0, n_points=400, sensor_to_room=truth, max_incidence_deg=80.0,
                            noise_um=50.0, seed=3)
    else:  # the emulator's ideal geometry
        truth = ideal_sensor_to_room(200.0, 45.0)
        src = RaycastSource(v, f, lambda: 0.0, n_points=400, standoff_mm=200.0, height_mm=45.0,
                            max_incidence_deg=80.0, noise_um=50.0, seed=3)
    prof = [src.profile_at(float(a)) for a in ANGLES]
    x = np.stack([p[0] for p in prof]) / 1000.0
    z = np.stack([p[1] for p in prof]) / 1000.0
    cal = calibrate_sphere(x, z, ANGLES, radius)
    want = gauge_fixed(truth)
    assert rotation_error_deg(cal.sensor_to_room, want) < 0.05
    assert np.linalg.norm(cal.sensor_to_room[:3, 3] - want[:3, 3]) < 0.05
    assert np.linalg.norm(cal.sphere_center_mm - gauge_fixed_point(truth, ball_centre(55.0, 30.0, radius))) < 0.05
    assert cal.rms_mm < 0.06 and cal.n_table_points > 1000


# ---------------------------------------------------------------------------- JSON
def test_json_round_trip(noisy_cal):
    cal = noisy_cal[2]
    back = ScannerCalibration.from_dict(json.loads(json.dumps(cal.to_dict())))
    np.testing.assert_array_equal(back.sensor_to_room, cal.sensor_to_room)
    np.testing.assert_array_equal(back.sphere_center_mm, cal.sphere_center_mm)
    np.testing.assert_array_equal(back.step_indices, cal.step_indices)
    np.testing.assert_array_equal(back.step_rms_mm, cal.step_rms_mm)
    for name in ("sphere_radius_mm", "rms_mm", "max_mm", "n_profiles", "n_sphere_points", "n_table_points",
                 "table_rms_mm", "fitted_radius_mm"):
        assert getattr(back, name) == getattr(cal, name)
    np.testing.assert_array_equal(back.sensor_origin_mm, cal.sensor_to_room[:3, 3])


@pytest.mark.parametrize("change, match", [
    ({"schema": "kogei.session"}, "schema"),
    ({"version": 99}, "version 99"),
    ({"version": "1"}, "version"),
    ({"sensor_to_room": np.diag([1.0, 1, -1, 1]).tolist()}, "rotation"),
    ({"sphere_center_mm": [1.0, 2.0]}, "sphere_center_mm"),
    ({"step_rms_mm": [0.1]}, "same length"),
])
def test_from_dict_rejects(noisy_cal, change, match):
    d = noisy_cal[2].to_dict()
    d.update(change)
    with pytest.raises(ValueError, match=match):
        ScannerCalibration.from_dict(d)


def test_from_dict_names_missing_fields(noisy_cal):
    d = noisy_cal[2].to_dict()
    del d["sphere_radius_mm"], d["rms_mm"]
    with pytest.raises(ValueError, match="sphere_radius_mm, rms_mm"):
        ScannerCalibration.from_dict(d)
    with pytest.raises(ValueError, match="JSON object"):
        ScannerCalibration.from_dict([1, 2])


# ---------------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def clean():
    s = scan(tilted_pose(), ANGLES, spheres=[(ball_centre(), R_BALL)], table_radius=150.0)
    return s.x, s.z


def test_bad_shapes_and_values(clean):
    x, z = clean
    with pytest.raises(ValueError, match="x_mm must be a"):
        calibrate_sphere(x[0], z[0], ANGLES[:1], R_BALL)
    with pytest.raises(ValueError, match="z_mm must have the shape"):
        calibrate_sphere(x, z[:, :-1], ANGLES, R_BALL)
    with pytest.raises(ValueError, match="one angle per profile"):
        calibrate_sphere(x, z, ANGLES[:-1], R_BALL)
    a = ANGLES.copy()
    a[[3, 7]] = np.nan
    with pytest.raises(ValueError, match=r"step\(s\) \[3, 7\]"):
        calibrate_sphere(x, z, a, R_BALL)
    zi = z.copy()
    zi[0, 0] = np.inf
    with pytest.raises(ValueError, match="z_mm contains infinite"):
        calibrate_sphere(x, zi, ANGLES, R_BALL)
    for r in (0.0, -3.0, np.nan, 1e4):
        with pytest.raises(ValueError, match="sphere_radius_mm"):
            calibrate_sphere(x, z, ANGLES, r)
    with pytest.raises(ValueError, match="min_profiles"):
        calibrate_sphere(x, z, ANGLES, R_BALL, min_profiles=2)


def test_no_valid_points():
    nan = np.full((20, 50), np.nan)
    with pytest.raises(CalibrationError, match="no valid points"):
        calibrate_sphere(nan, nan, np.arange(20) * 18.0, R_BALL)


def test_sphere_not_found():
    s = scan(tilted_pose(), ANGLES, table_radius=150.0)              # the table alone
    with pytest.raises(CalibrationError, match="found in only 0 profile"):
        calibrate_sphere(s.x, s.z, ANGLES, R_BALL)


def test_sphere_seen_in_too_few_profiles():
    a = np.arange(180) * 2.0
    s = scan(tilted_pose(), a, spheres=[(ball_centre(), R_BALL)], table_radius=150.0)
    keep = np.zeros(a.size, bool)
    keep[np.flatnonzero((s.label == 0).any(1))[:5]] = True          # five profiles of the sphere
    keep |= ~(s.label == 0).any(1)
    with pytest.raises(CalibrationError, match="found in only [0-5] profile"):
        calibrate_sphere(s.x[keep], s.z[keep], a[keep], R_BALL)


def test_radius_too_small_is_implausible(clean):
    x, z = clean
    with pytest.raises(CalibrationError, match="implausible.*radius up to 12"):
        calibrate_sphere(x, z, ANGLES, R_BALL / 2)


def test_diameter_instead_of_radius_is_implausible(clean):
    x, z = clean
    with pytest.raises(CalibrationError, match="implausible: the scan fits a sphere of radius 12.7"):
        calibrate_sphere(x, z, ANGLES, 2 * R_BALL)


def test_sphere_on_the_axis():
    s = scan(tilted_pose(), ANGLES, spheres=[(np.array([2.0, 1.0, R_BALL]), R_BALL)], table_radius=150.0)
    with pytest.raises(CalibrationError, match="off-axis"):
        calibrate_sphere(s.x, s.z, ANGLES, R_BALL)


def test_table_required_but_absent():
    s = scan(tilted_pose(), ANGLES, spheres=[(ball_centre(), R_BALL)])
    with pytest.raises(CalibrationError, match="use_table=True"):
        calibrate_sphere(s.x, s.z, ANGLES, R_BALL, use_table=True)


def test_not_a_sphere_fails_the_residual_check(clean):
    # a cylinder's sections are lines or ellipses, never the circles of a sphere
    s = scan(tilted_pose(), ANGLES, cylinders=[(40.0, 30.0, 12.0, 40.0)], table_radius=150.0)
    with pytest.raises(CalibrationError):
        calibrate_sphere(s.x, s.z, ANGLES, R_BALL)


def test_residual_above_the_limit_is_refused(noisy_cal):
    _, s, _ = noisy_cal
    with pytest.raises(CalibrationError, match=r"RMS distance of 0\.03\d+ mm to the sphere"):
        calibrate_sphere(s.x, s.z, ANGLES, R_BALL, max_rms_mm=0.01)
    for bad in ({"max_rms_mm": 0.0}, {"gap_mm": -1.0}, {"table_tolerance_mm": np.inf},
                {"radius_tolerance_mm": -0.1}, {"sphere_height_mm": np.nan}, {"min_points_per_profile": 2}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            calibrate_sphere(s.x, s.z, ANGLES, R_BALL, **bad)
