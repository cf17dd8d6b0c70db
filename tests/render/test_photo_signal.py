"""render_signal against the simulated camera's photos of the same world (true materials, camera and lamp).

Truth: ``mocks.observation_sim.simulated_observations(..., noise=False).images``,
rendered by ``mocks.world.World`` independently (its own pinhole rays, normals
interpolated from the vertex normals, its own lamp).  The simulation's images put
a white diffuser facing the lamp at 1, as the chart calibration does, so the
renderer's lamp scale is 1; the simulated sensor also saturates, so clipped
pixels are left out.  The simulated photos carry the camera's lens spread
(``World.lens_sigma_px``): the renderer is given the same spread, and pixels
within 4 spreads (the kernel's reach) of the outline (where the photo mixes in the backdrop the
renderer does not draw) are left out.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from mocks.camera_sim import channel_signal
from mocks.observation_sim import _SENSOR, simulated_observations
from mocks.world import World
from render.errors import RenderInputError
from render.photo_signal import pixel_faces, render_signal

SIM_SCALE = 1.0          # the simulation's white diffuser reads 1, as after the chart calibration


def _world(point: bool) -> World:
    lamp = {"light_position_mm": (-150.0, -250.0, 300.0)} if point else {"light_direction": (-0.4, -0.6, 0.7)}
    return World.hawk(4000, width=240, height=160, **lamp)


@pytest.fixture(scope="module", params=[True, False], ids=["point-lamp", "distant-lamp"])
def sim(request):
    w = _world(request.param)
    s = simulated_observations(w, [30.0, 200.0], noise=False)
    white = channel_signal(w.light_spectrum(), w.grid, s.sensitivities)
    clip = _SENSOR.well_e / (_SENSOR.quantum_scale * 0.01) / white      # the sim's saturation, per channel
    d0 = None if w.light_position_mm is None else float(np.linalg.norm(np.subtract(w.light_position_mm,
                                                                                   w.camera_target_mm)))
    return w, s, clip, d0


def test_rendered_signal_equals_the_simulated_photo(sim):
    w, s, clip, d0 = sim
    specs = [s.materials[n] for n in s.region_names]
    for k, frame in enumerate(s.frames):
        sig, mask = render_signal(s.vertices, s.triangles, s.normals, s.face_region, specs, frame, w.light_spectrum(),
                                  sensitivities=s.sensitivities, scale=SIM_SCALE, irradiance_ref_mm=d0, grid=w.grid,
                                  spread_px=w.lens_sigma_px)
        img, obj = s.images[k], s.labels[k] >= 0
        assert sig.shape == img.shape and sig.dtype == np.float32
        assert np.mean(mask == obj) > 0.999                               # same outline up to ray precision
        clipped = ndimage.binary_dilation(np.any(img >= 0.999 * clip, axis=-1), iterations=3)   # spread clipping
        inner = ndimage.binary_erosion(obj, iterations=5) & ~clipped
        rel = np.abs(sig[inner] - img[inner]) / np.maximum(img[inner], 1e-4)
        lit = img[inner].max(axis=1) > 1e-3
        assert inner.sum() > 3000 and lit.sum() > 300
        assert np.mean(rel.max(axis=1) < 0.01) > 0.995                   # shadow edges may flip a few pixels
        assert np.median(rel[lit]) < 1e-3


def test_regions_without_material_are_nan_and_outside_the_mask(sim):
    w, s, _, d0 = sim
    specs = [s.materials[n] for n in s.region_names]
    specs[1] = None                                                       # the beak: not measured
    frame = s.frames[0]
    sig, mask = render_signal(s.vertices, s.triangles, s.normals, s.face_region, specs, frame, w.light_spectrum(),
                              sensitivities=s.sensitivities, scale=SIM_SCALE, irradiance_ref_mm=d0, grid=w.grid)
    faces = pixel_faces(s.vertices, s.triangles, frame)
    beak = (faces >= 0) & (s.face_region[np.maximum(faces, 0)] == 1)
    assert beak.sum() > 20
    assert np.isnan(sig[beak]).all() and not mask[beak].any()
    assert np.isfinite(sig[~beak]).all() and np.array_equal(mask, (faces >= 0) & ~beak)
    assert np.array_equal(faces >= 0, s.labels[0] >= 0) or np.mean((faces >= 0) == (s.labels[0] >= 0)) > 0.999


def test_bad_inputs_are_refused(sim):
    w, s, _, _ = sim
    frame = s.frames[0]
    args = (s.vertices, s.triangles, s.normals, s.face_region, ["gold"] * 5, frame, "D65")
    with pytest.raises(RenderInputError, match="face_material"):
        render_signal(*args[:3], s.face_region[:-1], *args[4:])
    with pytest.raises(RenderInputError, match="face_material"):
        render_signal(*args[:4], ["gold"], *args[5:])
    with pytest.raises(RenderInputError, match="scale"):
        render_signal(*args, scale=0.0)
    with pytest.raises(RenderInputError, match="light_spectrum"):
        render_signal(*args[:6], np.ones(3))
    with pytest.raises(RenderInputError, match="normals"):
        render_signal(*args[:2], np.ones((2, 3)), *args[3:])


def test_distorted_frame_outline_matches_the_mesh_mask(sim):
    from processing.appearance.frame_poses import FramePose
    from processing.appearance.silhouette import mesh_mask

    w, s, _, d0 = sim
    f = s.frames[0]
    distorted = FramePose(f.name, f.pass_index, f.table_angle_deg, f.image_size, f.K,
                          np.array([-0.6, 0.2, 0.002, -0.001, 0.0]), f.mesh_to_camera, f.lamps)
    specs = [s.materials[n] for n in s.region_names]
    _, mask = render_signal(s.vertices, s.triangles, s.normals, s.face_region, specs, distorted, w.light_spectrum(),
                            sensitivities=s.sensitivities, scale=SIM_SCALE, irradiance_ref_mm=d0, grid=w.grid)
    truth = mesh_mask((s.vertices, s.triangles), distorted)
    undistorted = s.labels[0] >= 0
    assert (mask & truth).sum() / (mask | truth).sum() > 0.99
    assert (mask ^ undistorted).sum() > 100                               # the distortion moved the outline
