"""Rendering cloth: tangent frames, the renderer against the model evaluated directly, both
colour back ends, the weave angle, the tamamushi colour flip, and `kogei render --material silk`."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.cli import main
from processing.materials.lobes import material_brdf
from processing.materials.presets import get_material
from processing.spectral.display import spectra_to_xyz, xyz_scale
from processing.spectral.spectra import SpectralGrid, light_spectrum
from render.camera import Camera
from render.errors import RenderInputError
from render.meshio import make_mesh
from render.presets import PRESETS
from render.renderer import render
from render.scene import Light, Scene, SceneObject, Sky
from render.tangents import rotate_tangents, tangents_from_direction, tangents_from_field, tangents_from_uvs

SQUARE = make_mesh([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], [[0, 1, 2], [0, 2, 3]])


# ----------------------------------------------------------------- tangent frames
def test_uv_tangents_follow_increasing_u_on_a_turned_sheet():
    from processing.cloth.draped import draped_cloth

    sheet = draped_cloth(divisions=12, fold_amplitude=0.0, wrinkle_amplitude=0.0)
    angle = math.radians(30)
    rot = np.array([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]])
    t = tangents_from_uvs(sheet.vertices @ rot.T, sheet.triangles, sheet.uvs, sheet.normals @ rot.T)
    np.testing.assert_allclose(t, np.broadcast_to(rot[:, 0], t.shape), atol=1e-12)   # u runs along x before turning


def test_uv_tangents_lie_in_the_tangent_plane_of_a_folded_sheet():
    from processing.cloth.draped import draped_cloth

    sheet = draped_cloth(divisions=24)
    t = tangents_from_uvs(sheet.vertices, sheet.triangles, sheet.uvs, sheet.normals)
    assert np.allclose(np.linalg.norm(t, axis=1), 1.0)
    assert np.abs(np.sum(t * sheet.normals, axis=1)).max() < 1e-12
    assert np.all(t[:, 0] > 0.5)                   # the warp stays along +x over the folds


def test_direction_and_field_tangents_project_and_fall_back():
    n = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    t = tangents_from_direction(n, (1.0, 0.0, 0.0))
    assert np.allclose(np.sum(t * n, axis=1), 0.0) and np.allclose(np.linalg.norm(t, axis=1), 1.0)
    np.testing.assert_allclose(t[[0, 2]], [[1, 0, 0], [1, 0, 0]], atol=1e-12)
    assert abs(t[1] @ [1, 0, 0]) < 1e-12           # direction along the normal: the fallback axis
    f = tangents_from_field(n, [[0, 3, 0], [0, 0, 0], [0, 0.8, -0.6]])
    np.testing.assert_allclose(f[[0, 2]], [[0, 1, 0], [0, 0.8, -0.6]], atol=1e-12)
    np.testing.assert_allclose(rotate_tangents(t[:1], n[:1], 45.0), [[math.sqrt(0.5), math.sqrt(0.5), 0]], atol=1e-12)


def test_bad_tangent_inputs_are_refused():
    with pytest.raises(RenderInputError, match="tangents must be a finite \\(4, 3\\)"):
        SceneObject(SQUARE, ["silk"], tangents=np.ones((3, 3)))
    with pytest.raises(RenderInputError, match="weave_angle_deg"):
        SceneObject(SQUARE, ["silk"], weave_angle_deg=float("nan"))
    with pytest.raises(RenderInputError, match="warp direction"):
        tangents_from_direction([[0, 0, 1]], (0, 0, 0))
    with pytest.raises(RenderInputError, match="uvs"):
        tangents_from_uvs(SQUARE.vertices, SQUARE.triangles, np.zeros((3, 2)), SQUARE.vertex_normals)


# ----------------------------------------------------------------- the renderer vs the model
def _one_pixel(spec: str, eye, light, weave: float = 0.0, preset: str = "reference", tangents=None):
    scene = Scene([SceneObject(SQUARE, [spec], tangents=tangents, weave_angle_deg=weave)],
                  [Light("directional", light)], Sky("none"))
    cam = Camera(eye, (0, 0, 0), (0, 0, 1) if abs(eye[2]) < 0.9 * np.linalg.norm(eye) else (0, 1, 0), 1.0, 1, 1)
    return render(scene, cam, PRESETS[preset].replace(samples_per_pixel=1, adaptive_samples=0)).xyz[0, 0]


def _model_xyz(spec: str, eye, light, tangent=(1.0, 0.0, 0.0), step: float = 5.0):
    grid = SpectralGrid(400, 700, step)
    e = light_spectrum("D65", grid)
    i = np.asarray(light, float) / np.linalg.norm(light)
    o = np.asarray(eye, float) / np.linalg.norm(eye)
    h = (i + o) / np.linalg.norm(i + o)
    t = np.asarray(tangent, float)
    b = np.cross([0, 0, 1.0], t)
    f = material_brdf(get_material(spec), i[2], o[2], h[2], i @ h, grid.wavelengths, (i @ t, i @ b, o @ t, o @ b))
    return xyz_scale(e, grid) * spectra_to_xyz(f * e * i[2], grid)


@pytest.mark.parametrize("eye, light", [((0.0, -3.0, 4.0), (0.0, 2.0, 3.0)), ((2.0, 1.0, 4.0), (-1.0, 0.3, 2.0)),
                                        ((0.5, -4.0, 1.0), (0.2, 3.0, 1.5))])
def test_renderer_matches_the_model_at_the_centre_pixel(eye, light):
    want = _model_xyz("silk", eye, light)
    got = _one_pixel("silk", eye, light)
    np.testing.assert_allclose(got, want, rtol=2e-4)
    table = _one_pixel("silk", eye, light, preset="standard")     # angular XYZ tables, float32
    np.testing.assert_allclose(table, want, rtol=3e-3)


def test_weave_angle_turns_the_yarn_frame():
    eye, light = (0.0, -3.0, 4.0), (1.0, 2.0, 3.0)
    c45 = math.sqrt(0.5)
    np.testing.assert_allclose(_one_pixel("satin", eye, light, weave=45.0),
                               _model_xyz("satin", eye, light, tangent=(c45, c45, 0.0)), rtol=2e-4)
    # plain weave of equal yarns is symmetric under a quarter turn; a warp-faced satin is not
    np.testing.assert_allclose(_one_pixel("silk", eye, light, weave=90.0), _one_pixel("silk", eye, light), rtol=1e-4)
    a, b = _one_pixel("satin", eye, light, weave=90.0), _one_pixel("satin", eye, light)
    assert abs(a[1] - b[1]) > 0.05 * b[1]


def test_per_vertex_tangent_field_is_used():
    eye, light = (0.0, -3.0, 4.0), (1.0, 2.0, 3.0)
    field = np.tile([0.0, 1.0, 0.0], (4, 1))
    np.testing.assert_allclose(_one_pixel("satin", eye, light, tangents=field),
                               _model_xyz("satin", eye, light, tangent=(0.0, 1.0, 0.0)), rtol=2e-4)


def test_tamamushi_dominant_colour_flips_with_the_view():
    # Yasuda Fig. 18: light above; seen across the warp (h tilts across the filament warp, whose wide
    # lobe then shines in its colour) the cloth is greener than seen along it (the warp's narrow lobe
    # is dark and the weft's colour remains)
    from processing.spectral.display import xyz_to_linear_srgb

    across = _model_xyz("tamamushi", (0.0, 6.0, 5.0), (0.0, 0.0, 1.0))
    along = _model_xyz("tamamushi", (6.0, 0.0, 5.0), (0.0, 0.0, 1.0))
    white = _model_xyz("cotton:specular=0,internal=0,diffuse=1,warp_colour=#ffffff,weft_colour=#ffffff",
                       (0.0, 0.0, 1.0), (0.0, 0.0, 1.0))
    rgb_a = xyz_to_linear_srgb(across[None], white / white[1])[0]
    rgb_b = xyz_to_linear_srgb(along[None], white / white[1])[0]
    assert rgb_a[1] > rgb_a[0] and rgb_b[0] > rgb_b[1]     # green over red, then red over green


def _mean_hue_deg(xyz, white):
    import colour

    lab = colour.XYZ_to_Lab(xyz / white[1], colour.XYZ_to_xy(white / white[1]))
    return math.degrees(math.atan2(lab[:, 2].mean(), lab[:, 1].mean())) % 360.0


def _hue_gap(a, b):
    return abs((a - b + 180.0) % 360.0 - 180.0)


def test_tamamushi_figure_flips_between_the_dye_colours():
    # Yasuda Fig. 18 on the rendered image: the mean CIELAB hue of the cloth pixels is near the warp
    # dye's hue in one view and near the weft dye's in the other, each by a wide margin (the dyes' hues
    # from their sRGB colours through colour-science, not through the renderer)
    import colour

    from app.workflows.cloth_scene import ACROSS_WARP, ALONG_WARP, render_cloth
    from processing.cloth.presets import CLOTH_PRESETS

    def dye_hue(hexa):
        lab = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(colour.notation.HEX_to_RGB(hexa)))
        return math.degrees(math.atan2(lab[2], lab[1])) % 360.0

    warp, weft = (dye_hue(CLOTH_PRESETS["tamamushi"][k]) for k in ("warp_colour", "weft_colour"))
    assert _hue_gap(warp, weft) > 120.0                              # two clearly different dyes
    hues = []
    for view in (ACROSS_WARP, ALONG_WARP):
        r = render_cloth("tamamushi", (40, 30), "standard", view=view, divisions=20, fold_amplitude=0.02,
                         wrinkle_amplitude=0.0)
        on = r.mask > 0.99
        assert on.mean() > 0.2
        hues.append(_mean_hue_deg(r.xyz[on].astype(np.float64), np.asarray(r.white, dtype=np.float64)))
    across, along = hues
    assert _hue_gap(across, warp) + 60.0 < _hue_gap(across, weft), (across, warp, weft)
    assert _hue_gap(along, weft) + 60.0 < _hue_gap(along, warp), (along, warp, weft)


def test_cloth_scene_renders_with_sky_and_both_backends():
    from app.workflows.cloth_scene import render_cloth

    ref = render_cloth("silk", (16, 12), "reference", divisions=16)
    std = render_cloth("silk", (16, 12), "standard", divisions=16)
    assert np.all(np.isfinite(ref.xyz)) and ref.mask.mean() > 0.5
    from processing.spectral.display import delta_e00

    de = delta_e00(std.xyz.reshape(-1, 3), ref.xyz.reshape(-1, 3), ref.white)
    assert float(np.mean(de)) < 1.0


# ----------------------------------------------------------------- the command line
def test_kogei_render_cloth_with_weave_angle(tmp_path, capsys):
    from PIL import Image

    ply = tmp_path / "square.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
                   "-1 -1 0\n1 -1 0\n1 1 0\n-1 1 0\n3 0 1 2\n3 0 2 3\n")
    for material in ("silk", "tamamushi"):
        out = tmp_path / f"{material}.png"
        code = main(["render", str(ply), "--material", material, "--weave-angle", "45", "--size", "16x12",
                     "--preset", "draft", "--eye", "0,-3,4", "--out", str(out), "--quiet"])
        assert code == 0, capsys.readouterr().err
        assert np.asarray(Image.open(out)).shape[:2] == (12, 16)
    code = main(["render", str(ply), "--material", "silk:layers=80", "--size", "16x12", "--out",
                 str(tmp_path / "x.png"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "layers" in err and "Traceback" not in err


def test_procedural_cloth_in_a_scene_file(tmp_path, capsys):
    scene = tmp_path / "cloth.toml"
    scene.write_text('[render]\nsize = "16x12"\npreset = "draft"\n[[object]]\nprocedural = "cloth"\n'
                     'material = "silk"\nweave_angle = 45\ntriangles = 600\n')
    code = main(["render", str(scene), "--out", str(tmp_path / "c.png"), "--quiet"])
    assert code == 0, capsys.readouterr().err
