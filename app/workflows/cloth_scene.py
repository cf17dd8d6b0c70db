"""Cloth scenes: the figures of Yasuda et al. (Fig. 15-18) on a draped sheet, and the demo's cloth scene.

Each figure is a montage of renders of :func:`processing.cloth.draped.draped_cloth`
(the paper's "simple wrinkles expressed with trigonometric functions") with
warp tangents from its UVs:

* ``fig15_components.png``: silk with only its specular, only its internal
  and only its diffuse component, and all three (top-left, top-right,
  bottom-left, bottom-right; view and light above the cloth, as in the paper);
* ``fig16_weave_angle.png``: the same silk with the weave at 0 and at 45 degrees;
* ``fig17_cotton_silk.png``: cotton (top) and silk (bottom) of the same dye;
* ``fig18_tamamushi.png``: tamamushi seen across the warp and along it
  (left, right): the warp's colour dominates in one, the weft's in the other.

:func:`render_cloth_scene` renders one cloth scene for ``make demo``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["ClothView", "FIGURES", "cloth_object", "render_cloth", "render_figures", "render_cloth_scene"]


@dataclass(frozen=True)
class ClothView:
    """Camera and light of a cloth render (the sheet lies in the x-y plane, warp along x)."""

    eye: tuple[float, float, float] = (0.0, -0.6, 7.0)
    light: tuple[float, float, float] = (0.25, -0.35, 1.0)
    fov_deg: float = 30.0


#: Looking down at the sheet (Fig. 15-17), and the two views of Fig. 18: the light 30 degrees off
#: the normal toward -y, the camera 40 degrees off it toward +y (near the mirror direction, the half
#: vector 5 degrees across the warp: the warp's lobe at its peak) or, walked a quarter turn round the
#: cloth, toward +x (the half vector 21 degrees along the warp, where its narrow axis leaves it dark).
#: The camera is far (20 units, 13 degree field) so the whole sheet sees nearly one half vector: the
#: filament warp's lobe is narrow along the yarn and a wide field would sweep across it.
TOP = ClothView()
_LIGHT_18 = (0.0, -0.5, math.sqrt(0.75))
_EYE_18 = (20.0 * math.sin(math.radians(40.0)), 20.0 * math.cos(math.radians(40.0)))
ACROSS_WARP = ClothView(eye=(0.0, _EYE_18[0], _EYE_18[1]), light=_LIGHT_18, fov_deg=13.0)
ALONG_WARP = ClothView(eye=(_EYE_18[0], 0.0, _EYE_18[1]), light=_LIGHT_18, fov_deg=13.0)

FIGURES = ("fig15_components.png", "fig16_weave_angle.png", "fig17_cotton_silk.png", "fig18_tamamushi.png")


def cloth_object(material: str, weave_angle_deg: float = 0.0, divisions: int = 96, fold_amplitude: float = 0.25,
                 wrinkle_amplitude: float = 0.012):
    """The draped sheet with ``material`` (a spec string) and warp tangents from its UVs."""
    from processing.cloth.draped import draped_cloth
    from processing.materials.presets import get_material
    from render.meshio import make_mesh
    from render.scene import SceneObject
    from render.tangents import tangents_from_uvs

    sheet = draped_cloth(divisions=divisions, fold_amplitude=fold_amplitude, wrinkle_amplitude=wrinkle_amplitude)
    mesh = make_mesh(sheet.vertices, sheet.triangles, sheet.normals, source="draped cloth")
    tangents = tangents_from_uvs(sheet.vertices, sheet.triangles, sheet.uvs, sheet.normals)
    return SceneObject(mesh, [get_material(material)], name=material, tangents=tangents,
                       weave_angle_deg=weave_angle_deg)


def render_cloth(material: str, size: tuple[int, int], preset: str = "standard", *, view: ClothView = TOP,
                 weave_angle_deg: float = 0.0, divisions: int = 96, illuminant: str = "D65",
                 fold_amplitude: float = 0.25, wrinkle_amplitude: float = 0.012, sky: float = 0.15):
    """Render the draped sheet under one sun (``view.light``) and a uniform sky of zenith radiance ``sky``.

    Returns the :class:`render.renderer.RenderResult`.
    """
    from render.camera import Camera
    from render.presets import get_preset
    from render.renderer import render
    from render.scene import Light, Scene, Sky

    scene = Scene([cloth_object(material, weave_angle_deg, divisions, fold_amplitude, wrinkle_amplitude)],
                  [Light("directional", view.light, illuminant, 1.0)], Sky("uniform", zenith=sky, spectrum=illuminant))
    width, height = size
    eye = np.asarray(view.eye, dtype=np.float64)
    up = (0.0, 1.0, 0.0) if abs(eye[2]) > 0.95 * np.linalg.norm(eye) else (0.0, 0.0, 1.0)
    camera = Camera(view.eye, (0.0, 0.0, 0.0), up, view.fov_deg, width, height)
    return render(scene, camera, get_preset(preset))


def _montage(images: list[NDArray[np.uint8]], columns: int, gap: int = 4) -> NDArray[np.uint8]:
    h, w = images[0].shape[:2]
    rows = (len(images) + columns - 1) // columns
    out = np.full((rows * h + (rows - 1) * gap, columns * w + (columns - 1) * gap, 3), 255, np.uint8)
    for k, img in enumerate(images):
        r, c = divmod(k, columns)
        out[r * (h + gap): r * (h + gap) + h, c * (w + gap): c * (w + gap) + w] = img
    return out


def render_figures(out_dir: str | Path, preset: str = "standard", size: tuple[int, int] = (320, 240),
                   divisions: int = 96) -> list[Path]:
    """Write the four figures of Yasuda et al. (see the module text) into ``out_dir``; returns their paths."""
    from render.image_io import write_png

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    def img(spec: str, **kw) -> NDArray[np.uint8]:
        return render_cloth(spec, size, preset, divisions=divisions, **kw).srgb8

    figures = [
        _montage([img("silk:internal=0,diffuse=0"), img("silk:specular=0,diffuse=0"),
                  img("silk:specular=0,internal=0"), img("silk")], 2),
        _montage([img("silk"), img("silk", weave_angle_deg=45.0)], 2),
        _montage([img("cotton"), img("silk")], 1),
        # gentle folds: most of the sheet sees the same tilt of h, across or along the warp
        _montage([img("tamamushi", view=ACROSS_WARP, fold_amplitude=0.02, wrinkle_amplitude=0.0),
                  img("tamamushi", view=ALONG_WARP, fold_amplitude=0.02, wrinkle_amplitude=0.0)], 2),
    ]
    paths = []
    for name, picture in zip(FIGURES, figures):
        paths.append(write_png(out / name, picture))
    return paths


def render_cloth_scene(out_dir: str | Path, preset: str = "standard", size: tuple[int, int] = (640, 480),
                       material: str = "tamamushi") -> Path:
    """The demo's cloth scene: ``material`` on the draped sheet, seen across the warp; returns the PNG path.

    Parameters
    ----------
    out_dir
        Folder of the image ``cloth-<material>.png`` (created).
    preset
        Render preset.
    size
        Image size (width, height).
    material
        A cloth material spec.
    """
    from render.image_io import write_png

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = material.split(":")[0].strip().lower()
    result = render_cloth(material, size, preset, view=ACROSS_WARP)
    return write_png(out / f"cloth-{name}.png", result.srgb8)
