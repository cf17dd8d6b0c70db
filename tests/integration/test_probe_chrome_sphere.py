"""A chrome sphere rendered under the recovered probe against the simulated camera's photo of it.

The simulated camera photographs a chrome ball (reflectance 0.6, flat) in the simulated room
(:mod:`mocks.probe_world`, 480 x 320 frames); ``build_probe`` recovers the room's map from the
brackets.  kogei's renderer then draws an ideal mirror sphere of the same reflectance, size and place
under that map, seen by the simulated camera (its pose, and its field of view from the intrinsics),
and the rendered luminance is compared with the truth photo (the room's true radiance seen in the
ball, in the probe's units: the chart's white) over the ball's pixels whose mirrored direction lies
outside the masked caps (the camera's own view and the directions behind the ball) by a margin.

What limits the agreement: the map is the photo resampled twice (the unwrap averages 3 x 3 directions
per map pixel of a 64 x 128 map, about the ball's own resolution, then the renderer interpolates it),
so at the lamps' and the window's edges, where the radiance jumps 8 to 40 times over a pixel, single
pixels differ a lot; the bulk of the ball (walls, floor, ceiling) and its total agree to the probe's
own accuracy (1 % luminance for the greys; the chromatic walls' estimator error, up to 9 %).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from app.workflows.light_probe import ProbeInputs, build_probe
from mocks.mirror_world import CHROME_REFLECTANCE
from mocks.probe_world import ProbeWorld, write_probe_shots
from processing.geometry.camera_calibration import CameraCalibration
from processing.materials.lobes import Lobe, Material
from processing.spectral.display import spectra_to_xyz
from render.camera import Camera
from render.meshio import make_mesh
from render.presets import PRESETS
from render.renderer import render
from render.scene import Scene, SceneObject, Sky

SIZE = (480, 320)
RADIUS_MM = 20.0
CAP_MARGIN_DEG = 8.0       # kept away from the masked caps' borders (filled there from a 5-degree ring)


class Flat:
    """Spectrally flat, angle-independent reflectance (the simulated chrome's)."""

    angle_dependent = False

    def __init__(self, rho: float) -> None:
        self.rho = rho

    def reflectance(self, cos_d, wavelengths):
        return np.full(np.shape(cos_d) + (len(wavelengths),), self.rho)


def uv_sphere(centre: np.ndarray, radius: float, n_theta: int = 192, n_phi: int = 384):
    """A closed UV sphere with exact unit normals at the vertices."""
    theta = np.linspace(0.0, math.pi, n_theta + 1)[1:-1]
    phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    n = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    n = np.concatenate([[[0, 0, 1.0]], n, [[0, 0, -1.0]]])
    rows = n_theta - 1
    i, j = np.meshgrid(np.arange(rows - 1), np.arange(n_phi), indexing="ij")
    a, b = 1 + i * n_phi + j, 1 + i * n_phi + (j + 1) % n_phi
    c, d = a + n_phi, b + n_phi
    top = np.stack([np.zeros(n_phi, int), 1 + np.arange(n_phi), 1 + (np.arange(n_phi) + 1) % n_phi], axis=1)
    last = len(n) - 1
    k = 1 + (rows - 1) * n_phi
    bottom = np.stack([np.full(n_phi, last), k + (np.arange(n_phi) + 1) % n_phi, k + np.arange(n_phi)], axis=1)
    tris = np.concatenate([top, np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3),
                           bottom])
    return make_mesh(centre + radius * n, tris, n)


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    world = ProbeWorld.probe(RADIUS_MM, width=SIZE[0], height=SIZE[1])
    chart, frames = write_probe_shots(world, tmp_path_factory.mktemp("room"))
    cal = CameraCalibration.from_dict(json.loads(json.dumps(CameraCalibration(
        SIZE, world.camera_intrinsics(), np.zeros(5), np.eye(4), room_to_camera=world.room_to_camera()).to_dict())))
    result = build_probe(ProbeInputs(frames, chart, cal, RADIUS_MM, "room"))
    # the simulated camera: pose from its room -> camera transform, vertical field of view from fy
    to_cam = world.room_to_camera()
    eye = -to_cam[:3, :3].T @ to_cam[:3, 3]
    forward, down = to_cam[2, :3], to_cam[1, :3]
    k = world.camera_intrinsics()
    fov_deg = 2 * math.degrees(math.atan((SIZE[1] / 2) / k[1, 1]))
    camera = Camera(tuple(eye), tuple(eye + 100 * forward), tuple(-down), fov_deg, *SIZE)
    centre = world.sphere_centre_mm(0.0)
    chrome = Material("chrome", (Lobe("microfacet", 1.0, Flat(CHROME_REFLECTANCE), roughness=1e-4, mirror=True),))
    scene = Scene([SceneObject(uv_sphere(centre, RADIUS_MM), [chrome])], [], Sky("none"),
                  environment=result.environment)
    rendered = render(scene, camera, PRESETS["standard"]).xyz[..., 1]
    frame = world.frame("object")
    photo = spectra_to_xyz(frame.radiance, frame.grid)[..., 1] / world.chart_white_luminance()
    # the ball's pixels (whole pixels, one off the rim) and their mirrored directions (ray-sphere, written out)
    h, w = SIZE[1], SIZE[0]
    yy, xx = np.mgrid[0:h, 0:w]
    axes = np.stack([to_cam[0, :3], down, forward])
    d = ((xx - k[0, 2]) / k[0, 0])[..., None] * axes[0] + ((yy - k[1, 2]) / k[1, 1])[..., None] * axes[1] + axes[2]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    oc = eye - centre
    b = d @ oc
    disc = b * b - (oc @ oc - RADIUS_MM**2)
    footprint = np.linalg.norm(oc) / k[0, 0]
    inside = b * b - (oc @ oc - (RADIUS_MM - 1.5 * footprint) ** 2) > 0
    t = -b - np.sqrt(np.clip(disc, 0, None))
    nrm = (eye + d * t[..., None] - centre) / RADIUS_MM
    refl = d - 2 * np.einsum("hwi,hwi->hw", d, nrm)[..., None] * nrm
    toward = np.asarray(result.report["map"]["toward_camera"])
    ang = np.degrees(np.arccos(np.clip(refl @ toward, -1, 1)))
    keep = inside & (ang > result.report["map"]["camera_mask_deg"] + CAP_MARGIN_DEG) & (
        ang < 180 - result.report["map"]["back_mask_deg"] - CAP_MARGIN_DEG)
    return rendered[keep], photo[keep]


def test_the_balls_total_luminance_matches_the_photo(compared):
    # what the ball shows, summed over the compared pixels: measured 0.986 (the probe's own 1 %); bound 3 %
    rendered, photo = compared
    assert len(rendered) > 1000
    assert abs(rendered.sum() / photo.sum() - 1.0) < 0.03


def test_the_balls_pixels_match_the_photo_away_from_the_lamps_edges(compared):
    # per pixel: the median ratio within 3 % (measured 0.991; median |error| 1.1 %); 80 % of the pixels within
    # 10 % (measured 86 %: the walls' estimator error, up to 9 %, and the blur of two resamplings at the lamps'
    # and the window's edges, where the 90th percentile of |error| is 18 %)
    rendered, photo = compared
    ratio = rendered / photo
    assert abs(float(np.median(ratio)) - 1.0) < 0.03
    assert np.mean(np.abs(ratio - 1.0) < 0.10) > 0.8
