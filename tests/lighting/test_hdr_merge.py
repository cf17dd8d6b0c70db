"""HDR merge of simulated exposure brackets against the simulated camera's truth, and bad brackets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import maximum_filter, minimum_filter

from mocks.camera_sim import SensorModel, channel_signal, simulate_raw, write_raw
from mocks.probe_world import PROBE_F_NUMBER, ProbeWorld, write_probe_shots
from processing.lighting.hdr_merge import HdrMergeError, exposure_scale, merge_brackets


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    world = ProbeWorld.probe(20.0, width=240, height=160)
    folder = tmp_path_factory.mktemp("brackets")
    chart, paths = write_probe_shots(world, folder)
    return world, world.frame("object"), paths


def _predicted_scale() -> float:
    """HDR value per unit camera signal: electrons per signal-second over DN range, times k N^2 / S."""
    sensor = SensorModel()
    dn_range = sensor.white_level - sensor.black_level
    return sensor.quantum_scale / sensor.gain_e_per_dn / dn_range * exposure_scale(1.0, PROBE_F_NUMBER, sensor.iso)


def test_merge_recovers_the_linear_truth_signal(shots):
    world, frame, paths = shots
    hdr = merge_brackets(paths)
    truth = channel_signal(frame.radiance, frame.grid) * _predicted_scale()
    # flat pixels only: the truth varies by < 1 % over 5 x 5 (demosaicking blurs edges, which is not the merge's error)
    g = truth[..., 1]
    flat = (maximum_filter(g, 5) <= 1.01 * minimum_filter(g, 5)) & ~hdr.saturated
    err = hdr.rgb[flat] / truth[flat] - 1.0
    # 7 brackets 2 EV apart put every pixel between 20 % and 80 % of the well in some frame: photon noise
    # there is <= 1 / sqrt(0.2 * 31566 e) = 1.3 % per photosite; the median is unbiased to the 0.1 % that
    # quantisation and the black level leave
    assert abs(float(np.median(err))) < 2e-3
    assert float(np.percentile(np.abs(err), 50)) < 0.01
    assert float(np.percentile(np.abs(err), 99)) < 0.05
    # the dynamic range spans the lamps and the dark walls: over 7 stops among flat pixels
    assert truth[flat].max() / truth[flat].min() > 100


def test_the_order_of_the_frames_does_not_matter(shots):
    _, _, paths = shots
    a = merge_brackets(paths)
    b = merge_brackets(paths[::-1])
    assert np.allclose(a.rgb, b.rgb, rtol=1e-5, atol=0)


def test_frames_saturated_everywhere_add_nothing_and_are_noted(shots):
    _, _, paths = shots
    hdr = merge_brackets(paths)
    assert any("probe-7.dng" in n for n in hdr.notes)
    short = merge_brackets(paths[:5])
    ok = ~hdr.saturated
    assert np.allclose(hdr.rgb[ok], short.rgb[ok], rtol=1e-3)


def test_brackets_saturated_everywhere_are_refused(tmp_path):
    world = ProbeWorld.probe(20.0, width=96, height=64)
    _, paths = write_probe_shots(world, tmp_path, times_s=(0.5, 2.0), chart_time_s=None)
    with pytest.raises(HdrMergeError) as exc:
        merge_brackets(paths)
    text = str(exc.value)
    assert "\n" not in text and "probe-1.dng" in text and "saturated" in text


def _flat_dng(path, exposure_time, f_number, shape=(32, 32)):
    frame = simulate_raw(np.full(shape + (31,), 0.01), ProbeWorld.probe(20.0, width=96, height=64).grid,
                         np.ones(31), exposure_s=0.01)
    frame.exposure_time = exposure_time
    frame.f_number = f_number
    return write_raw(path, frame)


def test_missing_exposure_time_names_the_file(tmp_path):
    good = _flat_dng(tmp_path / "a.dng", 0.01, 8.0)
    bad = _flat_dng(tmp_path / "b.dng", None, 8.0)
    with pytest.raises(HdrMergeError) as exc:
        merge_brackets([good, bad])
    text = str(exc.value)
    assert "\n" not in text and "b.dng" in text and "exposure time" in text


def test_missing_aperture_names_the_file_unless_given(tmp_path):
    bad = _flat_dng(tmp_path / "c.dng", 0.01, None)
    with pytest.raises(HdrMergeError, match=r"c\.dng.*aperture"):
        merge_brackets([bad])
    assert merge_brackets([bad], f_number=8.0).settings[0] == (0.01, 8.0, 100.0)


def test_frames_of_different_sizes_are_refused(tmp_path):
    a = _flat_dng(tmp_path / "a.dng", 0.01, 8.0)
    b = _flat_dng(tmp_path / "b.dng", 0.02, 8.0, shape=(32, 48))
    with pytest.raises(HdrMergeError, match=r"b\.dng.*one view"):
        merge_brackets([a, b])


def test_no_frames_is_refused():
    with pytest.raises(HdrMergeError, match="no bracket"):
        merge_brackets([])
