"""The scene file of docs/scene-file.md is a sensible scene: it parses, its objects stand apart, all in view.

The example's ``head.ply`` is, as the document says, the demo's scan of the procedural hawk; here the
procedural hawk itself (fewer triangles) stands in for it.  Geometry only: nothing is rendered.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from app.workflows.scene_build import object_mesh
from app.workflows.scene_spec import load_scene_file
from mocks.procedural_hawk import hawk_head
from processing.geometry.mesh_ply import write_mesh_ply
from render.camera import Camera

DOC = Path(__file__).resolve().parents[2] / "docs" / "scene-file.md"


def _example(tmp_path: Path):
    text = DOC.read_text(encoding="utf-8")
    block = re.search(r"```toml\n(\[render\].*?)```", text, flags=re.S)
    assert block, "docs/scene-file.md has no TOML example starting with [render]"
    scene = tmp_path / "scene.toml"
    scene.write_text(block.group(1), encoding="utf-8")
    hawk = hawk_head(3000)
    write_mesh_ply(tmp_path / "head.ply", hawk.vertices, hawk.triangles)
    spec = load_scene_file(scene)
    for obj in spec.objects:
        if "triangles" in obj.procedural_args:
            obj.procedural_args["triangles"] = 3000
    return spec


def test_the_documented_scene_shows_every_object_apart_and_in_view(tmp_path):
    spec = _example(tmp_path)
    objects = {(o.procedural or "mesh"): object_mesh(o) for o in spec.objects}
    assert sorted(objects) == ["cloth", "hawk", "mesh"]
    boxes = {k: (o.mesh.vertices.min(axis=0), o.mesh.vertices.max(axis=0)) for k, o in objects.items()}
    (lo_a, hi_a), (lo_b, hi_b) = boxes["mesh"], boxes["hawk"]
    assert np.any(hi_a < lo_b) or np.any(hi_b < lo_a), "the two heads overlap"
    cloth_lo, cloth_hi = boxes["cloth"]
    for k in ("mesh", "hawk"):
        lo, hi = boxes[k]
        assert cloth_hi[2] <= lo[2] + 1.0, f"the cloth rises through the {k}'s base"
        assert np.all(cloth_lo[:2] < lo[:2]) and np.all(hi[:2] < cloth_hi[:2]), f"the {k} is not on the cloth"
    w, h = spec.size
    cam = spec.camera
    camera = Camera(cam.eye, cam.target, cam.up, cam.fov_deg, w, h)
    for k in ("mesh", "hawk"):
        xy = camera.project(objects[k].mesh.vertices)
        assert np.all(np.isfinite(xy)), f"part of the {k} is behind the camera"
        assert np.all((xy >= 0) & (xy <= [w, h])), f"the {k} is not wholly in view"
    centre = camera.project(0.5 * (cloth_lo + cloth_hi))
    assert 0 <= centre[0] <= w and 0 <= centre[1] <= h, "the cloth is out of view"
