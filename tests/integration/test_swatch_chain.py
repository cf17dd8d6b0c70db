"""The simulated swatch chain step by step: radiance -> noise-free signal -> DNG -> decoded RAW -> fit pixels.

A swatch capture's frames must differ from the cloth model only by pixel noise and one gain per channel
(EMVA Standard 1288, release 4.0, section 2: linear signal, shot noise, read noise, quantisation).  The
noise-free signal (``mean_electrons`` of :func:`mocks.camera_sim.simulate_raw`) is compared with the model's
prediction at the table angle the fit uses, and the decoded frames' means with the noise-free signal,
against the sensor's closed-form variance: a departure shared by the pixels of a frame (an exposure, a
wrong angle, a decoding offset) shows as a z-score far above the few that noise gives.
"""

from __future__ import annotations

import numpy as np
import pytest

from mocks.camera_sim import SensorModel, simulate_raw
from mocks.swatch_world import SwatchWorld
from processing.camera.raw_decode import decode_raw
from processing.cloth.fit import chart_gains, grid_chart_means, predict_rgb
from processing.materials.presets import get_material

COTTON = ("cotton:a_t=0.3,a_b=0.6,weft_a_t=0.3,weft_a_b=0.6,specular=0.08,internal=0.15,diffuse=0.7,"
          "warp_colour=#c08040,weft_colour=#c08040")
W, H = 64, 48
CAMERA_SIDE = (-0.22, -0.6, 0.77)     # pass 2's lamp: near the mirror direction, where turning the table matters most


def _binned(a: np.ndarray) -> np.ndarray:
    """Same-colour photosites of each RGGB cell: R, mean of the two G, B (the decoder's 2 x 2 binning)."""
    return np.stack([a[0::2, 0::2], (a[0::2, 1::2] + a[1::2, 0::2]) / 2, a[1::2, 1::2]], axis=-1)


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    from app.session import Session
    from app.workflows.cloth_fit import capture_swatch_session, load_swatch_session

    world = SwatchWorld.swatch(COTTON, width=W, height=H)
    lights = [tuple(world.light_direction), CAMERA_SIDE]
    # 6 steps of 60 deg: a pass starting one step off its recorded zero would show (the plain weave's period
    # is 90 deg), by up to 1 % of the frame mean under the camera-side lamp
    root = capture_swatch_session(tmp_path_factory.mktemp("chain") / "s", COTTON, steps=6, width=W, height=H,
                                  seed=3, lights=lights)
    data = load_swatch_session(root, max_pixels=10_000)          # every pixel that sees the swatch throughout
    frames = sorted((r for r in Session.read(root)["captures"].values() if r.get("kind") == "frame"),
                    key=lambda r: (int(r["pass"]), float(r["angle_deg"])))
    noise_free = []
    for r in frames:
        world.light_direction = lights[int(r["pass"]) - 1]
        f = world.frame("object", float(r["angle_deg"]))        # the swatch at the angle the session records
        noise_free.append(simulate_raw(f.radiance, f.grid, f.light, seed=0).mean_electrons)
    world.light_direction = lights[0]
    return root, data, frames, world, noise_free


def test_noise_free_signal_is_the_model_times_the_chart_gain(chain):
    # radiance -> electrons is linear: at every frame, pixel and channel the noise-free signal over the
    # model's prediction at the recorded table angle is one number, the noise-free chart frame's gain
    _, data, frames, world, noise_free = chain
    m, g = data.measurement, data.geometry
    assert m.angles_deg.tolist() == [float(r["angle_deg"]) for r in frames]
    assert m.passes.tolist() == [1] * 6 + [2] * 6
    px = m.pixels
    mu = np.stack([_binned(e)[px[:, 1], px[:, 0]] for e in noise_free])
    ratio = mu / predict_rgb(get_material(COTTON), g, m.angles_deg, px, m.cfa_pattern, passes=m.passes)
    chart = world.frame("chart", 0.0)
    chart_mu = _binned(simulate_raw(chart.radiance, chart.grid, chart.light, seed=0).mean_electrons)
    gain = chart_gains(grid_chart_means(chart_mu), g)
    np.testing.assert_allclose(ratio, gain[0], rtol=1e-6)
    np.testing.assert_allclose(gain, gain[0], rtol=1e-6)


def test_decoded_frame_means_depart_from_the_signal_only_by_pixel_noise(chain):
    # DNG -> decode -> the fit's pixels: each frame's summed electrons minus the noise-free sum, over the
    # closed-form standard deviation (shot mu + read noise^2 + quantisation g^2 / 12 per photosite); the
    # second pass too, its lamp moved and the swatch left where it lies (the table turned back to the
    # first pass's zero, not re-zeroed where the first pass ended)
    root, data, frames, _, noise_free = chain
    s = SensorModel()
    px = data.measurement.pixels
    assert px.shape[0] > 150
    z = []
    for r, e in zip(frames, noise_free):
        img = decode_raw(root / r["file"], mode="bin2x2")
        black = np.asarray(img.black_levels[:3])
        got = img.rgb[px[:, 1], px[:, 0]].astype(np.float64) * (img.white_level - black) * s.gain_e_per_dn
        mu = _binned(e)[px[:, 1], px[:, 0]]
        var = _binned(e + s.read_noise_e ** 2 + s.gain_e_per_dn ** 2 / 12)[px[:, 1], px[:, 0]] / np.array([1.0, 2.0, 1.0])
        z.append((got - mu).sum(axis=0) / np.sqrt(var.sum(axis=0)))
    z = np.array(z)                                                      # (frames, 3)
    # a departure of 0.5 % shared by a frame's pixels gives z of 4 to 7 in R and G here (2 to 4 in B), and an rms
    # of about 4; pixel noise alone keeps |z| below 3 (about 230 binned pixels per frame, 36 values)
    assert np.abs(z).max() < 4.0
    assert 0.4 < np.sqrt(np.mean(z ** 2)) < 1.7
    assert 0.4 < np.sqrt(np.mean(z[6:] ** 2)) < 1.9                    # the second pass alone
