"""CIEDE2000 between two images against Sharma et al. (2005)'s published test pairs, masks and bad inputs.

Truth: the CIEDE2000 test data of Sharma, Wu and Dalal (2005), Color Res. Appl.
30(1), 21-30, doi:10.1002/col.20070 (Table 1: L*a*b* pairs and their
Delta E_00 to 4 decimals); the ColorChecker's XYZ from colour-science for the
fitted camera matrix.
"""

from __future__ import annotations

import colour
import numpy as np
import pytest

from processing.appearance.photo_comparison import (
    PhotoComparisonError,
    camera_to_xyz_matrix,
    compare_images,
    signal_to_lab,
)
from processing.camera.response import camera_sensitivities
from processing.spectral.spectra import SpectralGrid, light_spectrum

# Sharma et al. (2005) Table 1, pairs 1, 2, 3, 7, 17, 18, 19, 20, 25-34: Lab 1, Lab 2, Delta E_00
SHARMA = [
    ((50.0000, 2.6772, -79.7751), (50.0000, 0.0000, -82.7485), 2.0425),
    ((50.0000, 3.1571, -77.2803), (50.0000, 0.0000, -82.7485), 2.8615),
    ((50.0000, 2.8361, -74.0200), (50.0000, 0.0000, -82.7485), 3.4412),
    ((50.0000, 0.0000, 0.0000), (50.0000, -1.0000, 2.0000), 2.3669),
    ((50.0000, 2.5000, 0.0000), (73.0000, 25.0000, -18.0000), 27.1492),
    ((50.0000, 2.5000, 0.0000), (61.0000, -5.0000, 29.0000), 22.8977),
    ((50.0000, 2.5000, 0.0000), (56.0000, -27.0000, -3.0000), 31.9030),
    ((50.0000, 2.5000, 0.0000), (58.0000, 24.0000, 15.0000), 19.4535),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
    ((63.0109, -31.0961, -5.8663), (62.8187, -29.7946, -4.0864), 1.2630),
    ((61.2901, 3.7196, -5.3901), (61.4292, 2.2480, -4.9620), 1.8731),
    ((35.0831, -44.1164, 3.7933), (35.0232, -40.0716, 1.5901), 1.8645),
    ((22.7233, 20.0904, -46.6940), (23.0331, 14.9730, -42.5619), 2.0373),
    ((36.4612, 47.8580, 18.3852), (36.2715, 50.5065, 21.2231), 1.4146),
    ((90.8027, -2.0831, 1.4410), (91.1528, -1.6435, 0.0447), 1.4441),
    ((90.9257, -0.5406, -0.9208), (88.6381, -0.8985, -0.7239), 1.5381),
    ((6.7747, -0.2908, -2.4247), (5.8714, -0.0985, -2.2286), 0.6377),
    ((2.0776, 0.0795, -1.1350), (0.9033, -0.0636, -0.5514), 0.9082),
]
D65_XYZ = np.array([0.95047, 1.0, 1.08883])


def _signal_of_lab(lab, camera_to_xyz, white_xyz):
    """Camera RGB whose Lab (through the matrix, relative to white_xyz) is ``lab`` (inverse path, colour-science)."""
    xyz = colour.Lab_to_XYZ(np.asarray(lab, float), illuminant=colour.XYZ_to_xy(white_xyz / white_xyz[1]))
    return xyz * white_xyz[1] @ np.linalg.inv(camera_to_xyz).T


@pytest.mark.parametrize("matrix", [np.eye(3), np.array([[0.6, 0.3, 0.1], [0.25, 0.7, 0.05], [0.02, 0.1, 0.95]])],
                         ids=["identity", "mixing"])
def test_sharma_pairs_give_their_published_ciede2000(matrix):
    a = _signal_of_lab([p[0] for p in SHARMA], matrix, D65_XYZ)
    b = _signal_of_lab([p[1] for p in SHARMA], matrix, D65_XYZ)
    inside = (a.min(axis=1) >= 0) & (b.min(axis=1) >= 0)     # pairs the camera can record (RGB >= 0)
    assert inside.sum() >= 12
    pairs, n = [p for p, ok in zip(SHARMA, inside, strict=True) if ok], int(inside.sum())
    photo = np.zeros((5, n + 4, 3))
    rend = np.zeros((5, n + 4, 3))
    photo[2, 2:n + 2], rend[2, 2:n + 2] = a[inside], b[inside]
    mask = np.zeros((5, n + 4), bool)
    mask[2, 2:n + 2] = True
    res = compare_images(photo, rend, mask, matrix, white_xyz=D65_XYZ, edge_margin_px=0)
    expected = np.array([p[2] for p in pairs])
    np.testing.assert_allclose(res.error_map[2, 2:n + 2], expected, atol=1e-4)
    assert res.n_pixels == n
    assert res.mean_de2000 == pytest.approx(expected.mean(), abs=1e-4)
    assert res.p95_de2000 == pytest.approx(np.percentile(expected, 95), abs=1e-4)
    assert res.median == pytest.approx(np.median(expected), abs=1e-4)
    assert np.isnan(res.error_map[~mask]).all()


