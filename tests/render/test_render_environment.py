"""Image-based lighting against closed forms: the furnace, a mirror sphere, a well's visible fraction.

* Furnace: a Lambertian sphere of albedo rho under a uniform environment of
  luminance L reflects ``rho L`` everywhere (any normal sees the same light).
* Mirror: an ideal mirror sphere shows the map along the direction mirrored
  about the sphere's normal (ray-sphere intersection written out here).
* Occlusion: the floor at the centre of a cylindrical well of radius R and
  depth D sees the sky through a disc of angular radius ``atan(R / D)``; its
  irradiance under a uniform environment is ``pi L sin^2(atan(R / D))``
  (the cosine-weighted solid angle of a cone), so a white floor reflects
  ``rho L sin^2``; the walls are black so nothing else adds light.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from processing.lighting.daylight_sky import daylight_sky
from processing.lighting.environment_map import EnvironmentMap, srgb_basis, uniform_environment
from processing.materials.lobes import Lobe, Material
from render.camera import Camera
from render.errors import RenderInputError
from render.meshio import make_mesh
from render.presets import PRESETS, RenderSettings
from render.renderer import render
from render.scene import Light, Scene, SceneObject, Sky


class Flat:
    """Spectrally flat, angle-independent reflectance."""

    angle_dependent = False

    def __init__(self, rho: float) -> None:
        self.rho = rho

    def reflectance(self, cos_d, wavelengths):
        return np.full(np.shape(cos_d) + (len(wavelengths),), self.rho)


def lambert(rho: float) -> Material:
    return Material(f"grey {rho}", (Lobe("lambert", 1.0, Flat(rho)),))


MIRROR = Material("mirror", (Lobe("microfacet", 1.0, Flat(1.0), roughness=1e-4, mirror=True),))


def uv_sphere(n_theta: int = 96, n_phi: int = 192, radius: float = 1.0):
    """A closed UV sphere with exact unit normals at the vertices."""
    theta = np.linspace(0.0, math.pi, n_theta + 1)
    phi = np.linspace(0.0, 2 * math.pi, n_phi, endpoint=False)
    t, p = np.meshgrid(theta[1:-1], phi, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1.0]], v, [[0, 0, -1.0]]]) * radius
    rows = n_theta - 1
    idx = lambda i, j: 1 + i * n_phi + (j % n_phi)  # noqa: E731
    tris = [[0, idx(0, j), idx(0, j + 1)] for j in range(n_phi)]
    for i in range(rows - 1):
        for j in range(n_phi):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
            tris += [[a, c, b], [b, c, d]]
    last = len(v) - 1
    tris += [[last, idx(rows - 1, j + 1), idx(rows - 1, j)] for j in range(n_phi)]
    return make_mesh(v, np.asarray(tris))


SPHERE = uv_sphere()
CAMERA = Camera((0, -6, 0), (0, 0, 0), (0, 0, 1), 22, 48, 48)


def smooth_map(height: int = 32, rotation_deg: float = 0.0) -> EnvironmentMap:
    """A smooth, coloured, non-uniform map (linear sRGB), for mirror lookups."""
    from processing.lighting.environment_map import pixel_directions

    d = pixel_directions(height, 2 * height)
    rgb = 0.3 + 0.25 * np.stack([d[..., 0] + 1, d[..., 1] + 1, 1.2 * (d[..., 2] + 1)], axis=-1)
    return EnvironmentMap(rgb.astype(np.float32), srgb_basis(), source="smooth", rotation_deg=rotation_deg)


def interior(result, margin: int = 2) -> np.ndarray:
    """Pixels fully on the object, ``margin`` pixels away from its silhouette."""
    from scipy.ndimage import binary_erosion

    return binary_erosion(result.mask >= 1.0, iterations=margin)


# --------------------------------------------------------------------------- furnace
@pytest.mark.parametrize("preset,tolerance", [("draft", 0.002), ("standard", 0.005)])
def test_furnace_lambert_sphere_reflects_albedo_times_radiance(preset, tolerance) -> None:
    """rho L = 0.8 x 0.5 = 0.4.  draft (prefiltered map, 16 x 32 normals from a 32 x 64 copy): the
    quadrature of the cosine lobe errs by < 0.2 % (measured 0.01 %).  standard (8 MIS directions per
    sample, shadow rays that a convex sphere never blocks): a uniform map is sampled by the BRDF alone
    (MIS compensation), cosine sampling of a Lambert lobe has no variance, so every pixel is within
    0.5 % (measured: mean 0.01 %, pixel standard deviation 0.17 %, float32 sums and the interpolated
    normals of the facets)."""
    env = uniform_environment(0.5, height=32)
    result = render(Scene([SceneObject(SPHERE, [lambert(0.8)])], [], Sky("none"), environment=env), CAMERA,
                    PRESETS[preset])
    y = result.xyz[..., 1][interior(result)]
    assert y.mean() == pytest.approx(0.4, rel=tolerance)
    assert np.percentile(np.abs(y - 0.4), 99) < 0.4 * tolerance


def test_environment_adds_to_a_directional_light() -> None:
    """Key light along the view (Y = rho cos theta) plus a uniform map (rho L): the centre pixel of the
    sphere faces the light, Y = 0.6 (1 + 0.5) = 0.9 (draft: exact to float32 and the 0.2 % quadrature)."""
    env = uniform_environment(0.5, height=32)
    scene = Scene([SceneObject(SPHERE, [lambert(0.6)])], [Light("directional", (0, -1, 0))], Sky("none"),
                  environment=env)
    result = render(scene, Camera((0, -6, 0), (0, 0, 0), (0, 0, 1), 22, 49, 49), PRESETS["draft"])
    assert result.xyz[24, 24, 1] == pytest.approx(0.9, rel=0.002)


def test_the_background_shows_the_map() -> None:
    """Camera rays that miss every object see the map itself: luminance 0.5 (float32)."""
    result = render(Scene([SceneObject(SPHERE, [lambert(0.5)])], [], Sky("none"),
                          environment=uniform_environment(0.5, height=8)), CAMERA, PRESETS["draft"])
    assert result.xyz[0, 0, 1] == pytest.approx(0.5, rel=1e-5)
    assert result.sky_visible


# --------------------------------------------------------------------------- mirror
def _mirrored_directions(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel centre: the direction mirrored about the unit sphere's normal, and whether it hits."""
    rays = camera.rays(0, camera.width, 0, camera.height, 1, np.random.default_rng(0), False)
    o, d = rays[:, :3].astype(np.float64), rays[:, 3:].astype(np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b = np.einsum("ij,ij->i", o, d)
    disc = b * b - (np.einsum("ij,ij->i", o, o) - 1.0)
    hit = disc > 0
    t = -b - np.sqrt(np.maximum(disc, 0))
    n = o + t[:, None] * d
    r = d - 2 * np.einsum("ij,ij->i", d, n)[:, None] * n
    return r.reshape(camera.height, camera.width, 3), hit.reshape(camera.height, camera.width)


@pytest.mark.parametrize("preset,tolerance", [("draft", 0.002), ("standard", 0.005)])
def test_mirror_sphere_reflects_the_map(preset, tolerance) -> None:
    """An ideal white mirror sphere shows L(r) with r mirrored about the normal.  Tolerance: the
    smooth map changes by < 0.05 % over the normal error of 96 x 192 facets (interpolated normals)
    at pixel centres (draft, measured 0.02 % at the 95th percentile: 0.2 % allowed); standard
    averages 4 samples over each pixel's footprint, where r turns by a few degrees near the rim
    (measured 0.06 %: 0.5 % allowed), on pixels 2 away from the silhouette."""
    env = smooth_map(rotation_deg=30.0)
    result = render(Scene([SceneObject(SPHERE, [MIRROR])], [], Sky("none"), environment=env), CAMERA,
                    PRESETS[preset])
    r, hit = _mirrored_directions(CAMERA)
    inside = interior(result) & hit
    expected = env.luminance(r[inside])
    got = result.xyz[..., 1][inside]
    assert np.median(np.abs(got / expected - 1)) < tolerance / 2
    assert np.percentile(np.abs(got / expected - 1), 95) < tolerance
    # the rotation matters: the unrotated map would differ by far more than the tolerance
    unrotated = env.with_(rotation_deg=0.0).luminance(r[inside])
    assert np.median(np.abs(got / unrotated - 1)) > 2 * tolerance


# --------------------------------------------------------------------------- occlusion
def well(radius: float, depth: float, n: int = 96):
    """A floor disc (object 0) at z = 0 and a cylindrical wall (object 1) up to z = depth."""
    phi = np.linspace(0, 2 * math.pi, n, endpoint=False)
    ring = np.stack([radius * np.cos(phi), radius * np.sin(phi), np.zeros(n)], axis=1)
    floor_v = np.concatenate([[[0, 0, 0.0]], ring])
    floor_t = [[0, 1 + j, 1 + (j + 1) % n] for j in range(n)]
    wall_v = np.concatenate([ring, ring + [0, 0, depth]])
    wall_t = []
    for j in range(n):
        k = (j + 1) % n
        wall_t += [[j, k, n + j], [k, n + k, n + j]]
    return make_mesh(floor_v, np.asarray(floor_t)), make_mesh(wall_v, np.asarray(wall_t))


def test_occlusion_the_floor_of_a_well_sees_the_sky_through_its_opening() -> None:
    """R = 1, D = 1.5: the floor's centre gets sin^2(atan(1/1.5)) = 0.3077 of the open sky's light.
    Camera straight down over the centre, a 2-degree view: the floor within 0.05 R of the centre,
    where the fraction changes by < 0.3 %.  standard: 48 x 48 pixels x 4 samples x 8 directions,
    standard error ~ 0.6 %; tolerance 3 %.  draft skips occlusion: it shows the open-sky value."""
    floor, wall = well(1.0, 1.5)
    env = uniform_environment(1.0, height=32)
    scene = Scene([SceneObject(floor, [lambert(1.0)], name="floor"), SceneObject(wall, [lambert(0.0)], name="wall")],
                  [], Sky("none"), environment=env)
    camera = Camera((0, 0, 3.0), (0, 0, 0), (0, 1, 0), 2.0, 48, 48)
    fraction = math.sin(math.atan(1.0 / 1.5)) ** 2
    standard = render(scene, camera, PRESETS["standard"]).xyz[..., 1].mean()
    assert standard == pytest.approx(fraction, rel=0.03)
    draft = render(scene, camera, PRESETS["draft"]).xyz[..., 1].mean()
    assert draft == pytest.approx(1.0, rel=0.01)


# --------------------------------------------------------------------------- spectra
def test_table_and_spectral_paths_agree_under_a_sky() -> None:
    """Rough gold under the analytic sky: the table path (standard) and per-sample spectra (reference
    settings, same samples) agree within 0.5 % in Y over the sphere (table interpolation < 0.1 %, the
    rest is the two paths' different random streams: both are Monte Carlo estimates)."""
    sky = daylight_sky(sun_elevation_deg=35, sun_azimuth_deg=-60, height=32)
    scene = Scene([SceneObject(SPHERE, ["gold:roughness=0.3,gloss=1,mirror=0"])], [], Sky("none"), environment=sky)
    base = PRESETS["standard"].replace(adaptive_samples=0, environment_samples=32)
    a = render(scene, CAMERA, base)
    b = render(scene, CAMERA, base.replace(use_tables=False))
    inside = interior(a)
    assert a.xyz[..., 1][inside].mean() == pytest.approx(b.xyz[..., 1][inside].mean(), rel=0.005)


# --------------------------------------------------------------------------- bad input
def test_bad_environment_and_settings() -> None:
    with pytest.raises(RenderInputError, match="environment must be"):
        Scene([SceneObject(SPHERE, [lambert(0.5)])], [], Sky("none"), environment="probe.exr")
    with pytest.raises(RenderInputError, match="no lights"):
        Scene([SceneObject(SPHERE, [lambert(0.5)])], [], Sky("none"))
    with pytest.raises(RenderInputError, match="environment_samples"):
        RenderSettings(environment_samples=-1)


def test_sampled_and_prefiltered_agree_for_lambert_under_a_sun() -> None:
    """A Lambert lobe on a convex sphere is exactly what the prefiltered map computes (albedo times the
    cosine-weighted mean radiance, nothing occluded), so the Monte Carlo path (map + BRDF samples, MIS,
    shadow rays that never hit) must agree with it under a sky with a sun: mean over the sphere within
    1 % (the prefilter's quadrature of a sun spread over 1.5 map pixels: < 0.5 %; the mean of ~1000 pixels
    x 64 directions: ~0.2 % standard error; measured 0.04 %) and 4 x 4 pixel blocks within 3 % at the 95th
    percentile (16 x 64 directions per block; measured 1.4 %, the terminator is the noisiest)."""
    sky = daylight_sky(sun_elevation_deg=30, sun_azimuth_deg=-120, sun=4.0, height=64)
    scene = Scene([SceneObject(SPHERE, [lambert(0.7)])], [], Sky("none"), environment=sky)
    sampled = render(scene, CAMERA, PRESETS["standard"].replace(adaptive_samples=0, environment_samples=16))
    prefiltered = render(scene, CAMERA, PRESETS["standard"].replace(adaptive_samples=0, environment_samples=0,
                                                                    mirror_bounces=0))
    inside = interior(sampled)
    a, b = sampled.xyz[..., 1], prefiltered.xyz[..., 1]
    assert a[inside].mean() == pytest.approx(b[inside].mean(), rel=0.01)
    blocks = lambda x: x.reshape(12, 4, 12, 4).mean(axis=(1, 3))  # noqa: E731
    full = blocks(inside.astype(float)) == 1.0
    assert np.percentile(np.abs(blocks(a)[full] / blocks(b)[full] - 1), 95) < 0.03


# --------------------------------------------------------------------------- the sampling of the map
def _plan(env):
    from processing.spectral.spectra import SpectralGrid
    from render.environment import EnvironmentPlan

    return EnvironmentPlan.build(env, SpectralGrid(400, 700, 10), 1.0)


def test_map_density_is_normalised_and_followed_by_the_samples() -> None:
    """The density integrates to 1 over the sphere (1e-6) and is proportional to the luminance above
    the mean; 200 000 draws land in each pixel in proportion to its probability (chi-square with
    H W - 1 degrees of freedom within 5 standard deviations), inside the pixel they were drawn from,
    with the density reported for that pixel."""
    from processing.lighting.environment_map import pixel_directions

    env = smooth_map(height=8, rotation_deg=40.0)
    plan = _plan(env)
    assert float((plan.pixel_pdf * env.solid_angles()).sum()) == pytest.approx(1.0, abs=1e-6)
    y = env.pixel_luminance()
    excess = np.maximum(y - (y * env.solid_angles()).sum() / (4 * np.pi), 0)
    nonzero = excess > 0
    ratio = plan.pixel_pdf[nonzero] / excess[nonzero]
    assert np.ptp(ratio) / ratio.mean() < 1e-6
    n = 200_000
    d, pdf, pixel = plan.sample(n, np.random.default_rng(3))
    assert np.allclose(np.linalg.norm(d, axis=0), 1.0, atol=1e-5)
    # float32 directions on a pixel's edge may fall in the neighbour: at most 1e-4 of them
    assert np.mean(plan.pixel_index(d) != pixel) < 1e-4
    assert np.allclose(pdf, plan.pdf_of(pixel))
    p = (plan.pixel_pdf * env.solid_angles()).ravel()
    counts = np.bincount(pixel, minlength=p.size)
    seen = p > 0
    assert counts[~seen].sum() == 0
    chi2 = float((((counts - n * p) ** 2)[seen] / (n * p[seen])).sum())
    dof = int(seen.sum()) - 1
    assert abs(chi2 - dof) < 5 * math.sqrt(2 * dof)
    # every pixel centre maps to its own pixel
    centres = pixel_directions(8, 16, 40.0).reshape(-1, 3).T.astype(np.float32)
    assert np.array_equal(plan.pixel_index(centres), np.arange(128))


def test_a_uniform_map_is_left_to_the_brdf() -> None:
    """No pixel is above the mean of a uniform map: the plan says so and the integrator draws every
    direction from the BRDF (MIS compensation)."""
    assert not _plan(uniform_environment(1.0, height=8)).samples_map
    assert _plan(smooth_map(height=8)).samples_map


def test_glossy_furnace_reflects_the_directional_albedo() -> None:
    """Under a uniform map of radiance L a convex object reflects L times its directional albedo
    A(cos_o) (nothing occludes, every direction brings L).  A grey Beckmann lobe (sigma 0.3, Smith,
    reflectance 0.9): ``standard`` integrates the map by sampling the BRDF (a uniform map is left to
    it) with its own densities, A comes from processing.materials.albedo's quadrature, an independent
    computation.  cos_o per pixel from the ray-sphere geometry at pixel centres; pixels with cos_o >
    0.3 (the grazing rim varies fastest across a pixel).  Mean ratio within 1 % (measured 0.004 %;
    single pixels are noisy, 8 directions each); ``draft`` (split sum: albedo table times the
    prefiltered map, uniform here) within 0.1 % of every pixel (measured 0.008 %: the 65-node table)."""
    from processing.materials.albedo import directional_albedo

    lobe = Lobe("microfacet", 1.0, Flat(0.9), roughness=0.3, shadowing="smith")
    material = Material("grey gloss", (lobe,))
    env = uniform_environment(1.0, height=16)
    scene = Scene([SceneObject(SPHERE, [material])], [], Sky("none"), environment=env)
    r, hit = _mirrored_directions(CAMERA)
    rays = CAMERA.rays(0, CAMERA.width, 0, CAMERA.height, 1, np.random.default_rng(0), False)
    view = -rays[:, 3:].reshape(CAMERA.height, CAMERA.width, 3).astype(np.float64)
    view /= np.linalg.norm(view, axis=-1, keepdims=True)
    normal = np.where(hit[..., None], r + view, view)     # r = 2 (v.n) n - v, so r + v is along n
    cos_o = np.einsum("ijk,ijk->ij", normal / np.linalg.norm(normal, axis=-1, keepdims=True), view)
    for preset, tolerance in (("standard", 0.01), ("draft", 0.001)):
        result = render(scene, CAMERA, PRESETS[preset])
        inside = interior(result) & hit & (cos_o > 0.3)
        albedo = directional_albedo(lobe, cos_o[inside], np.array([550.0]))[..., 0]
        ratio = result.xyz[..., 1][inside] / albedo
        if preset == "standard":
            assert ratio.mean() == pytest.approx(1.0, rel=tolerance)
        else:
            assert np.abs(ratio - 1).max() < tolerance


def test_float32_lookup_is_the_maps_bilinear_lookup() -> None:
    """The plan's float32 bilinear lookup (background, mirrors) against EnvironmentMap.lookup (float64)
    on a turned, scaled map, poles included: within 1e-5 of the map's largest value (float32)."""
    env = smooth_map(height=16, rotation_deg=33.0).with_(intensity=1.7)
    plan = _plan(env)
    d = np.random.default_rng(1).normal(size=(3, 20000)).astype(np.float32)
    d /= np.linalg.norm(d, axis=0)
    d[:, 0], d[:, 1] = (0, 0, 1), (0, 0, -1)
    expected = env.lookup(d.T.astype(np.float64)).T
    assert np.abs(plan.lookup(d) - expected).max() < 1e-5 * np.abs(expected).max()


def test_a_maps_white_sets_the_display_whatever_its_basis() -> None:
    """A grey map's light written on six basis spectra of luminance 1 each (D65 times six hat functions): the
    same radiance everywhere, but the rows together are no longer the white.  Given its white (D65), the sRGB
    image is the 3-basis map's to one level; without it the display takes the rows' sum (luminance 6) for
    white and exposure and the image comes out darker, as under a probe's basis found from its spectra."""
    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.spectra import REFERENCE_GRID, light_spectrum

    g = REFERENCE_GRID
    env3 = smooth_map()
    d65 = light_spectrum("D65", g)
    d65 = d65 / spectra_to_xyz(d65, g)[1]
    nodes = np.linspace(g.start, g.stop, 6)
    hats = np.clip(1 - np.abs(g.wavelengths[None] - nodes[:, None]) / (nodes[1] - nodes[0]), 0, None) * d65
    y = spectra_to_xyz(hats, g)[:, 1]
    grey = env3.coefficients.mean(axis=2, keepdims=True)
    env3 = EnvironmentMap(np.repeat(grey, 3, axis=2), srgb_basis(), source="grey")
    six = (grey * y[None, None, :]).astype(np.float32)
    d = env3.directions().reshape(-1, 3)
    images = {}
    for name, env in (("three", env3), ("six", EnvironmentMap(six, hats / y[:, None], g, white=d65)),
                      ("six, no white", EnvironmentMap(six, hats / y[:, None], g))):
        if name != "three":
            np.testing.assert_allclose(env.spectral_radiance(d), env3.spectral_radiance(d), rtol=1e-5, atol=1e-7)
        result = render(Scene([SceneObject(SPHERE, [lambert(0.8)])], [], Sky("none"), environment=env), CAMERA,
                        PRESETS["draft"])
        images[name] = np.asarray(result.srgb8, dtype=np.float64)
    assert np.abs(images["six"] - images["three"]).max() <= 1.0
    assert images["six, no white"].mean() < 0.7 * images["three"].mean()
