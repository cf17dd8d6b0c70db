"""Observations against synthetic truth: an analytic image, a sphere's analytic geometry, hostile files."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import open3d as o3d
import pytest

from processing.appearance.frame_poses import AppearanceError, FramePose
from processing.appearance.observations import (
    observe,
    per_vertex_counts,
    read_observations,
    write_observations,
)
from tests.appearance.synthetic_scene import (
    HEIGHT,
    SPHERE_CENTRE,
    SPHERE_RADIUS,
    WIDTH,
    intrinsics,
    look_at,
    rigid,
)

ROOM_TO_CAMERA = look_at([480.0, -60.0, 200.0], [0.0, 0.0, 60.0])
PASS_POSE = rigid(4.0, -3.0, 25.0, [2.0, -1.0, 0.5])
DIST = np.array([-0.1, 0.02, 0.0005, -0.0003, 0.0])
LAMPS = [{"name": "key", "position_mm": [200.0, 300.0, 500.0]}, {"name": "sun", "direction": [0.0, -0.6, 0.8]}]
THETAS = (0.0, 90.0, 180.0, 270.0)
NOISE = np.array([[1e-4, 2e-3], [2e-4, 1e-3], [5e-5, 4e-3], [1e-4, 1e-3]])


def analytic_image(width=WIDTH, height=HEIGHT) -> np.ndarray:
    """Channels 0.1 + 0.002 u, 0.2 + 0.003 v, 1e-5 u v: bilinear interpolation reproduces them exactly."""
    uu, vv = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([0.1 + 0.002 * uu, 0.2 + 0.003 * vv, 1e-5 * uu * vv], -1).astype(np.float32)


@pytest.fixture(scope="module")
def setup():
    # the sphere in M; the table pose/angle only change where the camera is seen from
    sphere = o3d.geometry.TriangleMesh.create_sphere(SPHERE_RADIUS, resolution=24).translate(SPHERE_CENTRE)
    v = np.asarray(sphere.vertices)
    sphere.vertex_normals = o3d.utility.Vector3dVector((v - SPHERE_CENTRE) / SPHERE_RADIUS)
    frames = [FramePose.from_chain(f"IMG_{i}", 2, ROOM_TO_CAMERA, t, PASS_POSE, intrinsics(), DIST,
                                   (WIDTH, HEIGHT), LAMPS) for i, t in enumerate(THETAS)]
    images = [analytic_image() for _ in frames]
    images[1][50:53, 100:103] = 5.0  # a clipped spot in frame 1
    obs = observe(frames, sphere, images, noise=NOISE, clip_level=np.array([4.0, 4.0, 4.0, 4.0]))
    return sphere, frames, images, obs


def _physical_camera_centre(theta: float) -> np.ndarray:
    # camera fixed in the room; M point X sits at Rz(theta) inv(T_p) X in the room
    c = np.cos(np.radians(theta))
    s = np.sin(np.radians(theta))
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    centre_room = -ROOM_TO_CAMERA[:3, :3].T @ ROOM_TO_CAMERA[:3, 3]
    return PASS_POSE[:3, :3] @ (rz.T @ centre_room) + PASS_POSE[:3, 3], rz


def test_signal_equals_the_analytic_image_at_opencvs_projection(setup):
    sphere, frames, _, obs = setup
    v = np.asarray(sphere.vertices)
    assert len(obs) > 400 and set(np.unique(obs.frame)) == {0, 1, 2, 3}
    for k, theta in enumerate(THETAS):
        rows = obs.frame == k
        _, rz = _physical_camera_centre(theta)
        m = ROOM_TO_CAMERA[:3, :3] @ rz @ PASS_POSE[:3, :3].T
        t = ROOM_TO_CAMERA[:3, :3] @ rz @ (-PASS_POSE[:3, :3].T @ PASS_POSE[:3, 3]) + ROOM_TO_CAMERA[:3, 3]
        uv = cv2.projectPoints(v[obs.vertex[rows]], cv2.Rodrigues(m)[0], t, intrinsics(), DIST)[0].reshape(-1, 2)
        u, w = uv[:, 0], uv[:, 1]
        expect = np.stack([0.1 + 0.002 * u, 0.2 + 0.003 * w, 1e-5 * u * w], -1)
        assert np.allclose(obs.uv_px[rows], uv, atol=1e-3)  # px, float32 storage
        if k != 1:
            assert np.allclose(obs.signal[rows], expect, rtol=1e-5, atol=1e-5)


def test_geometry_equals_the_analytic_sphere(setup):
    sphere, _, _, obs = setup
    x = np.asarray(sphere.vertices)[obs.vertex]
    assert np.allclose(obs.normal, (x - SPHERE_CENTRE) / SPHERE_RADIUS, atol=1e-6)
    for k, theta in enumerate(THETAS):
        rows = obs.frame == k
        c, rz = _physical_camera_centre(theta)
        to_cam = c - x[rows]
        assert np.allclose(obs.distance_mm[rows], np.linalg.norm(to_cam, axis=1), rtol=1e-6)
        view = to_cam / np.linalg.norm(to_cam, axis=1, keepdims=True)
        assert np.allclose(obs.view_dir[rows], view, atol=1e-6)
        lamp = PASS_POSE[:3, :3] @ (rz.T @ np.array(LAMPS[0]["position_mm"])) + PASS_POSE[:3, 3]
        to_lamp = lamp - x[rows]
        to_lamp /= np.linalg.norm(to_lamp, axis=1, keepdims=True)
        sun = PASS_POSE[:3, :3] @ rz.T @ np.array(LAMPS[1]["direction"])
        assert np.allclose(obs.light_dir[rows, 0], to_lamp, atol=1e-6)
        assert np.allclose(obs.light_dir[rows, 1], sun, atol=1e-6)
        for j, ell in enumerate((to_lamp, np.broadcast_to(sun, to_lamp.shape))):
            h = (ell + view) / np.linalg.norm(ell + view, axis=1, keepdims=True)
            angle = np.degrees(np.arccos(np.clip(np.sum(h * obs.normal[rows], axis=1), -1, 1)))
            assert np.allclose(obs.half_angle_deg[rows, j], angle, atol=1e-3)
        # every observation views its vertex within 75 deg of the normal (the default limit)
        assert np.all(np.sum(view * obs.normal[rows], axis=1) > np.cos(np.radians(75.0)) - 1e-6)


def test_noise_and_clipping(setup):
    _, _, images, obs = setup
    expect = np.sqrt(NOISE[obs.frame, 0, None] + NOISE[obs.frame, 1, None] * obs.signal)
    assert np.allclose(obs.sigma, expect, rtol=1e-5)
    # brute force: any channel in the 3 x 3 around the nearest pixel at or above 4.0
    col, row = np.rint(obs.uv_px[:, 0]).astype(int), np.rint(obs.uv_px[:, 1]).astype(int)
    brute = np.array([images[f][max(r - 1, 0):r + 2, max(c - 1, 0):c + 2].max() >= 4.0
                      for f, r, c in zip(obs.frame, row, col)])
    assert brute.sum() >= 1 and np.array_equal(obs.clipped, brute)


def test_sorted_by_vertex_and_selection(setup):
    sphere, _, _, obs = setup
    counts = per_vertex_counts(obs)
    assert counts.shape == (len(sphere.vertices),) and counts.sum() == len(obs)
    assert np.all(np.diff(obs.vertex) >= 0)
    i = int(np.argmax(counts))
    sel = obs.of_vertex(i)
    assert np.all(sel["vertex"] == i) and len(sel["frame"]) == counts[i] >= 2
    assert len(set(sel["frame"].tolist())) == counts[i]  # one observation per frame
    with pytest.raises(AppearanceError, match="out of range"):
        obs.of_vertex(len(sphere.vertices))


def test_npz_round_trip(setup, tmp_path):
    obs = setup[3]
    path = tmp_path / "obs.npz"
    write_observations(path, obs)
    back = read_observations(path)
    assert back.n_vertices == obs.n_vertices and back.frame_names == obs.frame_names
    assert back.lamp_names == ("key", "sun")
    for name in ("offsets", "vertex", "frame", "uv_px", "signal", "sigma", "clipped", "normal", "view_dir",
                 "light_dir", "half_angle_deg", "distance_mm"):
        a, b = getattr(obs, name), getattr(back, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name


def _rewrite(src, dst, **changes):
    with np.load(src, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    data.update(changes)
    for k in [k for k, v in changes.items() if v is None]:
        del data[k]
    np.savez(dst, **data)


@pytest.mark.parametrize(("change", "needle"), [
    (lambda o: {"vertex": o.vertex.astype(np.float64)}, "'vertex'"),
    (lambda o: {"signal": np.where(np.arange(len(o))[:, None] == 3, np.nan, o.signal).astype(np.float32)}, "'signal'"),
    (lambda o: {"vertex": np.where(np.arange(len(o)) == len(o) - 1, o.n_vertices, o.vertex).astype(np.int32)},
     "'vertex'"),
    (lambda o: {"frame": np.full(len(o), 9, np.int32)}, "'frame'"),
    (lambda o: {"normal": o.normal * 2}, "'normal'"),
    (lambda o: {"offsets": o.offsets[::-1].copy()}, "'offsets'"),
    (lambda o: {"light_dir": o.light_dir[:, :1].copy()}, "'light_dir'"),
    (lambda o: {"schema": np.array("something.else")}, "schema"),
    (lambda o: {"sigma": None}, "'sigma'"),
    (lambda o: {"signal": np.array([{"x": 1}] * len(o), dtype=object)}, "pickled"),
])
def test_hostile_files_are_refused_with_one_line(setup, tmp_path, change, needle):
    obs = setup[3]
    good, bad = tmp_path / "good.npz", tmp_path / "bad.npz"
    write_observations(good, obs)
    changes = change(obs)
    if any(isinstance(v, np.ndarray) and v.dtype == object for v in changes.values()):
        with np.load(good) as z:
            data = {k: z[k] for k in z.files}
        data.update(changes)
        np.savez(bad, **data)  # savez pickles object arrays
    else:
        _rewrite(good, bad, **changes)
    with pytest.raises(AppearanceError) as err:
        read_observations(bad)
    msg = str(err.value)
    assert needle in msg and str(bad) in msg and "\n" not in msg


@pytest.mark.parametrize("damage", ["truncate", "garbage", "empty_zip"])
def test_damaged_files_are_refused_with_one_line(setup, tmp_path, damage):
    good, bad = tmp_path / "good.npz", tmp_path / "bad.npz"
    write_observations(good, setup[3])
    raw = good.read_bytes()
    if damage == "truncate":
        bad.write_bytes(raw[: len(raw) // 2])
    elif damage == "garbage":
        bad.write_bytes(b"not a zip at all" * 10)
    else:
        with zipfile.ZipFile(bad, "w"):
            pass
    with pytest.raises(AppearanceError) as err:
        read_observations(bad)
    assert str(bad) in str(err.value) and "\n" not in str(err.value)


def test_a_header_claiming_hundreds_of_gigabytes_is_refused_before_allocating(setup, tmp_path):
    """vertex.npy rewritten to claim (100000000000,) int32 (373 GiB) in a member of 192 bytes."""
    import io

    good, bad = tmp_path / "good.npz", tmp_path / "bad.npz"
    write_observations(good, setup[3])
    with zipfile.ZipFile(good) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<i4", "fortran_order": False, "shape": (100_000_000_000,)})
    members["vertex.npy"] = head.getvalue() + bytes(64)
    with zipfile.ZipFile(bad, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    with pytest.raises(AppearanceError) as err:
        read_observations(bad)
    msg = str(err.value)
    assert str(bad) in msg and "'vertex'" in msg and "(100000000000,)" in msg and "member holds" in msg, msg
    assert msg.endswith("write it with write_observations") and "\n" not in msg


def test_bad_inputs_to_observe(setup):
    sphere, frames, images, _ = setup
    with pytest.raises(AppearanceError, match="one image per frame"):
        observe(frames, sphere, images[:2], noise=[0, 1e-3], clip_level=1.0)
    with pytest.raises(AppearanceError, match="IMG_0"):
        observe(frames[:1], sphere, [images[0][:10]], noise=[0, 1e-3], clip_level=1.0)
    with pytest.raises(AppearanceError, match="noise"):
        observe(frames, sphere, images, noise=[[0, 1]] * 3, clip_level=1.0)


def test_non_finite_pixels_where_the_mesh_is_seen_are_refused(setup):
    sphere, frames, images, obs = setup
    bad = images[0].copy()
    u, v = obs.uv_px[obs.frame == 0][0]
    bad[int(round(v)), int(round(u)), 2] = np.nan
    with pytest.raises(AppearanceError, match="IMG_0.*NaN"):
        observe(frames[:1], sphere, [bad], noise=[0, 1e-3], clip_level=4.0)
