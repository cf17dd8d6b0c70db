"""Held-out validation on simulated photos: the true materials against the one-material baseline.

Truth: ``mocks.observation_sim.simulated_observations`` of the procedural hawk
(head nami-shibuichi, beak gold, cere and pupil urushi-black, eye copper) with
the sensor's noise, its true camera and lamp.  The photos carry the camera's
lens spread; the validation measures it on fitted (not held-out) frames
(:func:`processing.camera.point_spread.fit_point_spread`), which must find the
simulation's, and renders with it.  Rendering the held-out frames with the
true materials then leaves only the sensor noise (measured at 240 x 160, 3
held-out frames: mean CIEDE2000 0.81, p95 2.23 over the object); the baseline
(nami-shibuichi on every face) is identical on the head, which *is*
nami-shibuichi, and far off on the other regions (4.6x the measured materials'
error there; 2.7x when the renderings ignore the spread).  The simulation's white diffuser reads 1/pi (its images divide by
the lamp's camera signal), hence the lamp scale 1/pi.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from app.errors import UsageError
from app.workflows.holdout_validation import holdout_frames, validate_frames
from mocks.camera_sim import channel_signal
from mocks.observation_sim import _SENSOR, simulated_observations
from mocks.world import World
from processing.camera.point_spread import fit_point_spread
from render.photo_signal import render_signal

ANGLES = [30.0 * i for i in range(12)]
SIM_SCALE = 1.0          # the simulation's white diffuser reads 1, as after the chart calibration


class _LazyPhotos:
    """A sequence that hands out one image at a time and counts the reads."""

    def __init__(self, images):
        self._images = images
        self.reads = []

    def __len__(self):
        return len(self._images)

    def __getitem__(self, i):
        self.reads.append(i)
        return self._images[i]


@pytest.fixture(scope="module")
def run():
    w = World.hawk(4000, width=240, height=160, light_position_mm=(-150.0, -250.0, 300.0))
    sim = simulated_observations(w, ANGLES, noise=True, seed=3)
    names = [f.name for f in sim.frames]
    held = holdout_frames(names, ANGLES)
    idx = [i for i, n in enumerate(names) if n in held]
    white = channel_signal(w.light_spectrum(), w.grid, sim.sensitivities) / np.pi   # a white diffuser
    clip = 0.98 * _SENSOR.well_e / (_SENSOR.quantum_scale * 0.01) / white
    photos = _LazyPhotos([sim.images[i] for i in idx])
    d0 = float(np.linalg.norm(np.subtract(w.light_position_mm, w.camera_target_mm)))
    specs = [sim.materials[n] for n in sim.region_names]
    fitted = [i for i in range(len(names)) if names[i] not in held][::3]
    kw = dict(sensitivities=sim.sensitivities, scale=SIM_SCALE, irradiance_ref_mm=d0, grid=w.grid)
    renders = [render_signal(sim.vertices, sim.triangles, sim.normals, sim.face_region, specs, sim.frames[i],
                             w.light_spectrum(), **kw) for i in fitted]
    spread = fit_point_spread([sim.images[i] for i in fitted], [r for r, _ in renders], [m for _, m in renders],
                              clip_level=clip)
    result = validate_frames([sim.frames[i] for i in idx], photos, sim.vertices, sim.triangles, sim.normals,
                             sim.face_region, specs, "nami-shibuichi", w.light_spectrum(), sim.sensitivities,
                             SIM_SCALE, irradiance_ref_mm=d0, grid=w.grid, clip_level=clip, spread_px=spread.sigma_px)
    return sim, idx, photos, result, (w, specs, d0, spread)


def test_the_cameras_point_spread_is_measured_on_fitted_frames(run):
    sim, _, _, result, (w, _, _, spread) = run
    assert w.lens_sigma_px == 1.0
    assert abs(spread.sigma_px - w.lens_sigma_px) <= 0.05          # measured: see the assertion's figure
    assert spread.rms_at_sigma < 0.8 * spread.rms_pinhole
    assert result["spread_px"] == spread.sigma_px and result["edge_margin_px"] == 3


def test_every_fourth_angle_is_held_out():
    names = [f"f{i}" for i in range(12)]
    assert holdout_frames(names, ANGLES) == {"f2", "f6", "f10"}               # 60, 180, 300 degrees
    # a second pass at the same angles is held out with them; angles are taken modulo 360
    assert holdout_frames(["a", "b", "c", "d", "e"], [0, 10, 20, 30, 380]) == {"c", "e"}
    with pytest.raises(UsageError, match="every"):
        holdout_frames(names, ANGLES, every=1)
    with pytest.raises(UsageError, match="angle"):
        holdout_frames(names, ANGLES[:-1])


def test_true_materials_match_the_photos_to_the_noise(run):
    sim, idx, photos, result, _ = run
    overall = result["overall"]["measured"]
    assert result["overall"]["n_frames"] == 3 and overall["n_pixels"] > 10_000
    assert overall["mean_de2000"] <= 1.0                  # measured: 0.81 (sensor noise only; dark lacquer ~2.6)
    assert overall["p95_de2000"] <= 3.0                   # measured: 2.23
    assert sorted(photos.reads) == [0, 1, 2]              # each photo read once


def test_one_material_baseline_is_clearly_worse_where_the_object_is_not_that_material(run):
    _, _, _, result, _ = run
    regions = result["overall"]["regions"]
    head = regions["0"]                                    # nami-shibuichi: the baseline is the truth there
    assert head["measured"]["n_pixels"] == head["baseline"]["n_pixels"]
    for key in ("mean_de2000", "p95_de2000"):                # equal but where the spread mixes in a neighbour
        assert head["measured"][key] == pytest.approx(head["baseline"][key], rel=0.02)
    others_m = sum(r["measured"]["mean_de2000"] * r["measured"]["n_pixels"] for k, r in regions.items() if k != "0")
    others_b = sum(r["baseline"]["mean_de2000"] * r["baseline"]["n_pixels"] for k, r in regions.items() if k != "0")
    n = sum(r["measured"]["n_pixels"] for k, r in regions.items() if k != "0")
    assert n > 500
    assert others_b / n >= 3.0 * others_m / n             # measured: 4.6x
    assert result["overall"]["baseline"]["mean_de2000"] > result["overall"]["measured"]["mean_de2000"]


def test_frames_carry_figures_and_pngs(run):
    sim, idx, _, result, _ = run
    for k, entry in zip(idx, result["frames"], strict=True):
        assert entry["name"] == sim.frames[k].name
        assert entry["measured"]["n_pixels"] == entry["baseline"]["n_pixels"] > 1000
        for key in ("error_map_png", "baseline_error_map_png", "triptych_png"):
            assert entry[key][:8] == b"\x89PNG\r\n\x1a\n"
        trip = Image.open(io.BytesIO(entry["triptych_png"]))
        assert trip.size == (3 * 240 + 8, 160)


def test_wrong_photos_are_refused_in_one_line(run):
    sim, idx, _, _, (w, specs, d0, _) = run
    args = (sim.vertices, sim.triangles, sim.normals, sim.face_region, specs, "nami-shibuichi", w.light_spectrum(),
            sim.sensitivities, SIM_SCALE)
    with pytest.raises(UsageError, match="one photo per frame"):
        validate_frames([sim.frames[idx[0]]], [], *args, grid=w.grid)
    with pytest.raises(UsageError, match="shape") as err:
        validate_frames([sim.frames[idx[0]]], [sim.images[0][:100]], *args, grid=w.grid, images=False)
    assert "\n" not in str(err.value)
    bad = sim.images[idx[0]].copy()
    bad[80, :] = np.nan
    with pytest.raises(UsageError, match="NaN"):
        validate_frames([sim.frames[idx[0]]], [bad], *args, grid=w.grid, images=False)



def test_a_frame_without_measured_pixels_is_skipped_not_guessed(run):
    sim, idx, _, _, (w, _, d0, _) = run
    res = validate_frames([sim.frames[idx[0]]], [sim.images[idx[0]]], sim.vertices, sim.triangles, sim.normals,
                          sim.face_region, [None] * len(sim.region_names), "nami-shibuichi", w.light_spectrum(),
                          sim.sensitivities, SIM_SCALE, irradiance_ref_mm=d0, grid=w.grid)
    assert res["frames"][0]["skipped"] and "measured" not in res["frames"][0]
    assert res["overall"]["n_frames"] == 0 and res["overall"]["n_skipped"] == 1
    assert res["overall"]["measured"]["mean_de2000"] is None


def test_the_noise_floor_is_what_a_perfect_model_scores(run):
    # Photos that are the true rendering plus sensor noise of variance a + b * signal: the measured figure is then
    # the noise's own, and an independent draw of the same noise (the floor) must give the same figure.
    from render.photo_signal import render_signal

    sim, idx, _, _, (w, specs, d0, _) = run
    frame = sim.frames[idx[0]]
    clean, _ = render_signal(sim.vertices, sim.triangles, sim.normals, sim.face_region, specs, frame,
                             w.light_spectrum(), sensitivities=sim.sensitivities, scale=SIM_SCALE, grid=w.grid,
                             irradiance_ref_mm=d0)
    ab = (1e-6, 2e-4)
    noisy = clean + np.sqrt(ab[0] + ab[1] * np.maximum(clean, 0.0)) * np.random.default_rng(11).standard_normal(
        clean.shape)
    args = (sim.vertices, sim.triangles, sim.normals, sim.face_region, specs, "nami-shibuichi", w.light_spectrum(),
            sim.sensitivities, SIM_SCALE)
    res = validate_frames([frame], [noisy], *args, irradiance_ref_mm=d0, grid=w.grid, images=False, noise=ab)
    floor, measured = res["overall"]["noise_floor"]["mean_de2000"], res["overall"]["measured"]["mean_de2000"]
    assert floor > 0.3                                         # the noise is visible
    assert measured == pytest.approx(floor, rel=0.1)
    exact = validate_frames([frame], [clean], *args, irradiance_ref_mm=d0, grid=w.grid, images=False, noise=ab)
    assert exact["overall"]["measured"]["mean_de2000"] < 0.05 < exact["overall"]["noise_floor"]["mean_de2000"]
    assert "noise_floor" not in validate_frames([frame], [clean], *args, irradiance_ref_mm=d0, grid=w.grid,
                                                images=False)["overall"]


def test_pooled_comparison_keeps_the_per_pixel_figures_and_lowers_the_noise(run):
    # Photos = the true rendering + sensor noise of variance a + b * signal (so every error is noise): compared in
    # 4 x 4 px blocks of linear values the noise's standard deviation falls 4-fold and the figures with it (the
    # measured figure and the floor alike, within 20 % of each other); the per-pixel figures must be exactly
    # those of a per-pixel run.
    from render.photo_signal import render_signal

    sim, idx, _, _, (w, specs, d0, _) = run
    frames = [sim.frames[i] for i in idx]
    args = (sim.vertices, sim.triangles, sim.normals, sim.face_region, specs, "nami-shibuichi", w.light_spectrum(),
            sim.sensitivities, SIM_SCALE)
    ab = (1e-6, 2e-4)
    rng = np.random.default_rng(5)
    photos = []
    for f in frames:
        clean, _ = render_signal(sim.vertices, sim.triangles, sim.normals, sim.face_region, specs, f,
                                 w.light_spectrum(), sensitivities=sim.sensitivities, scale=SIM_SCALE, grid=w.grid,
                                 irradiance_ref_mm=d0)
        photos.append(clean + np.sqrt(ab[0] + ab[1] * np.maximum(clean, 0.0)) * rng.standard_normal(clean.shape))
    kw = dict(irradiance_ref_mm=d0, grid=w.grid, noise=ab)
    res = validate_frames(frames, photos, *args, images=True, pool_px=4, **kw)
    plain = validate_frames(frames, photos, *args, images=False, **kw)
    assert res["overall"]["measured"] == plain["overall"]["measured"]
    per_pixel, pooled = res["overall"]["measured"]["mean_de2000"], res["overall"]["pooled"]
    assert pooled["block_px"] == 4 and pooled["measured"]["n_pixels"] > 300
    assert pooled["measured"]["mean_de2000"] < 0.4 * per_pixel
    assert pooled["measured"]["mean_de2000"] == pytest.approx(pooled["noise_floor"]["mean_de2000"], rel=0.2)
    assert all("pooled" in f and f["pooled_error_map_png"].startswith(b"\x89PNG") for f in res["frames"])
    # the floor of a 16-frame mean: noise sd / 4; CIEDE2000 is close to linear in small differences (+-30 %)
    burst = validate_frames(frames[:1], photos[:1], *args, images=False, frames_averaged=16, **kw)
    single = validate_frames(frames[:1], photos[:1], *args, images=False, **kw)
    ratio = burst["overall"]["noise_floor"]["mean_de2000"] / single["overall"]["noise_floor"]["mean_de2000"]
    assert 0.25 / 1.3 < ratio < 0.25 * 1.3
    with pytest.raises(UsageError, match="pool_px"):
        validate_frames(frames[:1], photos[:1], *args, images=False, pool_px=0)