def test_identical_images_give_zero_and_the_white_diffuser_is_lab_100():
    rng = np.random.default_rng(0)
    img = rng.uniform(0.0, 1.5, (20, 30, 3)).astype(np.float32)
    m = np.array([[0.6, 0.3, 0.1], [0.25, 0.7, 0.05], [0.02, 0.1, 0.95]])
    res = compare_images(img, img.copy(), np.ones((20, 30), bool), m)
    assert res.mean_de2000 == 0.0 and res.p95_de2000 == 0.0 and res.n_pixels == 16 * 26
    np.testing.assert_allclose(signal_to_lab(np.ones(3), m), [100.0, 0.0, 0.0], atol=1e-9)


def test_mask_and_edge_margin_are_honoured():
    img = np.full((20, 20, 3), 0.4)
    other = img.copy()
    other[:, :10] = 0.1                      # differs only in the left half
    mask = np.zeros((20, 20), bool)
    mask[4:16, 10:18] = True                 # the right half only
    res = compare_images(img, other, mask, np.eye(3), edge_margin_px=2)
    assert res.mean_de2000 == 0.0 and res.n_pixels == 8 * 4
    assert np.isfinite(res.error_map).sum() == 32 and np.isfinite(res.error_map[6:14, 12:16]).all()
    mask[4:16, 2:10] = True
    assert compare_images(img, other, mask, np.eye(3), edge_margin_px=2).mean_de2000 > 5.0


def test_camera_matrix_maps_the_chart_to_its_xyz():
    grid = SpectralGrid(400, 700, 10)
    s, e = camera_sensitivities(grid), light_spectrum("D65", grid)
    m = camera_to_xyz_matrix(s, e, grid)
    # truth from colour-science: the ColorChecker's XYZ under D65 (white Y = 1), and the camera's patch signals
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    shape = colour.SpectralShape(400, 700, 10)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(shape)
    xyz = np.stack([colour.sd_to_XYZ(sd.copy().align(shape), cmfs, ill, method="Integration")
                    for sd in sds.values()]) / 100.0
    refl = np.stack([sd.copy().align(shape).values for sd in sds.values()])
    rgb = (refl * e) @ s / (e @ s)
    lab_true = colour.XYZ_to_Lab(xyz, colour.XYZ_to_xy(m @ np.ones(3)))
    lab_fit = signal_to_lab(rgb, m)
    de = colour.delta_E(lab_true, lab_fit, method="CIE 2000")
    assert np.median(de) < 2.0 and de.max() < 6.0          # a 3 x 3 matrix of a real camera is not exact
    np.testing.assert_allclose(m @ np.ones(3) / (m @ np.ones(3))[1], colour.xy_to_XYZ(colour.XYZ_to_xy(xyz[18])),
                               atol=0.02)                   # the white diffuser's chromaticity ~ the white patch's


def test_bad_inputs_give_one_line_errors():
    img = np.full((8, 8, 3), 0.3)
    mask = np.ones((8, 8), bool)
    bad = img.copy()
    bad[4, 4, 1] = np.nan
    for args, kw, match in [
        ((bad, img, mask, np.eye(3)), {}, "photo_signal.*NaN"),
        ((img, bad, mask, np.eye(3)), {}, "render_signal.*NaN"),
        ((img - 0.5, img, mask, np.eye(3)), {}, "photo_signal.*below"),
        ((img, img[:4], mask, np.eye(3)), {}, "render_signal"),
        ((img, img, mask.astype(int), np.eye(3)), {}, "mask"),
        ((img, img, mask, np.zeros((3, 3))), {}, "camera_to_xyz"),
        ((img, img, mask, np.eye(3)), {"edge_margin_px": 4}, "no object pixel"),
        ((img, img, mask, np.eye(3)), {"white_xyz": [1.0, -1.0, 1.0]}, "white_xyz"),
    ]:
        with pytest.raises(PhotoComparisonError, match=match) as err:
            compare_images(*args, **kw)
        assert "\n" not in str(err.value)
    bad_outside = img.copy()
    bad_outside[0, 0] = np.nan                     # outside the eroded mask: ignored
    assert compare_images(bad_outside, img, mask, np.eye(3)).mean_de2000 == 0.0


def test_pooled_blocks_are_the_means_of_whole_blocks_inside_the_mask():
    from processing.appearance.photo_comparison import pool_blocks

    img = np.random.default_rng(0).random((9, 10, 3))
    mask = np.ones((9, 10), bool)
    mask[4, 7] = False
    pooled, kept = pool_blocks(img, mask, 3)
    assert pooled.shape == (3, 3, 3) and kept.shape == (3, 3)          # the 10th column is past the last block
    np.testing.assert_allclose(pooled[1, 2], img[3:6, 6:9].reshape(-1, 3).mean(axis=0))
    assert kept.sum() == 8 and not kept[1, 2]                         # the block with the masked pixel is left out
    with pytest.raises(PhotoComparisonError, match="pool_px"):
        pool_blocks(img, mask, 0)


