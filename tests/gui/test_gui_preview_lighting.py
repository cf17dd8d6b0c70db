"""The Preview tab's lighting: a light probe (an environment map file) and the daylight sky light the mesh.

Ground truth is the direction of the light: a map bright only toward +x lights the +x side of a sphere,
which the default view (from -y, z up) shows on the image's right; the same map turned by 180 degrees
lights the left.  The sky's sun follows the light's azimuth the same way.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np

from tests.gui.helpers import make_window


def _sphere(path):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(radius=20.0, resolution=40)
    m.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(path), m)
    return path


def _half_map(path):
    """A map of luminance 1 toward +x (cos(azimuth) > 0), black toward -x."""
    from processing.lighting.environment_map import EnvironmentMap, pixel_directions, srgb_basis, write_environment
    from processing.spectral.spectra import REFERENCE_GRID

    d = pixel_directions(32, 64)
    coeff = np.where((d[..., 0] > 0)[..., None], 1.0, 0.0) * np.ones(3)      # sRGB (1, 1, 1): D65 of luminance 1
    write_environment(path, EnvironmentMap(coeff.astype(np.float32), srgb_basis(), REFERENCE_GRID, source="half"))
    return path


def _right_over_left(panel) -> float:
    """Linear mean of the object's right half over its left half (sRGB decoded)."""
    c = panel.last["srgb8"].astype(float) / 255.0
    img = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).mean(axis=2)
    mask = panel.last["mask"] > 0.99
    h, w = img.shape
    left, right = mask.copy(), mask.copy()
    left[:, w // 2:] = False
    right[:, :w // 2] = False
    return (img[right].mean() + 1e-3) / (img[left].mean() + 1e-3)


def _render(qtbot, panel) -> None:
    panel.last_kind = None
    panel.request("final")
    qtbot.waitUntil(lambda: panel.last_kind == "final" and not panel._busy, timeout=120_000)


def _preview_of_a_sphere(qtbot, tmp_path):
    """The window's Preview tab showing a red-lacquer sphere, draft, 160 x 120, its first render done."""
    w = make_window(qtbot, tmp_path)
    p = w.preview
    p.material.setCurrentText("urushi-red")
    p.preset.setCurrentText("draft")
    p.size.setCurrentText("160x120")
    p.set_mesh(str(_sphere(tmp_path / "sphere.ply")))
    qtbot.waitUntil(lambda: p.last_kind == "final" and not p._busy, timeout=120_000)
    return p


def test_probe_and_sky_light_the_mesh_from_their_directions(qtbot, tmp_path):
    from app.gui.preview_panel import LIGHTINGS

    p = _preview_of_a_sphere(qtbot, tmp_path)
    # no probe chosen yet: the panel says what to do instead of rendering something else
    p.lighting.setCurrentText(LIGHTINGS[2])
    p.request("final")
    assert "no light probe chosen" in p.info.text()
    probe = _half_map(tmp_path / "half.exr")
    p.set_probe(str(probe))
    _render(qtbot, p)
    # lit from +x: a Lambertian sphere seen from -y sends 2.49x as much light from its right half as from its
    # left (the visible normals integrated against the lit half-space, orthographic view); the lacquer's
    # gloss adds to the lit side (measured 2.78)
    assert _right_over_left(p) > 2.0
    p.set_probe(f"{probe}:rotate=180")
    _render(qtbot, p)
    assert _right_over_left(p) < 1 / 2.0                 # turned: lit from -x
    p.lighting.setCurrentText(LIGHTINGS[1])              # the sky, its sun at the light's direction
    p.light_el.setValue(30.0)
    p.light_az.setValue(0.0)                             # the sun toward +x
    _render(qtbot, p)
    assert _right_over_left(p) > 1.5                     # the sky's own light fills the sun's shadow
    assert "under" in p.info.text()


def test_a_probe_of_six_basis_spectra_lights_the_mesh_as_its_three_basis_twin(qtbot, tmp_path):
    """A probe from two bracket sets is a map of six basis spectra naming its white: the half map written that
    way (D65 times six hat functions, its white D65) gives the Preview the same picture as the 3-basis map."""
    from processing.lighting.environment_map import EnvironmentMap, pixel_directions, write_environment
    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.spectra import REFERENCE_GRID as g
    from processing.spectral.spectra import light_spectrum

    d65 = light_spectrum("D65", g)
    d65 = d65 / spectra_to_xyz(d65, g)[1]
    nodes = np.linspace(g.start, g.stop, 6)
    hats = np.clip(1 - np.abs(g.wavelengths[None] - nodes[:, None]) / (nodes[1] - nodes[0]), 0, None) * d65
    y = spectra_to_xyz(hats, g)[:, 1]
    lit = (pixel_directions(32, 64)[..., 0] > 0)[..., None]
    six = write_environment(tmp_path / "six.exr", EnvironmentMap((lit * y).astype(np.float32), hats / y[:, None], g,
                                                                 source="six", white=d65))
    p = _preview_of_a_sphere(qtbot, tmp_path)
    from app.gui.preview_panel import LIGHTINGS

    p.lighting.setCurrentText(LIGHTINGS[2])
    images = []
    for probe in (_half_map(tmp_path / "half.exr"), six):
        p.set_probe(str(probe))
        _render(qtbot, p)
        images.append(p.last["srgb8"].astype(float))
    assert images[0].std() > 5
    assert np.abs(images[1] - images[0]).max() <= 1.0
