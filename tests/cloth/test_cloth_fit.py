"""Measuring a swatch: the simulated swatch world against closed forms, a swatch capture through
the station's hot folder, `kogei cloth fit` recovering the world's known parameters within 10 %
and rendering unseen angles within mean delta E00 1.5, robustness to outliers, bad input."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from app.cli import main
from mocks.swatch_world import SwatchWorld
from processing.cloth.fit import ClothFitError, SwatchMeasurement, chart_gains, fit_swatch, predict_rgb
from processing.cloth.swatch_geometry import SwatchGeometry, swatch_samples
from processing.materials.presets import get_material

TRUTH = {"a_t": 0.08, "a_b": 0.5, "specular": 0.25, "internal": 0.3, "diffuse": 0.4, "colour": "#3060a0"}
TRUTH_SPEC = (f"silk:a_t={TRUTH['a_t']},a_b={TRUTH['a_b']},weft_a_t={TRUTH['a_t']},weft_a_b={TRUTH['a_b']},"
              f"specular={TRUTH['specular']},internal={TRUTH['internal']},diffuse={TRUTH['diffuse']},"
              f"warp_colour={TRUTH['colour']},weft_colour={TRUTH['colour']}")
TRUTH_RGB = [int(TRUTH["colour"][i:i + 2], 16) / 255 for i in (1, 3, 5)]


def _truth_vector():
    return [TRUTH["a_t"], TRUTH["a_b"], TRUTH["specular"], TRUTH["internal"], TRUTH["diffuse"], *TRUTH_RGB]


def test_geometry_rays_are_the_stations_pinhole():
    w = SwatchWorld.swatch("silk", width=32, height=24)
    eye, dirs = w._view()
    g = SwatchGeometry.from_dict(w.geometry())
    jj, ii = np.mgrid[0:24, 0:32]
    np.testing.assert_allclose(g.rays(ii, jj), dirs, atol=1e-12)
    np.testing.assert_allclose(g.camera_frame()[0], eye, atol=1e-9)


def test_white_diffuse_swatch_is_lambertian():
    # closed form: radiance = E cos_i / pi for a white Lambertian swatch, at every table angle
    w = SwatchWorld.swatch("cotton:specular=0,internal=0,diffuse=1,warp_colour=#ffffff,weft_colour=#ffffff",
                           width=32, height=24)
    f = w.frame("object", 37.0)
    e = w.light_spectrum()
    cos_i = np.asarray(w.light_direction) / np.linalg.norm(w.light_direction)
    on = f.labels == 0
    assert on.mean() > 0.2
    # white: the sRGB white's reflectance spectrum is 1, K/S = 0, the Kubelka-Munk reflectance 1
    np.testing.assert_allclose(f.radiance[on], np.broadcast_to(e * cos_i[2] / math.pi, f.radiance[on].shape),
                               rtol=1e-6)


def test_swatch_turns_with_the_table():
    w = SwatchWorld.swatch("satin", width=32, height=24)
    g = SwatchGeometry.from_dict(w.geometry())
    # the warp seen at table angle a is the warp of a swatch placed at weave angle a
    turned = SwatchWorld.swatch("satin", width=32, height=24, weave_angle_deg=30.0)
    np.testing.assert_allclose(w.frame("object", 30.0).radiance[12, 16], turned.frame("object", 0.0).radiance[12, 16],
                               rtol=1e-9)
    s = swatch_samples(g, [0.0, 30.0], [32], [24])
    assert s.tangential[0][0, 0] != pytest.approx(s.tangential[0][1, 0])


def test_chart_gains_recover_a_known_gain():
    import colour

    from processing.camera.response import camera_rgb, camera_sensitivities
    from processing.spectral.spectra import SpectralGrid, light_spectrum, resample

    g = SwatchGeometry()
    grid = SpectralGrid(400, 700, 10)
    refl = np.stack([resample(sd.wavelengths, sd.values, grid) for sd in colour.SDS_COLOURCHECKERS[g.chart].values()])
    pred = camera_rgb(refl / math.pi, light_spectrum("D65", grid), camera_sensitivities(grid, g.camera), grid)
    np.testing.assert_allclose(chart_gains(pred * [2.0, 3.0, 0.5], g), [2.0, 3.0, 0.5], rtol=1e-12)


def _synthetic(outliers: float = 0.0):
    g = SwatchGeometry(width=48, height=36)
    angles = np.arange(0.0, 180.0, 20.0)
    xs, ys = np.meshgrid(np.arange(0, 24, 2), np.arange(0, 18, 2))
    px = np.stack([xs.ravel(), ys.ravel()], 1)
    ok = np.ones(len(px), bool)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        ok &= swatch_samples(g, angles, 2 * px[:, 0] + dx, 2 * px[:, 1] + dy, margin_mm=2.0).inside.all(axis=0)
    px = px[ok]
    rgb = predict_rgb(get_material(TRUTH_SPEC), g, angles, px)
    rng = np.random.default_rng(5)
    rgb = rgb * (1 + 0.003 * rng.normal(size=rgb.shape))
    if outliers:
        bad = rng.random(rgb.shape[:2]) < outliers
        rgb[bad] *= 3.0                              # e.g. glints of loose fibres, dust
    return g, SwatchMeasurement(angles, px, rgb)


def test_robust_fit_ignores_outlier_pixels():
    g, m = _synthetic(outliers=0.05)
    fit = fit_swatch(m, g, yarn="silk")
    np.testing.assert_allclose(list(fit.parameters.values()), _truth_vector(), rtol=0.10)


def test_fit_refuses_data_it_cannot_use():
    from processing.cloth.fit import ClothFitError

    g, m = _synthetic()
    with pytest.raises(ClothFitError, match="black"):
        fit_swatch(SwatchMeasurement(m.angles_deg, m.pixels, np.zeros_like(m.rgb)), g)
    with pytest.raises(ClothFitError, match="at least 3 table angles"):
        fit_swatch(SwatchMeasurement(m.angles_deg[:2], m.pixels, m.rgb[:2]), g)
    with pytest.raises(ClothFitError, match="unknown yarn preset 'wool'"):
        fit_swatch(m, g, yarn="wool")
    with pytest.raises(ClothFitError, match="shape"):
        SwatchMeasurement(m.angles_deg, m.pixels, m.rgb[:, :3])


def test_layer_count_is_chosen_by_the_lowest_cost():
    from processing.cloth.fit import choose_layers

    g, m = _synthetic()                            # the truth has the silk preset's 4 layers
    fit, costs = choose_layers(m, g, yarn="silk", candidates=(1, 4, 8))
    assert fit.fixed["layers"] == 4 and costs[4] < min(costs[1], costs[8])


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from app.workflows.cloth_fit import capture_swatch_session

    return capture_swatch_session(tmp_path_factory.mktemp("swatch") / "s", TRUTH_SPEC, steps=8, width=64, height=48)


def test_kogei_cloth_fit_recovers_the_swatch(session, tmp_path, capsys):
    out = tmp_path / "fit"
    code = main(["cloth", "fit", str(session), "--out", str(out), "--pixels", "64"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "+-" in captured.out and "residual rms" in captured.out
    report = json.loads((out / "cloth-fit.json").read_text())
    got = report["parameters"]
    for name, want in zip(("a_t", "a_b", "specular", "internal", "diffuse", "dye_r", "dye_g", "dye_b"),
                          _truth_vector()):
        assert got[name] == pytest.approx(want, rel=0.10), name
        assert report["sigma"][name] is not None and report["sigma"][name] < 0.1 * max(want, 0.05)
    assert report["relative_residual"] < 0.05
    assert (out / "cloth-fit.png").stat().st_size > 10_000

    # render the fit and the truth at table angles the capture never saw: mean delta E00 <= 1.5
    from processing.spectral.display import delta_e00, spectra_to_xyz

    world = SwatchWorld.swatch(TRUTH_SPEC, width=64, height=48)
    fitted = SwatchWorld.swatch(report["material"], width=64, height=48)
    errors = []
    for angle in (10.0, 55.0, 100.0, 200.0):
        a, b = world.frame("object", angle), fitted.frame("object", angle)
        on = a.labels == 0
        xa = spectra_to_xyz(a.radiance[on], a.grid)
        xb = spectra_to_xyz(b.radiance[on], b.grid)
        white = spectra_to_xyz(a.light / math.pi, a.grid)       # a white diffuser facing the light
        errors.append(delta_e00(xb, xa, white))
    assert float(np.mean(np.concatenate(errors))) <= 1.5


def test_bad_sessions_are_refused_in_one_line(session, tmp_path, capsys):
    from app.capture.runner import CapturePlan
    from app.session import Session

    assert main(["cloth", "fit", str(tmp_path / "nowhere")]) == 2
    assert "session folder not found" in capsys.readouterr().err
    assert main(["cloth", "fit", str(session), "--layers", "many"]) == 2
    assert "--layers must be a whole number" in capsys.readouterr().err
    Session.create(tmp_path / "scan", plan=CapturePlan("scan", steps=4, passes=1).to_dict()).close()
    assert main(["cloth", "fit", str(tmp_path / "scan")]) == 2
    assert "not a swatch capture" in capsys.readouterr().err
    assert main(["cloth", "fit", str(session), "--geometry", str(tmp_path / "none.json")]) == 2
    assert "swatch geometry not found" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"width": 64, "height": 48, "lens": 50}))
    assert main(["cloth", "fit", str(session), "--geometry", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "unknown swatch geometry key(s) lens" in err and "Traceback" not in err


def test_demo_cloth_scene_writes_an_image(tmp_path):
    from PIL import Image

    from app.workflows.cloth_scene import render_cloth_scene

    path = render_cloth_scene(tmp_path, "draft", (32, 24))
    assert path.name == "cloth-tamamushi.png"
    assert np.asarray(Image.open(path)).shape[:2] == (24, 32)


def test_swatch_capture_through_the_fake_gphoto2(session, tmp_path):
    # the fake gphoto2 rebuilds the swatch world from its configuration file: its frames must be the
    # swatch (not the station's default object), equal to the hot-folder frames up to sensor noise and to
    # the cloth model's prediction for the world's known parameters
    from app.workflows.cloth_fit import capture_swatch_session, load_swatch_session

    shot = capture_swatch_session(tmp_path / "g", TRUTH_SPEC, steps=8, width=64, height=48, camera="gphoto2")
    via_gphoto2 = load_swatch_session(shot, max_pixels=64)
    via_folder = load_swatch_session(session, max_pixels=64)
    m, ref = via_gphoto2.measurement, via_folder.measurement
    assert m.angles_deg.tolist() == ref.angles_deg.tolist() and m.pixels.tolist() == ref.pixels.tolist()
    np.testing.assert_allclose(m.rgb.mean(axis=1), ref.rgb.mean(axis=1), rtol=0.02)
    truth = predict_rgb(get_material(TRUTH_SPEC), via_gphoto2.geometry, m.angles_deg, m.pixels)
    np.testing.assert_allclose(m.rgb.mean(axis=1), truth.mean(axis=1), rtol=0.03)
    # pixel by pixel too: the highlight's place in the frame is the model's (the swatch varies across the
    # view by far more than the noise)
    spread = truth.sum(axis=2)
    assert spread.max() > 1.5 * spread.min()
    assert np.median(np.abs(m.rgb / truth - 1.0)) < 0.03


COTTON = ("cotton:a_t=0.3,a_b=0.6,weft_a_t=0.3,weft_a_b=0.6,specular=0.08,internal=0.15,diffuse=0.7,"
          "warp_colour=#c08040,weft_colour=#c08040")
SECOND_LIGHT = (-0.22, -0.6, 0.77)        # the lamp moved to the camera's side for pass 2


def test_swatch_capture_with_the_lamp_moved_between_passes(tmp_path):
    # two passes, each under its own light: the decoded responses of each pass are the world's cloth model
    # under that pass's light (and not under the other's), calibrated by that pass's chart frame
    from app.workflows.cloth_fit import capture_swatch_session, load_swatch_session

    first = tuple(SwatchWorld.swatch("cotton", width=64, height=48).light_direction)
    shot = capture_swatch_session(tmp_path / "s", COTTON, steps=4, width=64, height=48, lights=[first, SECOND_LIGHT])
    data = load_swatch_session(shot, max_pixels=48)
    m, g = data.measurement, data.geometry
    assert g.passes == 2 and m.passes.tolist() == [1] * 4 + [2] * 4
    assert np.asarray(data.gains).shape == (2, 3)
    truth = predict_rgb(get_material(COTTON), g, m.angles_deg, m.pixels, m.cfa_pattern, passes=m.passes)
    assert np.median(np.abs(m.rgb / truth - 1.0)) < 0.03
    wrong = predict_rgb(get_material(COTTON), g, m.angles_deg, m.pixels, m.cfa_pattern)      # pass 1's light only
    assert np.median(np.abs(m.rgb[4:] / wrong[4:] - 1.0)) > 0.06
    with pytest.raises(ClothFitError, match="1 light direction"):
        fit_swatch(m, g.for_pass(1), yarn="cotton")


def test_second_light_separates_the_broad_lobes_of_cotton():
    # the parameters' standard deviations from the Fisher information (J^T J)^-1 of the model at the truth,
    # noise 1.8 % per value (the simulated captures' relative residual): from one light the specular,
    # internal and diffuse weights of cotton trade against each other; a second light separates them
    from processing.cloth.fit import fit_material

    g = SwatchGeometry.from_dict(SwatchWorld.swatch("cotton", width=64, height=48).geometry())
    angles = np.arange(0.0, 360.0, 45.0)
    xs, ys = np.meshgrid(np.arange(10, 22, 2), np.arange(8, 16, 2))
    px = np.stack([xs.ravel(), ys.ravel()], 1)
    fixed = {"warp_kind": "spun", "weft_kind": "spun", "warp_fraction": 0.5, "layers": 4, "rounding": 0.7,
             "n": 1.55, "scattering": 0.25}
    x0 = np.array([0.3, 0.6, 0.08, 0.15, 0.7, 0xc0 / 255, 0x80 / 255, 0x40 / 255])

    def sigma(geometry, passes):
        a = np.tile(angles, len(set(passes)))
        p = np.repeat(sorted(set(passes)), angles.size)

        def f(x):
            return predict_rgb(fit_material(x, fixed), geometry, a, px, passes=p).ravel()

        y = f(x0)
        jac = np.stack([(f(x0 + dx) - f(x0 - dx)) / (2 * dx[k]) for k, dx in enumerate(np.diag(1e-4 * x0))], 1)
        jn = jac / (0.018 * np.abs(y))[:, None]
        return np.sqrt(np.diag(np.linalg.inv(jn.T @ jn))) / x0

    one = sigma(g, [1])
    two = sigma(dataclasses.replace(g, pass_light_directions=(SECOND_LIGHT,)), [1, 2])
    weights = slice(2, 5)
    assert np.all(one[weights] > 0.15)                  # one light: the weights are not determined to 10 %
    assert np.all(two[weights] < 0.5 * one[weights])    # a second light at least halves every weight's spread


def test_swatch_pass_is_calibrated_by_several_chart_exposures(tmp_path):
    # each pass opens with four chart frames, each its own capture and its own exposure (own sensor noise);
    # the noise-free gain is the same in every channel (tests/integration/test_swatch_chain.py), so the calibrated
    # gains' channel-to-channel spread is their noise: a standard deviation of 0.10-0.18 % per channel from
    # one chart frame at 64 x 48, half that from four
    from app.errors import UsageError
    from app.session import Session
    from app.workflows.cloth_fit import capture_swatch_session, load_swatch_session

    shot = capture_swatch_session(tmp_path / "s", COTTON, steps=3, width=64, height=48, seed=5, chart_frames=4)
    charts = {k: r for k, r in Session.read(shot)["captures"].items() if r["kind"] == "chart"}
    assert sorted(charts) == ["p01/chart/00", "p01/chart/01", "p01/chart/02", "p01/chart/03"]
    assert len({r["sha256"] for r in charts.values()}) == 4
    assert [r["kind"] for r in Session.read(shot)["captures"].values()].count("frame") == 3
    gains = np.asarray(load_swatch_session(shot, max_pixels=48).gains)
    # this seed: within 0.025 % from four frames, 0.078 % (green) from the first frame alone
    assert np.all(np.abs(gains / gains.mean() - 1.0) < 0.0006)
    with pytest.raises(UsageError, match="chart_frames"):
        capture_swatch_session(tmp_path / "t", COTTON, steps=2, width=64, height=48, chart_frames=0)


def test_swatch_capture_refuses_a_used_folder_and_leaves_no_station_behind(tmp_path, monkeypatch):
    # the station's ports and hot folder live in a temporary folder: it must be gone after a capture and after a
    # refusal, and a folder holding anything is never emptied to make room for a session
    import tempfile

    from app.errors import UsageError
    from app.workflows.cloth_fit import capture_swatch_session

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    used = tmp_path / "used"
    used.mkdir()
    (used / "notes.txt").write_text("keep me")
    with pytest.raises(UsageError, match="not an empty folder"):
        capture_swatch_session(used, COTTON, steps=2, width=64, height=48)
    assert (used / "notes.txt").read_text() == "keep me"
    with pytest.raises(UsageError, match="chart_frames"):
        capture_swatch_session(tmp_path / "t", COTTON, steps=2, width=64, height=48, chart_frames=0)
    with pytest.raises(UsageError, match="lights"):
        capture_swatch_session(tmp_path / "u", COTTON, steps=2, width=64, height=48, lights=[(0.0, 0.0, -1.0)])
    shot = capture_swatch_session(tmp_path / "s", COTTON, steps=2, width=64, height=48, chart_frames=1)
    assert (shot / "swatch.json").is_file()
    assert list(scratch.iterdir()) == []
