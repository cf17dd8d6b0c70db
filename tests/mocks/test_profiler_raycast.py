"""Ray-cast profile source: geometry against closed-form ray-sphere intersections,
incidence dropouts, camera occlusion, range limit, and the table angle from the
Horus emulator driven by the real turntable driver."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest

from drivers.profiler import LaserProfiler
from drivers.transport import SerialTransport
from drivers.turntable import Turntable
from mocks.horus_firmware import HorusFirmware
from mocks.profiler_firmware import ProfilerFirmware, RaycastSource

D = 200.0  # standoff, mm
FOV = 30.0
N = 61


def sphere(radius, center=(0.0, 0.0, 0.0), resolution=80):
    m = o3d.geometry.TriangleMesh.create_sphere(radius, resolution=resolution)
    return np.asarray(m.vertices) + np.asarray(center), np.asarray(m.triangles)


def box(lo, hi):
    m = o3d.geometry.TriangleMesh.create_box(*(np.subtract(hi, lo)))
    return np.asarray(m.vertices) + np.asarray(lo), np.asarray(m.triangles)


def closed_form(radius, cx):
    """Ray-sphere hits for rays from (D, 0, 0) at elevation theta toward -X; sphere at (cx, 0, 0)."""
    th = np.radians(np.linspace(-FOV / 2, FOV / 2, N))
    d = np.stack([-np.cos(th), np.zeros_like(th), np.sin(th)], 1)
    oc = np.array([D - cx, 0.0, 0.0])
    b = d @ oc
    disc = b * b - (oc @ oc - radius**2)
    t = -b - np.sqrt(np.where(disc >= 0, disc, np.nan))
    p = np.array([D, 0.0, 0.0]) + d * t[:, None]
    n = (p - [cx, 0.0, 0.0]) / radius
    cos_i = np.sum(n * -d, axis=1)
    return t * np.cos(th), t * np.sin(th), cos_i


def test_sphere_ranges_match_closed_form():
    v, f = sphere(30.0)
    x, z, ok = RaycastSource(v, f, lambda: 0.0, n_points=N, fov_deg=FOV, standoff_mm=D,
                             max_incidence_deg=89.0)()
    z_ref, x_ref, cos_i = closed_form(30.0, 0.0)
    hit = np.isfinite(z_ref)
    inner = hit & (cos_i > 0.3)  # away from the limb, where tessellation error grows
    assert inner.sum() > 10
    assert ok[inner].all()
    # chord error of the tessellated sphere: R (1 - cos(pi / resolution)) ~ 0.023 mm
    np.testing.assert_allclose(z[inner] / 1000, z_ref[inner], atol=0.05)
    np.testing.assert_allclose(x[inner] / 1000, x_ref[inner], atol=0.05)
    assert not ok[~hit].any() and np.isnan(z[~hit]).all()


def test_incidence_dropouts_follow_the_normal():
    v, f = sphere(30.0)
    limit = 40.0
    _, _, ok = RaycastSource(v, f, lambda: 0.0, n_points=N, fov_deg=FOV, standoff_mm=D,
                             max_incidence_deg=limit)()
    _, _, cos_i = closed_form(30.0, 0.0)
    c = math.cos(math.radians(limit))
    clear_in = np.nan_to_num(cos_i) > c + 0.03
    clear_out = np.nan_to_num(cos_i, nan=-1) < c - 0.03
    assert clear_in.any() and clear_out.any()
    assert ok[clear_in].all() and not ok[clear_out].any()


def test_table_angle_turns_the_object():
    v, f = sphere(20.0, center=(50.0, 0.0, 0.0))
    angle = [0.0]
    src = RaycastSource(v, f, lambda: angle[0], n_points=N, fov_deg=FOV, standoff_mm=D)
    mid = N // 2
    assert src()[1][mid] / 1000 == pytest.approx(D - 50 - 20, abs=0.05)
    angle[0] = 180.0
    assert src()[1][mid] / 1000 == pytest.approx(D + 50 - 20, abs=0.05)
    angle[0] = 90.0  # moved out of the laser plane: no return at the centre
    assert not src()[2][mid]


def test_camera_occlusion_and_range_limit():
    wall = box((-60.0, -100.0, -100.0), (-50.0, 100.0, 100.0))  # face at x = -50, range 250
    kw = dict(n_points=N, fov_deg=10.0, standoff_mm=D, baseline_mm=60.0, range_mm=(100.0, 300.0))
    assert RaycastSource(*wall, lambda: 0.0, **kw)()[2].all()
    # a blocker beside the laser plane (y 10..50) cuts every camera ray (camera at y = 60)
    bv, bf = box((20.0, 10.0, -100.0), (120.0, 50.0, 100.0))
    v = np.vstack([wall[0], bv])
    f = np.vstack([wall[1], bf + len(wall[0])])
    assert not RaycastSource(v, f, lambda: 0.0, **kw)()[2].any()
    # the same wall beyond the far range limit
    kw["range_mm"] = (100.0, 240.0)
    assert not RaycastSource(*wall, lambda: 0.0, **kw)()[2].any()


def test_range_noise_has_the_requested_spread():
    wall = box((-60.0, -100.0, -100.0), (-50.0, 100.0, 100.0))
    x, z, ok = RaycastSource(*wall, lambda: 0.0, n_points=2000, fov_deg=2.0, standoff_mm=D,
                             noise_um=50.0, seed=1)()
    th = np.radians(np.linspace(-1.0, 1.0, 2000))
    resid = z - 250_000.0  # the face is at range 250 mm for every ray (range along the axis)
    assert ok.all() and abs(resid.mean()) < 5.0 and resid.std() == pytest.approx(50.0, rel=0.1)
    assert np.allclose(x, 250_000.0 * np.tan(th), atol=1.0)


@pytest.mark.parametrize("kw,msg", [({"n_points": 0}, "n_points"), ({"fov_deg": 180.0}, "fov_deg"),
                                    ({"range_mm": (300.0, 100.0)}, "range_mm"),
                                    ({"max_incidence_deg": 0.0}, "max_incidence_deg")])
def test_bad_parameters(kw, msg):
    v, f = sphere(10.0, resolution=8)
    with pytest.raises(ValueError, match=msg):
        RaycastSource(v, f, lambda: 0.0, **kw)


def test_bad_mesh():
    with pytest.raises(ValueError, match="triangles"):
        RaycastSource(np.zeros((3, 3)), np.array([[0, 1, 5]]), lambda: 0.0)


def test_end_to_end_with_turntable_and_profiler_over_ptys(tmp_path):
    v, f = sphere(20.0, center=(50.0, 0.0, 0.0), resolution=40)
    with HorusFirmware(tmp_path / "turntable") as hfw:
        src = RaycastSource(v, f, lambda: hfw.angle_deg, n_points=N, fov_deg=FOV, standoff_mm=D)
        with ProfilerFirmware(tmp_path / "profiler", source=src) as pfw:
            tt = Turntable(SerialTransport(hfw.path), margin_s=0.5)
            lp = LaserProfiler(SerialTransport(pfw.path), max_points=256, margin_s=0.5)
            tt.connect()
            lp.connect()
            lp.laser(True)
            tt.motor(True)
            near = lp.profile(2.0).z_mm[N // 2]
            tt.move_to(180.0)
            far = lp.profile(2.0).z_mm[N // 2]
            lp.close()
            tt.close()
    assert near == pytest.approx(D - 70, abs=0.1) and far == pytest.approx(D + 30, abs=0.1)
