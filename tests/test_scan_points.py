"""Profiles -> table-frame point clouds: closed-form scans of a cylinder, a sphere and the table
through a deliberately non-ideal station; positions, normals, cropping, confidence, bad input."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from processing.calibration import ScannerCalibration, calibrate_sphere, ideal_sensor_to_room
from processing.scan_points import ScanPoints, profiles_to_points


# ---------------------------------------------------------------------------- closed-form scanner
def rz(a_rad):
    """Rotations about +Z, shape a.shape + (3, 3)."""
    c, s = np.cos(a_rad), np.sin(a_rad)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def tilted_pose(standoff=200.0, height=40.0, tilt_deg=(2.0, -3.0, 1.5), offset=(3.0, -4.0, 2.5)):
    """A deliberately non-ideal station: the ideal pose tilted a few degrees and offset a few mm."""
    m = np.eye(4)
    ideal = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    m[:3, :3] = Rotation.from_euler("xyz", tilt_deg, degrees=True).as_matrix() @ ideal
    m[:3, 3] = np.array([standoff, 0.0, height]) + np.asarray(offset)
    return m


def gauge_fixed(m):
    """``m`` rotated about the table axis so that the sensor origin lies in the XZ plane, x > 0."""
    g = np.eye(4)
    g[:3, :3] = rz(np.array(-np.arctan2(m[1, 3], m[0, 3])))
    return g @ m


@dataclass
class Scan:
    x: np.ndarray        # (S, P) sensor x, NaN invalid
    z: np.ndarray        # (S, P) sensor z (range), NaN invalid
    label: np.ndarray    # (S, P) index of the surface hit (spheres, cylinder sides, cylinder caps, table), -1 none
    point: np.ndarray    # (S, P, 3) exact hit point in the table frame
    normal: np.ndarray   # (S, P, 3) exact outward surface normal in the table frame


def scan(sensor_to_room, angles_deg, *, n_points=400, fov_deg=30.0, spheres=(), cylinders=(), table_radius=None,
         noise=0.0, max_incidence_deg=80.0, range_mm=(100.0, 300.0), seed=0):
    """Laser fan against analytic surfaces fixed in the table frame, in closed form.

    Rays leave the sensor origin along ``sin(t) X_s + cos(t) Z_s``; the surfaces are spheres ``(centre, R)``,
    vertical cylinders ``(cx, cy, radius, height)`` standing on the table (side and top cap) and the
    table disk ``z = 0`` of radius ``table_radius``.  The nearest hit is kept if its incidence is within
    ``max_incidence_deg`` and its range within ``range_mm``; Gaussian noise ``noise`` (mm) is added to the range.
    """
    rot, o = sensor_to_room[:3, :3], sensor_to_room[:3, 3]
    th = np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, n_points))
    d_room = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], 1) @ rot.T
    to_table = np.swapaxes(rz(np.radians(np.asarray(angles_deg, float))), -1, -2)
    org = np.einsum("sij,j->si", to_table, o)[:, None, :]                         # (S, 1, 3)
    dr = np.einsum("sij,pj->spi", to_table, d_room)                               # (S, P, 3)
    best_t = np.full(dr.shape[:2], np.inf)
    best_n = np.zeros(dr.shape)
    label = np.full(dr.shape[:2], -1)

    def take(t, n, k):
        nonlocal best_t, best_n, label
        better = (t > 1e-9) & (t < best_t)
        best_t = np.where(better, t, best_t)
        best_n = np.where(better[..., None], n, best_n)
        label = np.where(better, k, label)

    def at(t):
        return org + dr * np.where(np.isfinite(t), t, 0.0)[..., None]

    k = 0
    for centre, rad in spheres:
        oc = org - np.asarray(centre)
        b = (dr * oc).sum(-1)
        disc = b * b - (oc * oc).sum(-1) + rad * rad
        t = np.where(disc > 0, -b - np.sqrt(np.abs(disc)), np.inf)
        take(t, (at(t) - np.asarray(centre)) / rad, k)
        k += 1
    for cx, cy, rc, hc in cylinders:
        ox, oy = org[..., 0] - cx, org[..., 1] - cy
        qa = dr[..., 0] ** 2 + dr[..., 1] ** 2
        qb = ox * dr[..., 0] + oy * dr[..., 1]
        disc = qb * qb - qa * (ox * ox + oy * oy - rc * rc)
        t = np.where(disc > 0, (-qb - np.sqrt(np.abs(disc))) / np.where(qa > 0, qa, 1.0), np.inf)
        p = at(t)
        t = np.where((p[..., 2] >= 0) & (p[..., 2] <= hc), t, np.inf)
        take(t, np.stack([(p[..., 0] - cx) / rc, (p[..., 1] - cy) / rc, np.zeros_like(t)], -1), k)
        dz = dr[..., 2]
        t = np.where(dz < -1e-12, (hc - org[..., 2]) / np.where(dz < -1e-12, dz, -1.0), np.inf)
        p = at(t)
        t = np.where((p[..., 0] - cx) ** 2 + (p[..., 1] - cy) ** 2 <= rc * rc, t, np.inf)
        take(t, np.broadcast_to([0.0, 0.0, 1.0], p.shape), k + 1)
        k += 2
    if table_radius is not None:
        dz = dr[..., 2]
        t = np.where(dz < -1e-12, -org[..., 2] / np.where(dz < -1e-12, dz, -1.0), np.inf)
        p = at(t)
        t = np.where(p[..., 0] ** 2 + p[..., 1] ** 2 <= table_radius**2, t, np.inf)
        take(t, np.broadcast_to([0.0, 0.0, 1.0], p.shape), k)
    hit = np.isfinite(best_t)
    cos_i = np.abs((best_n * -dr).sum(-1))
    t = np.where(hit, best_t, 0.0)
    x, z = t * np.sin(th), t * np.cos(th)
    ok = hit & (cos_i >= np.cos(np.radians(max_incidence_deg))) & (z >= range_mm[0]) & (z <= range_mm[1])
    if noise:
        z = z + np.random.default_rng(seed).normal(0.0, noise, z.shape)
    return Scan(np.where(ok, x, np.nan), np.where(ok, z, np.nan), np.where(ok, label, -1), at(t), best_n)



def rotation_error_deg(a, b):
    return float(np.degrees(Rotation.from_matrix(a[:3, :3] @ b[:3, :3].T).magnitude()))


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