def test_independent_noise_falls_by_the_block_side_when_pooled():
    # Noise of standard deviation sd per pixel averages over s x s pixels to sd / s (independent draws):
    # with 64 x 64 blocks per scale the sample standard deviation is within +-10 % at 3 sigma.
    from processing.appearance.photo_comparison import pool_blocks

    rng = np.random.default_rng(1)
    for s in (2, 4):
        noise = 0.01 * rng.standard_normal((64 * s, 64 * s, 3))
        pooled, kept = pool_blocks(noise, np.ones(noise.shape[:2], bool), s)
        assert kept.all()
        assert np.std(pooled) == pytest.approx(0.01 / s, rel=0.1)


def test_pooled_comparison_of_identical_images_is_zero_and_maps_each_block():
    img = np.full((16, 16, 3), 0.2)
    res = compare_images(img, img, np.ones((16, 16), bool), np.eye(3), white_xyz=D65_XYZ, edge_margin_px=2,
                         pool_px=4)
    # eroding 2 px leaves rows/columns 2..13: only the four central 4 x 4 blocks lie wholly inside
    assert res.mean_de2000 == 0.0 and res.n_pixels == 4
    assert np.isfinite(res.error_map).sum() == 4 * 16
    with pytest.raises(PhotoComparisonError, match="no 8 x 8 px block"):
        compare_images(img, img, np.ones((16, 16), bool), np.eye(3), edge_margin_px=2, pool_px=8)


def _flat_photos(seeds, level=0.02, size=128):
    """Flat grey frames from the simulated camera (its own shot and read noise per seed), bilinearly
    demosaicked as the photos are; and the noiseless photo from the expected photosite values."""
    from mocks.camera_sim import SensorModel, simulate_raw
    from processing.camera.raw_decode import bilinear_demosaic

    g = SpectralGrid(400, 700, 10)
    rad = np.full((size, size, g.size), level)
    sensor = SensorModel()
    idx = np.array([0, 1, 1, 2])
    none = np.zeros((size, size), bool)
    out, raw = [], None
    for s in seeds:
        raw = simulate_raw(rad, g, np.ones(g.size), exposure_s=0.002, seed=s)
        values = (raw.bayer.astype(np.float64) - raw.black_level) / (raw.white_level - raw.black_level)
        out.append(bilinear_demosaic(values.astype(np.float32), idx, none, none)[0].astype(np.float64))
    mean = raw.mean_electrons / sensor.gain_e_per_dn / (raw.white_level - raw.black_level)
    clean = bilinear_demosaic(mean.astype(np.float32), idx, none, none)[0].astype(np.float64)
    span = raw.white_level - raw.black_level
    ab = (((sensor.read_noise_e / sensor.gain_e_per_dn) ** 2 + 1 / 12) / span ** 2, 1.0 / (sensor.gain_e_per_dn * span))
    return out, clean, ab


def test_averaging_independent_frames_lowers_the_noise_as_one_over_root_n():
    # Truth from the simulated camera: 16 frames of a flat grey, each with its own seed.  The noise of the
    # mean of N frames is the single frame's / sqrt(N); over ~15 000 demosaicked pixels (neighbours correlated
    # by the interpolation, so fewer independent samples) the sample ratio is within +-8 %.
    frames, clean, _ = _flat_photos(range(16))
    inner = (slice(4, -4), slice(4, -4))
    sd1 = np.std(frames[0][inner] - clean[inner])
    for n in (4, 16):
        sdn = np.std(np.mean(frames[:n], axis=0)[inner] - clean[inner])
        assert sdn / sd1 == pytest.approx(1 / np.sqrt(n), rel=0.08)
    # the same seed gives the same frame: the noise is the seed's, not the clock's
    again, _, _ = _flat_photos([0])
    np.testing.assert_array_equal(again[0], frames[0])


def test_the_demosaicked_noise_floor_matches_the_simulated_cameras_photos():
    # The floor's model (noise a + b * signal drawn on the RGGB mosaic, demosaicked bilinearly) against the
    # simulated camera's own frames compared with its noiseless photo: the same CIEDE2000 within 10 % for one
    # frame and for the mean of 16; independent noise per pixel (no mosaic) overstates it.
    from processing.appearance.photo_comparison import noise_floor

    frames, clean, ab = _flat_photos(range(16))
    m = camera_to_xyz_matrix(camera_sensitivities(SpectralGrid(400, 700, 10)), np.ones(31), SpectralGrid(400, 700, 10))
    white = clean.mean(axis=(0, 1)) / 0.2            # the grey reads 0.2 of the white: chart-normalise to that
    ok = np.ones(clean.shape[:2], bool)
    scaled_ab = (ab[0] / white.mean() ** 2, ab[1] / white.mean())
    for n in (1, 16):
        photo = np.mean(frames[:n], axis=0) / white
        real = compare_images(photo, clean / white, ok, m, edge_margin_px=4).mean_de2000
        model = noise_floor(clean / white, ok, m, scaled_ab, edge_margin_px=4, cfa="RGGB", frames=n).mean_de2000
        independent = noise_floor(clean / white, ok, m, scaled_ab, edge_margin_px=4, frames=n).mean_de2000
        assert model == pytest.approx(real, rel=0.1)
        assert independent > 1.2 * real
