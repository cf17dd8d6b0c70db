"""Pinhole camera: validation, ray directions, sub-pixel strata, framing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from render.camera import Camera
from render.errors import RenderInputError


def cam(**kw) -> Camera:
    base = dict(eye=(0.0, -5.0, 0.0), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), fov_deg=40.0, width=8, height=6)
    base.update(kw)
    return Camera(**base)


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(width=0), "width"),
        (dict(height=-3), "height"),
        (dict(width=2.5), "width"),
        (dict(width=True), "width"),
        (dict(eye=(0, 0, 0)), "same point"),
        (dict(up=(0, 1, 0)), "parallel"),
        (dict(up=(0, 0, 0)), "up vector is zero"),
        (dict(fov_deg=0), "fov_deg"),
        (dict(fov_deg=180), "fov_deg"),
        (dict(fov_deg=float("nan")), "fov_deg"),
        (dict(eye=(0, float("inf"), 0)), "finite"),
        (dict(target=(1, 2)), "three numbers"),
    ],
)
def test_bad_cameras_are_refused_with_the_parameter_named(kw, message):
    with pytest.raises(RenderInputError, match=message):
        cam(**kw)


def test_centre_pixel_ray_points_at_the_target_and_corners_span_the_field_of_view():
    c = cam(width=5, height=5, fov_deg=60.0)
    rays = c.rays(0, 5, 0, 5, samples=1).reshape(5, 5, 6)
    np.testing.assert_allclose(rays[..., :3], np.broadcast_to([0, -5, 0], (5, 5, 3)))
    np.testing.assert_allclose(np.linalg.norm(rays[..., 3:], axis=-1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(rays[2, 2, 3:], [0, 1, 0], atol=1e-7)
    # the centre of the top row is 2/5 of the half field above the axis: tan(angle) = 0.8 tan(30 deg)
    top = rays[0, 2, 3:]
    assert top[2] > 0
    assert math.atan2(top[2], top[1]) == pytest.approx(math.atan(0.8 * math.tan(math.radians(30))), rel=1e-6)
    # the left column is to the -x side (right-handed camera frame: right = forward x up)
    assert rays[2, 0, 3] < 0 < rays[2, 4, 3]


def test_project_inverts_ray_generation():
    c = cam(width=32, height=20, fov_deg=50.0, eye=(3.0, -4.0, 2.0), target=(0.5, 0.2, 0.1))
    rays = c.rays(0, 32, 0, 20, samples=1)
    points = rays[:, :3] + 7.0 * rays[:, 3:]
    xy = c.project(points)
    ys, xs = np.mgrid[0:20, 0:32]
    np.testing.assert_allclose(xy[:, 0], xs.ravel() + 0.5, atol=2e-4)
    np.testing.assert_allclose(xy[:, 1], ys.ravel() + 0.5, atol=2e-4)
    assert np.all(np.isnan(c.project([[0.0, -10.0, 0.0]])))   # behind the camera


@pytest.mark.parametrize("samples", [2, 4, 9, 16])
def test_stratified_samples_fill_each_stratum_once(samples):
    c = cam()
    off = c.sample_offsets(500, samples, np.random.default_rng(3), jitter=True)
    assert off.shape == (500, samples, 2) and off.dtype == np.float32
    assert np.all((off >= 0) & (off < 1))
    k = math.ceil(math.sqrt(samples))
    rows = math.ceil(samples / k)
    cells = np.floor(off[..., 0] * k) + k * np.floor(off[..., 1] * rows)
    assert np.all(cells == np.arange(samples))           # sample j in stratum j
    # jitter covers the stratum: mean position over many pixels is its centre
    centre = (np.stack([np.arange(samples) % k, np.arange(samples) // k], -1) + 0.5) / [k, rows]
    np.testing.assert_allclose(off.mean(axis=0), centre, atol=0.05)


@pytest.mark.parametrize("samples", [4, 9, 16])
def test_ordered_grid_is_a_rotated_grid_centred_on_the_pixel(samples):
    c = cam()
    off = c.sample_offsets(3, samples, None, jitter=False)
    assert np.array_equal(off[0], off[2])                         # the same pattern in every pixel
    k = int(math.isqrt(samples))
    cells = np.floor(off[0, :, 0] * k) + k * np.floor(off[0, :, 1] * k)
    assert np.all(cells == np.arange(samples))                   # one sample per stratum
    assert len(set(off[0, :, 0])) == samples and len(set(off[0, :, 1])) == samples   # N-rooks
    np.testing.assert_allclose(off[0].mean(axis=0), [0.5, 0.5], atol=1e-7)


def test_four_samples_use_the_rotated_grid_pattern_and_one_sample_is_the_pixel_centre():
    c = cam()
    np.testing.assert_array_equal(c.sample_offsets(3, 4, None, jitter=False)[1],
                                  [[0.375, 0.125], [0.875, 0.375], [0.125, 0.625], [0.625, 0.875]])
    np.testing.assert_array_equal(c.sample_offsets(2, 1, None), [[[0.5, 0.5]], [[0.5, 0.5]]])
    with pytest.raises(RenderInputError, match="random generator"):
        c.sample_offsets(2, 4, None, jitter=True)
    with pytest.raises(RenderInputError, match="whole number"):
        c.sample_offsets(2, 0, None)


def test_ray_blocks_outside_the_image_are_refused():
    with pytest.raises(RenderInputError, match="outside"):
        cam().rays(0, 9, 0, 6)


def test_rays_of_tiles_assemble_into_the_rays_of_the_image():
    c = cam(width=10, height=7)
    whole = c.rays(0, 10, 0, 7, samples=4, jitter=False).reshape(7, 10, 4, 6)
    part = c.rays(3, 8, 2, 6, samples=4, jitter=False).reshape(4, 5, 4, 6)
    np.testing.assert_array_equal(part, whole[2:6, 3:8])


@hsettings(max_examples=40, deadline=None)
@given(
    lo=st.tuples(*[st.floats(-100, 100) for _ in range(3)]),
    size=st.tuples(*[st.floats(0.01, 50) for _ in range(3)]),
    fov=st.floats(5, 120),
    width=st.integers(1, 400),
    height=st.integers(1, 400),
    direction=st.tuples(*[st.floats(-1, 1) for _ in range(3)]).filter(
        lambda d: np.linalg.norm(d) > 0.1 and np.linalg.norm(np.cross(d, (0, 0, 1))) > 0.05 * np.linalg.norm(d)
    ),
)
def test_framing_keeps_the_whole_bounding_box_in_view(lo, size, fov, width, height, direction):
    lo = np.asarray(lo)
    hi = lo + np.asarray(size)
    c = Camera.framing(lo, hi, width, height, fov_deg=fov, direction=direction)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    xy = c.project(corners)
    assert np.all(np.isfinite(xy))
    assert np.all((xy[:, 0] >= 0) & (xy[:, 0] <= width) & (xy[:, 1] >= 0) & (xy[:, 1] <= height))
    np.testing.assert_allclose(c.target, (lo + hi) / 2)


def test_framing_errors():
    with pytest.raises(RenderInputError, match="single point"):
        Camera.framing((1, 1, 1), (1, 1, 1), 10, 10)
    with pytest.raises(RenderInputError, match="below bounds_min"):
        Camera.framing((1, 1, 1), (0, 2, 2), 10, 10)
    with pytest.raises(RenderInputError, match="direction is zero"):
        Camera.framing((0, 0, 0), (1, 1, 1), 10, 10, direction=(0, 0, 0))
    with pytest.raises(RenderInputError, match="height"):
        Camera.framing((0, 0, 0), (1, 1, 1), 10, 0)
    with pytest.raises(RenderInputError, match="parallel"):
        Camera.framing((0, 0, 0), (1, 1, 1), 10, 10, direction=(0, 0, 1))
