"""Environment maps: frame and layout, lookups, rotation, spectra, files in and out, and bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from processing.lighting.environment_map import (
    HEADER_KEY,
    EnvironmentMap,
    EnvironmentMapError,
    direction_pixels,
    pixel_directions,
    read_environment,
    srgb_basis,
    uniform_environment,
    write_environment,
)
from processing.spectral.display import spectra_to_xyz
from processing.spectral.spectra import REFERENCE_GRID, SpectralGrid, light_spectrum


def _random_map(height: int = 8, seed: int = 0) -> EnvironmentMap:
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.0, 5.0, (height, 2 * height, 3)).astype(np.float32)
    return EnvironmentMap(c, srgb_basis(), REFERENCE_GRID, source="random")


def _write_exr(path, rgb: np.ndarray, header_extra: dict | None = None) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **(header_extra or {})}
    with OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}) as f:
        f.write(str(path))


# ------------------------------------------------------------------------------------------- frame

def test_pixel_directions_are_unit_and_follow_the_documented_layout():
    d = pixel_directions(4, 8)
    assert np.allclose(np.linalg.norm(d, axis=-1), 1.0)
    # row 0 is nearest the zenith, the last row nearest the nadir
    assert d[0, :, 2].min() > 0.9 and d[-1, :, 2].max() < -0.9
    # azimuth from +x toward +y: column W/4 - 1/2 (pixel 1 of 8, centre phi = 3 pi / 8) points between +x and +y
    assert d[1, 1, 0] > 0 and d[1, 1, 1] > 0
    assert d[1, 5, 0] < 0 and d[1, 5, 1] < 0


def test_direction_pixels_inverts_pixel_directions_everywhere():
    h, w = 6, 12
    for rot in (0.0, 37.0, -200.0):
        r, c = direction_pixels(pixel_directions(h, w, rot), h, w, rot)
        rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        assert np.allclose(r, rows, atol=1e-9)
        assert np.allclose(c, cols, atol=1e-9)


def test_solid_angles_sum_to_the_sphere():
    env = uniform_environment(1.0, height=32)
    assert math.isclose(float(env.solid_angles().sum()) * env.width, 4 * math.pi, rel_tol=1e-12)


# ------------------------------------------------------------------------------------------- lookups

def test_lookup_at_pixel_centres_returns_the_pixel():
    env = _random_map()
    got = env.lookup(env.directions())
    assert np.allclose(got, env.coefficients, atol=1e-5)


def test_lookup_wraps_in_azimuth():
    # a direction just past the last column's centre interpolates with column 0, not with column W - 2
    c = np.zeros((4, 8, 3), np.float32)
    c[:, 0] = 1.0
    env = EnvironmentMap(c, srgb_basis(), source="seam")
    phi = 2 * math.pi * (7.75 / 8)                       # a quarter of the way from column 7 to column 0
    theta = math.pi * 1.5 / 4
    d = [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
    assert np.allclose(env.lookup([d])[0], 0.25, atol=1e-6)


def test_rotation_turns_the_map_counter_clockwise_about_z():
    env = _random_map(seed=1)
    turned = env.with_(rotation_deg=90.0)
    d = pixel_directions(env.height, env.width)[2:6].reshape(-1, 3)
    # a direction turned by +90 deg about z sees in the turned map what the original shows at d
    rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.allclose(turned.lookup(d @ rz.T), env.lookup(d), atol=1e-5)


def test_intensity_scales_lookups_and_luminance():
    env = _random_map(seed=2)
    d = env.directions()[3]
    assert np.allclose(env.with_(intensity=2.5).lookup(d), 2.5 * env.lookup(d), rtol=1e-6)
    assert np.allclose(env.with_(intensity=2.5).pixel_luminance(), 2.5 * env.pixel_luminance(), rtol=1e-9)


def test_uniform_environment_lights_a_white_diffuser_to_its_own_luminance():
    # a constant radiance L all round gives irradiance pi L on an up-facing surface: a white Lambertian
    # surface then has radiance L, whatever the map's resolution (the documented radiance scale)
    env = uniform_environment(3.0, height=64, spectrum="A")
    d = env.directions()
    cos_up = np.clip(d[..., 2], 0.0, None)
    y = env.pixel_luminance()
    irradiance_y = float((y * cos_up * env.solid_angles()).sum())
    assert math.isclose(irradiance_y / math.pi, 3.0, rel_tol=2e-3)   # quadrature error of 64 rows
    assert math.isclose(float(spectra_to_xyz(env.mean_radiance_spectrum())[1]), 3.0, rel_tol=1e-9)


def test_srgb_basis_unit_coefficients_are_the_srgb_primaries():
    # Mallett-Yuksel: the basis spectra's sRGB are the unit vectors (to their decomposition's accuracy, 1e-3)
    c = np.zeros((2, 4, 3), np.float32)
    c[:, 0], c[:, 1], c[:, 2] = np.eye(3, dtype=np.float32)
    env = EnvironmentMap(c, srgb_basis())
    rgb = env.to_linear_srgb()
    assert np.allclose(rgb[0, :3], np.eye(3), atol=2e-3)


# ------------------------------------------------------------------------------------------- files

def test_exr_round_trip_keeps_the_spectra(tmp_path):
    # a map on a non-sRGB basis (D65 / A / a green spectrum) comes back through linear sRGB channels plus
    # the header's basis: the spectra agree to float32 rounding of the channels (relative 1e-5 of the peak)
    grid = REFERENCE_GRID
    basis = np.stack([light_spectrum("D65", grid), light_spectrum("A", grid),
                      np.exp(-0.5 * ((grid.wavelengths - 540.0) / 30.0) ** 2)]) * 0.01
    rng = np.random.default_rng(3)
    env = EnvironmentMap(rng.uniform(0, 10, (8, 16, 3)).astype(np.float32), basis, grid, source="three")
    back = read_environment(write_environment(tmp_path / "m.exr", env))
    d = env.directions()
    a, b = env.spectral_radiance(d), back.spectral_radiance(d)
    assert np.abs(a - b).max() <= 1e-5 * np.abs(a).max()


def test_exr_round_trip_applies_intensity_not_rotation(tmp_path):
    env = _random_map(seed=4).with_(rotation_deg=30.0, intensity=2.0)
    back = read_environment(write_environment(tmp_path / "m.exr", env))
    assert back.rotation_deg == 0.0 and back.intensity == 1.0
    d = pixel_directions(env.height, env.width)
    assert np.allclose(back.luminance(d), env.with_(rotation_deg=0.0).luminance(d), rtol=1e-4)


def test_exr_without_the_header_is_read_as_linear_srgb(tmp_path):
    rgb = np.full((4, 8, 3), 0.5, np.float32)
    _write_exr(tmp_path / "plain.exr", rgb)
    env = read_environment(tmp_path / "plain.exr")
    assert np.allclose(env.basis, srgb_basis())
    assert math.isclose(float(env.luminance([[0, 0, 1.0]])[0]), 0.5, rel_tol=1e-3)


def test_hdr_file_is_read_as_linear_srgb(tmp_path):
    import cv2

    rgb = np.zeros((4, 8, 3), np.float32)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 0.25, 0.5, 1.0
    cv2.imwrite(str(tmp_path / "m.hdr"), rgb[..., ::-1])      # OpenCV writes BGR
    env = read_environment(tmp_path / "m.hdr")
    # Radiance RGBE keeps 8 bits of mantissa: 1 % here
    assert np.allclose(env.coefficients[0, 0], [0.25, 0.5, 1.0], rtol=1e-2)


# ------------------------------------------------------------------------------------------- bad input

def _one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text and isinstance(exc.value, EnvironmentMapError)
    return text


@pytest.mark.parametrize("value, word", [(np.nan, "NaN"), (np.inf, "infinite"), (-1.0, "negative")])
def test_bad_values_in_a_file_are_one_line_errors(tmp_path, value, word):
    rgb = np.ones((4, 8, 3), np.float32)
    rgb[1, 2, 0] = value
    _write_exr(tmp_path / "bad.exr", rgb)
    with pytest.raises(EnvironmentMapError) as exc:
        read_environment(tmp_path / "bad.exr")
    text = _one_line(exc)
    assert "bad.exr" in text and word in text


def test_wrong_aspect_ratio_is_a_one_line_error(tmp_path):
    _write_exr(tmp_path / "square.exr", np.ones((8, 8, 3), np.float32))
    with pytest.raises(EnvironmentMapError) as exc:
        read_environment(tmp_path / "square.exr")
    text = _one_line(exc)
    assert "square.exr" in text and "2:1" in text


def test_missing_file_is_a_one_line_error(tmp_path):
    with pytest.raises(EnvironmentMapError) as exc:
        read_environment(tmp_path / "nowhere.exr")
    assert "nowhere.exr" in _one_line(exc)


def test_not_an_exr_is_a_one_line_error(tmp_path):
    p = tmp_path / "fake.exr"
    p.write_bytes(b"not an image at all")
    with pytest.raises(EnvironmentMapError) as exc:
        read_environment(p)
    assert "fake.exr" in _one_line(exc)


def test_other_extensions_are_refused(tmp_path):
    p = tmp_path / "map.png"
    p.write_bytes(b"\x89PNG")
    with pytest.raises(EnvironmentMapError) as exc:
        read_environment(p)
    assert ".png" in _one_line(exc)


def test_malformed_header_basis_is_a_one_line_error(tmp_path):
    _write_exr(tmp_path / "h.exr", np.ones((4, 8, 3), np.float32),
               {HEADER_KEY: json.dumps({"wavelengths_nm": [400, 500], "basis": [[1, 2]]})})
    with pytest.raises(EnvironmentMapError) as exc:
        read_environment(tmp_path / "h.exr")
    assert HEADER_KEY in _one_line(exc)


def test_bad_maps_in_memory_are_refused():
    with pytest.raises(EnvironmentMapError, match="twice as wide"):
        EnvironmentMap(np.ones((4, 4, 3), np.float32), srgb_basis())
    with pytest.raises(EnvironmentMapError, match="basis"):
        EnvironmentMap(np.ones((4, 8, 3), np.float32), np.ones((2, REFERENCE_GRID.size)))
    with pytest.raises(EnvironmentMapError, match="intensity"):
        EnvironmentMap(np.ones((4, 8, 3), np.float32), srgb_basis(), intensity=0.0)
    with pytest.raises(EnvironmentMapError, match="rotation_deg"):
        EnvironmentMap(np.ones((4, 8, 3), np.float32), srgb_basis(), rotation_deg=float("nan"))


def test_writing_needs_an_exr_name_and_an_existing_folder(tmp_path):
    env = uniform_environment(1.0, height=4)
    with pytest.raises(EnvironmentMapError, match=r"\.exr"):
        write_environment(tmp_path / "m.hdr", env)
    with pytest.raises(EnvironmentMapError, match="does not exist"):
        write_environment(tmp_path / "no" / "m.exr", env)


def test_a_coarser_grid_reads_the_same_luminance(tmp_path):
    env = _random_map(seed=5)
    p = write_environment(tmp_path / "m.exr", env)
    coarse = read_environment(p, SpectralGrid(400.0, 700.0, 10.0))
    d = env.directions()[1:3]
    # every other sample of D65 times the basis: the 10 nm quadrature differs by up to 2.2 % (measured)
    assert np.allclose(coarse.luminance(d), env.luminance(d), rtol=0.03)


def test_colours_outside_srgb_round_trip_through_exr(tmp_path):
    # a saturated narrow-band green has negative linear sRGB; the file then holds the map's own coefficients
    grid = REFERENCE_GRID
    basis = np.stack([np.exp(-0.5 * ((grid.wavelengths - 510.0) / 8.0) ** 2), light_spectrum("D65", grid) * 0.01,
                      light_spectrum("A", grid) * 0.01])
    c = np.zeros((4, 8, 3), np.float32)
    c[..., 0], c[..., 1] = 1.0, 0.1
    env = EnvironmentMap(c, basis, grid, source="green")
    assert env.to_linear_srgb().min() < 0
    back = read_environment(write_environment(tmp_path / "g.exr", env))
    d = env.directions()
    assert np.allclose(back.spectral_radiance(d), env.spectral_radiance(d), rtol=1e-6, atol=1e-9)


def test_exr_of_six_basis_spectra_keeps_them_and_shows_srgb(tmp_path):
    # a probe of two bracket sets keeps six basis spectra: six channels of their own, read back exactly, and
    # the map's sRGB (clipped at 0) in R, G, B for any viewer
    import OpenEXR

    rng = np.random.default_rng(3)
    env = EnvironmentMap(rng.uniform(0, 4, (8, 16, 6)).astype(np.float32), rng.uniform(0, 1, (6, REFERENCE_GRID.size)),
                         REFERENCE_GRID, source="six", intensity=2.0)
    path = write_environment(tmp_path / "six.exr", env)
    back = read_environment(path)
    d = env.directions().reshape(-1, 3)
    np.testing.assert_allclose(back.spectral_radiance(d), env.spectral_radiance(d), rtol=1e-6)
    with OpenEXR.File(str(path)) as f:
        rgb = np.asarray(f.channels()["RGB"].pixels)
    np.testing.assert_allclose(rgb, np.maximum(env.to_linear_srgb(), 0.0), rtol=1e-6, atol=1e-7)


def test_exr_header_naming_missing_coefficient_channels_is_refused(tmp_path):
    import OpenEXR

    meta = {"wavelengths_nm": REFERENCE_GRID.wavelengths.tolist(), "basis": np.ones((2, REFERENCE_GRID.size)).tolist(),
            "channels": "coefficient channels", "coefficient_channels": ["kogei.c0", "kogei.c1"]}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, HEADER_KEY: json.dumps(meta)}
    with OpenEXR.File(header, {"RGB": np.ones((4, 8, 3), np.float32), "kogei.c0": np.ones((4, 8), np.float32)}) as f:
        f.write(str(tmp_path / "bad.exr"))
    with pytest.raises(EnvironmentMapError, match=r"bad\.exr: the header names coefficient channels the file lacks "
                                                   r"\(kogei\.c1\)"):
        read_environment(tmp_path / "bad.exr")


def test_exr_keeps_the_maps_white(tmp_path):
    # a probe names its white (the chart's); the file keeps it, for three basis spectra and for six
    from processing.spectral.spectra import light_spectrum

    white = light_spectrum("A", REFERENCE_GRID)
    for k in (3, 6):
        rng = np.random.default_rng(k)
        env = EnvironmentMap(rng.uniform(0, 1, (4, 8, k)).astype(np.float32), rng.uniform(0.1, 1, (k, REFERENCE_GRID.size)),
                             REFERENCE_GRID, white=white)
        back = read_environment(write_environment(tmp_path / f"w{k}.exr", env))
        np.testing.assert_allclose(back.white, white, rtol=1e-9)
        assert read_environment(write_environment(tmp_path / f"n{k}.exr", replace_white(env))).white is None
    with pytest.raises(EnvironmentMapError, match="the white must be"):
        EnvironmentMap(np.ones((4, 8, 3), np.float32), srgb_basis(), white=np.zeros(REFERENCE_GRID.size))


def replace_white(env):
    from dataclasses import replace

    return replace(env, white=None)


def test_a_radiance_header_declaring_an_image_bomb_is_one_line(tmp_path):
    """A 119-byte .hdr whose header declares 200000 x 100000 pixels: OpenCV refuses it with cv2.error, which
    escaped as a traceback; now one line naming the file."""
    from processing.lighting.environment_map import EnvironmentMapError, read_environment

    path = tmp_path / "bomb.hdr"
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 200000\n" + bytes(64))
    with pytest.raises(EnvironmentMapError, match="bomb.hdr: OpenCV refuses to read it") as err:
        read_environment(path)
    assert "\n" not in str(err.value)
