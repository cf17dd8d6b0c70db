"""Mesh and object masks against analytic outlines; IoU and boundary offset of known shapes."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from processing.appearance.frame_poses import AppearanceError, FramePose
from processing.appearance.silhouette import mesh_mask, object_mask, outline_px, silhouette_check
from tests.appearance.synthetic_scene import HEIGHT, WIDTH, analytic_labels, intrinsics, look_at, sphere_and_box

ROOM_TO_CAMERA = look_at([480.0, -60.0, 200.0], [0.0, 0.0, 60.0])


def _disc(shape, centre, radius):
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    return (cols - centre[0]) ** 2 + (rows - centre[1]) ** 2 <= radius ** 2


@pytest.fixture(scope="module")
def scene():
    mesh, _, lo, hi = sphere_and_box(resolution=60)
    frame = FramePose("f", 1, 0.0, (WIDTH, HEIGHT), intrinsics(), np.zeros(5), ROOM_TO_CAMERA)
    truth = analytic_labels(ROOM_TO_CAMERA, intrinsics(), lo=lo, hi=hi) > 0
    return mesh, frame, truth


@pytest.mark.parametrize(("binning", "max_off_px"), [(1, 1.5), (2, 2.5)])
def test_mesh_mask_matches_the_analytic_outline(scene, binning, max_off_px):
    mesh, frame, truth = scene
    got = mesh_mask(mesh, frame, binning=binning)
    assert got.shape == (HEIGHT, WIDTH) and got.dtype == bool
    # every disagreeing pixel lies within max_off_px of the analytic outline
    edge = truth ^ cv2.erode(truth.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    d = cv2.distanceTransform((~edge).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    assert d[got ^ truth].max(initial=0) <= max_off_px
    check = silhouette_check(got, truth)
    assert check["iou"] > 0.97 and check["offset_px"] < 0.5 * binning


def test_object_mask_finds_the_object_on_a_noisy_backdrop(scene):
    _, _, truth = scene
    rng = np.random.default_rng(3)
    image = np.full((HEIGHT, WIDTH, 3), [0.20, 0.22, 0.25], np.float32)
    image[truth] = [0.5, 0.35, 0.2]
    image[truth & (np.arange(WIDTH)[None, :] > 120)] = [0.2, 0.22, 0.40]  # differs in one channel only
    image[_disc(truth.shape, (118, 70), 4)] = [0.20, 0.22, 0.25]  # a hole of backdrop colour inside
    image += rng.normal(0.0, 0.004, image.shape).astype(np.float32)
    spikes = rng.integers(0, [HEIGHT, WIDTH], (30, 2))
    image[spikes[:, 0], spikes[:, 1]] += 0.2  # isolated hot pixels
    got = object_mask(image, name="IMG_1")
    inter = np.count_nonzero(got & truth) / np.count_nonzero(got | truth)
    assert inter > 0.99  # the hole is filled, the spikes are gone


def test_object_mask_refuses_an_empty_frame():
    image = np.full((60, 80, 3), 0.3) + np.random.default_rng(0).normal(0, 0.001, (60, 80, 3))
    with pytest.raises(AppearanceError, match="IMG_9"):
        object_mask(image, name="IMG_9")
    with pytest.raises(AppearanceError, match="IMG_9"):
        object_mask(np.full((60, 80, 3), np.nan), name="IMG_9")


def test_silhouette_check_of_shifted_discs():
    r, shift = 40.0, 3.0
    a = _disc((200, 300), (150, 100), r)
    b = _disc((200, 300), (150 + shift, 100), r)
    lens = 2 * r * r * math.acos(shift / (2 * r)) - shift / 2 * math.sqrt(4 * r * r - shift * shift)
    iou = lens / (2 * math.pi * r * r - lens)
    got = silhouette_check(a, b)
    # mean distance between two circles shifted by s is 2 s / pi (first order); pixel outlines add ~0.2 px
    assert abs(got["iou"] - iou) < 0.005 and abs(got["offset_px"] - 2 * shift / math.pi) < 0.3
    same = silhouette_check(a, a)
    assert same == {"iou": 1.0, "offset_px": 0.0}
    with pytest.raises(AppearanceError, match="empty"):
        silhouette_check(a, np.zeros_like(a))


def test_outline_of_a_rectangle_and_a_disc():
    m = np.zeros((50, 60), bool)
    m[10:20, 5:30] = True
    (poly,) = outline_px(m)
    assert {tuple(p) for p in poly.tolist()} == {(5.0, 10.0), (29.0, 10.0), (29.0, 19.0), (5.0, 19.0)}
    disc = _disc((100, 100), (50, 50), 30)
    polys = outline_px(disc)
    assert len(polys) == 1
    radius = np.hypot(polys[0][:, 0] - 50, polys[0][:, 1] - 50)
    assert np.abs(radius - 30).max() < 1.0


@pytest.mark.parametrize("level", [0.02, 0.9])   # a dark object (a metal away from its highlight) and a bright one
def test_object_mask_puts_the_outline_where_pixels_are_half_covered(level):
    """An anti-aliased disc (16 x 16 samples per pixel, noise 0.2 % of full scale) against the analytic disc.

    A noise threshold alone takes every partly covered rim pixel (the mask grows by about half a pixel);
    the half-coverage rim keeps the area within 0.5 % and the IoU with the exact disc above 0.995.
    """
    h, w, r, c = 120, 160, 37.3, (81.2, 58.7)
    s = 16
    ys, xs = np.mgrid[0:h * s, 0:w * s]
    inside = ((xs + 0.5) / s - 0.5 - c[0]) ** 2 + ((ys + 0.5) / s - 0.5 - c[1]) ** 2 < r * r
    cover = inside.reshape(h, s, w, s).mean(axis=(1, 3))
    backdrop = np.array([0.05, 0.06, 0.055])
    obj = np.array([level, level * 0.9, level * 1.1])
    img = cover[..., None] * obj + (1 - cover[..., None]) * backdrop
    img += np.random.default_rng(3).normal(0, 0.002, img.shape)
    mask = object_mask(img, name="disc")
    yy, xx = np.mgrid[0:h, 0:w]
    exact = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 < r * r
    assert abs(mask.sum() / (math.pi * r * r) - 1) < 0.005
    assert silhouette_check(mask, exact)["iou"] > 0.995
