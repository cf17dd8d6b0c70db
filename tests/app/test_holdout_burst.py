"""Bursts at the held-out table angles: captured through the simulated station, averaged by the validation.

A scan plan with ``holdout_burst = N`` shoots N frames at every held-out camera angle; the
simulated camera gives each its own sensor noise (the physics reference: its noise model, variance
``mu_e / g^2 + (read_e / g)^2 + 1/12`` DN per photosite), and ``kogei fit-materials`` compares each
held-out rendering with the linear mean of its burst, the noise floor computed for N frames.
"""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, run_capture
from app.session import Session
from mocks.camera_sim import SensorModel
from mocks.station import SimulatedStation
from mocks.world import World
from tests.integration.object_session import build_object_session


def _mosaic(root, rec) -> np.ndarray:
    with rawpy.imread(str(root / rec["file"])) as raw:
        return raw.raw_image_visible.astype(np.float64)


def test_a_captured_burst_has_independent_noise_per_shot(tmp_path):
    world = World.hawk(4000, width=240, height=160, chart_layout="classic24")
    plan = CapturePlan("scan", steps=4, passes=1, camera_angles_deg=(0.0, 90.0, 180.0, 270.0), chart=False,
                       holdout_burst=3)
    with SimulatedStation(world, root=tmp_path / "station", seed=4) as st:
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)},
                  "camera": {"kind": "gphoto2", "executable": str(st.gphoto2_path)}}
        s = Session.create(tmp_path / "s", plan=plan.to_dict(), settings={"unattended": True,
                                                                         "device_config": config})
        try:
            run_capture(s, plan, build_devices(config, s.root),
                        CaptureHooks(before_pass=lambda p, n: st.place(p), before_frame=st.before_frame))
        finally:
            s.close()
    manifest = Session.read(tmp_path / "s")
    caps = manifest["captures"]
    assert manifest["plan"]["holdout_burst"] == 3
    burst = {c: r for c, r in caps.items() if r.get("kind") == "burst"}
    assert sorted(burst) == ["p01/frame/02/burst/01", "p01/frame/02/burst/02"]      # 180 deg: the held-out angle
    assert all(r["burst_of"] == "p01/frame/02" and r["angle_deg"] == 180.0 for r in burst.values())
    first = _mosaic(tmp_path / "s", caps["p01/frame/02"])
    shots = [first] + [_mosaic(tmp_path / "s", burst[c]) for c in sorted(burst)]
    sensor = SensorModel()
    g, black, white = sensor.gain_e_per_dn, sensor.black_level, sensor.white_level
    for a, b in ((shots[0], shots[1]), (shots[1], shots[2])):
        ok = (a < white) & (b < white)
        mean_dn = 0.5 * (a + b)[ok] - black
        expected = 2.0 * np.mean(mean_dn / g + (sensor.read_noise_e / g) ** 2 + 1.0 / 12.0)
        # 38 400 photosites: the mean square's relative standard error is about 1 %; 5 % tolerance
        assert np.mean((a - b)[ok] ** 2) == pytest.approx(expected, rel=0.05)
    # the burst is the same view: its mean equals the first frame's up to the noise
    assert abs(np.mean(shots[1]) - np.mean(first)) < 0.05 * np.sqrt(expected)


@pytest.fixture(scope="module")
def validated(tmp_path_factory):
    """The same one-placement hawk session (12 angles, 3 held out) without and with a burst of 4, measured."""
    from app.workflows.object_materials import measure_object
    from app.workflows.posed_frames import project_session

    world = World.hawk(4000, width=240, height=160, chart_layout="classic24")
    docs = {}
    for n in (1, 4):
        root = tmp_path_factory.mktemp(f"burst{n}") / "session"
        build_object_session(root, world, np.arange(0.0, 360.0, 30.0), holdout_burst=n)
        project_session(root)
        lines: list[str] = []
        docs[n] = (root, measure_object(root, message=lines.append), lines)
    return docs


def test_burst_frames_are_not_fitted(validated):
    for n in (1, 4):
        _, doc, _ = validated[n]
        names = set(doc["frames"]["fit"]) | set(doc["frames"]["held_out"])
        assert not any("/burst/" in c for c in names)
    assert validated[1][1]["frames"] == validated[4][1]["frames"]
    assert [r["material"] for r in validated[1][1]["regions"]] == [r["material"] for r in validated[4][1]["regions"]]


def test_a_burst_validates_with_the_lower_floor(validated):
    single, burst = validated[1][1]["validation"], validated[4][1]["validation"]
    assert single["frames_averaged"] == 1 and burst["frames_averaged"] == 4
    assert any("burst of 4" in line for line in validated[4][2])
    # the floor of 4 frames: the noise's standard deviation halves, and near a small ΔE00 the mean follows it
    # (measured 1.04 against 1.98); 15 % allows CIEDE2000's non-linearity
    assert burst["noise_floor_mean_de2000"] == pytest.approx(0.5 * single["noise_floor_mean_de2000"], rel=0.15)
    # the photos are cleaner, so the measured materials' error falls too (measured 2.12 against 2.99)
    assert burst["mean_de2000"] < 0.85 * single["mean_de2000"]
    assert burst["pooled"]["noise_floor_mean_de2000"] < 0.65 * single["pooled"]["noise_floor_mean_de2000"]


def test_burst_mean_keeps_a_pixel_any_shot_clipped_out_of_the_comparison():
    from app.workflows.object_materials import _BurstMeans

    clip = np.array([1.0, 1.0, 1.0])
    shots = [np.full((2, 2, 3), 0.2, np.float32), np.full((2, 2, 3), 0.4, np.float32)]
    shots[1][0, 0, 1] = 1.0                              # one shot clipped one channel of one pixel
    mean = _BurstMeans(shots[:1], shots, 2, clip)[0]
    assert mean[0, 0, 1] >= 1.0                          # still at the clip level: the comparison drops it
    assert np.allclose(np.delete(mean.reshape(-1), 1), 0.3)   # elsewhere the linear mean
