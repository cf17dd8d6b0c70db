"""Adaptive anti-aliasing: which pixels are refined, what refined pixels hold, and the ray counts
of the cast-only baseline.

Expected values: a uniformly lit plane has identical samples (never refined); a silhouette or a
material boundary crossing a pixel makes its samples disagree (refined); a refined pixel is, by
construction, the pixel a uniform render with ``adaptive_samples`` samples gives, which is checked
against such a render; and adaptive ``standard`` is compared with a 256-sample render.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import settings as hsettings
from hypothesis import strategies as st

from processing.materials.lobes import Lobe, Material
from processing.spectral.display import delta_e00
from render.camera import Camera
from render.errors import RenderInputError
from render.meshio import make_mesh
from render.presets import PRESETS, RenderSettings
from render.renderer import cast_rays_baseline, pixels_to_refine, render
from render.scene import Light, Scene, SceneObject, Sky


class Grey:
    angle_dependent = False

    def __init__(self, rho: float) -> None:
        self.rho = rho

    def reflectance(self, cos_d, wavelengths):
        return np.full(np.shape(cos_d) + (len(wavelengths),), self.rho)


def lambert(rho: float, name: str) -> Material:
    return Material(name, (Lobe("lambert", 1.0, Grey(rho)),))


def quad(x0: float, x1: float, y0: float, y1: float, z: float = 0.0):
    v = [[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]]
    return make_mesh(v, [[0, 1, 2], [0, 2, 3]])


def adaptive(**kw) -> RenderSettings:
    base = dict(spectral_step=10.0, samples_per_pixel=4, mirror_bounces=1, mirror_rays=0, use_tables=True,
                shadows=True, tile_size=16, adaptive_samples=16, adaptive_threshold=0.5)
    base.update(kw)
    return RenderSettings(**base)


# camera looking straight down at z = 0; 16 x 16 pixels over about [-1, 1]^2
CAM = Camera((0.0, 0.0, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 22.0, 16, 16)
SUN = Light("directional", (0.3, 0.2, 1.0), "D65")


def test_uniformly_lit_plane_is_never_refined():
    scene = Scene([SceneObject(quad(-3, 3, -3, 3), [lambert(0.6, "grey")])], [SUN], Sky("none"))
    res = render(scene, CAM, adaptive(adaptive_threshold=0.01))
    assert res.stats["refined_pixels"] == 0 and not res.refined.any()
    assert res.stats["primary_rays"] == 16 * 16 * 4
    assert np.allclose(res.xyz[..., 1], res.xyz[0, 0, 1], rtol=1e-5)


def test_silhouette_and_material_edge_are_refined_and_nothing_else():
    # an edge at x = 0.43 (inside a pixel) between two materials, and the plane's
    # silhouette at y = 0.43 against the black background
    dark = SceneObject(quad(-3, 0.43, -3, 0.43), [lambert(0.1, "dark")])
    light = SceneObject(quad(0.43, 3, -3, 0.43), [lambert(0.8, "light")])
    scene = Scene([dark, light], [SUN], Sky("none"))
    res = render(scene, CAM, adaptive())
    edge_x, edge_y = CAM.project([0.43, 0.0, 0.0])[0], CAM.project([0.0, 0.43, 0.0])[1]
    assert 0.3 < edge_x % 1 < 0.7 and 0.3 < edge_y % 1 < 0.7                  # edges cross pixel interiors
    cols = np.arange(16) + 0.5
    near_x = np.abs(cols - edge_x) < 1.0                                      # pixels the edge can cross
    near_y = np.abs(cols - edge_y) < 1.0
    ys, xs = np.nonzero(res.refined)
    assert res.refined.any()
    assert np.all(near_x[xs] | near_y[ys])                                    # only edge pixels
    # every pixel the edge crosses is refined: in the column holding the edge, all covered rows
    row, col = int(edge_y), int(edge_x)
    assert np.all(res.refined[row + 1:, col])
    assert np.all(res.refined[row, :])
    assert res.stats["refined_pixels"] == int(res.refined.sum())
    assert res.stats["primary_rays"] == 16 * 16 * 4 + 16 * int(res.refined.sum())


def test_refined_pixels_equal_a_uniform_render_with_the_refinement_samples():
    dark = SceneObject(quad(-3, 0.43, -3, 0.43), [lambert(0.1, "dark")])
    light = SceneObject(quad(0.43, 3, -3, 0.43), [lambert(0.8, "light")])
    scene = Scene([dark, light], [SUN], Sky("gradient", zenith=0.3, horizon=0.8))
    res = render(scene, CAM, adaptive())
    base = render(scene, CAM, adaptive(adaptive_samples=0))
    full = render(scene, CAM, adaptive(samples_per_pixel=16, adaptive_samples=0))
    r = res.refined
    assert r.any() and not r.all()
    assert np.allclose(res.xyz[r], full.xyz[r], rtol=1e-6, atol=1e-7)
    assert np.array_equal(res.xyz[~r], base.xyz[~r])
    assert np.allclose(res.mask[r], full.mask[r]) and np.array_equal(res.mask[~r], base.mask[~r])
    # threshold 0 refines every covered pixel with any variation; sky-only pixels never
    all_on = render(scene, CAM, adaptive(adaptive_threshold=0.0))
    assert not np.any(all_on.refined[base.mask == 0])


def test_adaptive_standard_is_close_to_a_256_sample_render_on_an_edge_rich_scene():
    # thin slats (about a pixel wide) of two greys over a plate they shadow, under a sky
    slats = []
    for i, x in enumerate(np.linspace(-0.9, 0.8, 5)):
        mat = lambert(0.7, "light") if i % 2 else lambert(0.2, "dark")
        slats.append(SceneObject(quad(x, x + 0.061, -0.9, 0.9, 0.05), [mat]))
    plate = SceneObject(quad(-1.2, 1.2, -1.2, 1.2), [lambert(0.4, "grey")])
    scene = Scene(slats + [plate], [SUN], Sky("gradient", zenith=0.3, horizon=0.8))
    cam = Camera((0.4, -1.5, 5.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), 30.0, 40, 30)
    truth = render(scene, cam, PRESETS["standard"].replace(samples_per_pixel=256, adaptive_samples=0,
                                                           mirror_rays=4, tile_size=8))
    std = render(scene, cam, PRESETS["standard"])
    plain = render(scene, cam, PRESETS["standard"].replace(adaptive_samples=0))
    de_std = float(delta_e00(std.xyz, truth.xyz, truth.white).mean())
    de_plain = float(delta_e00(plain.xyz, truth.xyz, truth.white).mean())
    assert 0.0 < std.stats["refined_fraction"] < 0.8
    assert de_std <= 0.1
    assert de_std < 0.6 * de_plain                  # the refinement is what brings it within the target


def test_baseline_casts_the_same_rays_as_the_render():
    dark = SceneObject(quad(-3, 0.43, -3, 0.43), [lambert(0.1, "dark")])
    light = SceneObject(quad(0.43, 3, -3, 0.43), [lambert(0.8, "light")])
    scene = Scene([dark, light], [SUN, Light("directional", (-0.5, 0.1, 1.0), "A", 0.5)], Sky("none"))
    for s in (adaptive(), adaptive(jitter=True, seed=3), adaptive(adaptive_samples=0)):
        res = render(scene, CAM, s)
        base = cast_rays_baseline(scene, CAM, s, refined=res.refined)
        assert base.primary_rays == res.stats["primary_rays"]
        assert base.shadow_rays == res.stats["shadow_rays"] > 0
        assert base.build >= 0.0 and base.cast > 0.0 and base.with_build == base.build + base.cast
    assert {"bvh_build", "primary_rays", "shadow_rays"} <= set(res.timings)


def test_baseline_and_settings_errors_are_specific():
    scene = Scene([SceneObject(quad(-3, 3, -3, 3), [lambert(0.6, "grey")])], [SUN], Sky("none"))
    with pytest.raises(RenderInputError, match="pass refined="):
        cast_rays_baseline(scene, CAM, adaptive())
    with pytest.raises(RenderInputError, match=r"bool array of shape \(16, 16\)"):
        cast_rays_baseline(scene, CAM, adaptive(), refined=np.zeros((4, 4), bool))
    with pytest.raises(RenderInputError, match="must exceed samples_per_pixel"):
        adaptive(adaptive_samples=4)
    with pytest.raises(RenderInputError, match="samples_per_pixel >= 2"):
        adaptive(samples_per_pixel=1)
    with pytest.raises(RenderInputError, match="adaptive_threshold must be a number >= 0"):
        adaptive(adaptive_threshold=-1.0)
    with pytest.raises(RenderInputError, match="adaptive_threshold"):
        adaptive(adaptive_threshold="high")


def test_presets_meet_the_adaptive_contract():
    d, s, r = PRESETS["draft"], PRESETS["standard"], PRESETS["reference"]
    assert d.adaptive_samples == 0                                   # draft stays one ray per pixel
    assert s.adaptive_samples > s.samples_per_pixel and r.adaptive_samples > r.samples_per_pixel
    assert r.adaptive_threshold <= s.adaptive_threshold              # the reference refines more
    for p in (s, r):                                                 # square patterns: every stratum filled
        assert round(p.adaptive_samples ** 0.5) ** 2 == p.adaptive_samples


@hsettings(max_examples=40, deadline=None)
@given(
    value=st.floats(0.0, 1e6, allow_subnormal=False),
    samples=st.integers(2, 16),
    step=st.floats(0.0, 1.0),
)
def test_pixels_to_refine_threshold_in_lightness_units(value, samples, step):
    """Identical samples are never refined (black, tiny, huge values); a step of relative size
    ``step`` in Y is refined exactly when its CIELAB lightness difference exceeds the threshold."""
    white = np.ones(3)
    same = np.full((samples, 3), value, np.float32)
    assert not pixels_to_refine(same, np.zeros(samples, int), samples, white, 0.0)[0]
    y = 0.5
    xyz = np.full((samples, 3), y, np.float32)
    xyz[-1] = y * (1.0 - step)

    def lstar(t):
        return 116 * np.cbrt(t) - 16 if t > (6 / 29) ** 3 else t * 116 / (3 * (6 / 29) ** 2)

    dl = lstar(np.float32(y)) - lstar(np.float32(y * (1.0 - step)))
    for threshold in (0.5, 2.0):
        if abs(dl - threshold) > 1e-3:
            got = bool(pixels_to_refine(xyz, np.zeros(samples, int), samples, white, threshold)[0])
            assert got == (dl > threshold)
