"""The Preview tab's "Adapt to display white": off, the image shows the light's own colour (illuminant A, a
tungsten light, looks warm next to D65); on, both are adapted to the display's white and look alike.

Ground truth: illuminant A's white, taken to sRGB without adaptation, has linear R/B of about 4.3 (8-bit
255/133 after gamut mapping) against D65's 1; a nearly neutral material (aluminium) shows the light's colour as it
is.  With CAT02 adaptation a neutral surface maps to the display's white under any light, so its R/B is the same
under A and D65 up to the 8-bit rounding and the spectral (not only tristimulus) shape of A on the metal's
reflectance.  Measured at 160 x 120, draft: R/B 0.980 (D65), 0.978 (A) adapted; 0.988 (D65), 6.27 (A) not.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

import numpy as np

from tests.gui.helpers import make_window


def _sphere(path):
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(radius=20.0, resolution=30)
    m.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(path), m)
    return path


def _red_over_blue(qtbot, panel, illuminant: str, adapt: bool) -> float:
    """Linear mean red over linear mean blue of the lit object (fully covered pixels, sRGB decoded)."""
    panel.illuminant.setCurrentText(illuminant)
    panel.adapt.setChecked(adapt)
    panel.last_kind = None
    panel.request("final")
    qtbot.waitUntil(lambda: panel.last_kind == "final" and not panel._busy, timeout=120_000)
    c = panel.last["srgb8"].astype(float) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    lit = (panel.last["mask"] > 0.99) & (lin.mean(axis=2) > 0.05)
    assert lit.sum() > 200
    return float(lin[lit][:, 0].mean() / lin[lit][:, 2].mean())


def test_adapt_to_display_white_off_shows_the_lights_colour(qtbot, tmp_path):
    w = make_window(qtbot, tmp_path)
    p = w.preview
    assert p.adapt.isChecked() and p.adapt.toolTip()                 # on by default, and says what it does
    p.preset.setCurrentText("draft")
    p.size.setCurrentText("160x120")
    p.material.setCurrentText("aluminium")
    p.set_mesh(str(_sphere(tmp_path / "sphere.ply")))
    qtbot.waitUntil(lambda: p.last_kind == "final" and not p._busy, timeout=120_000)

    d65_on, a_on = _red_over_blue(qtbot, p, "D65", True), _red_over_blue(qtbot, p, "A", True)
    d65_off, a_off = _red_over_blue(qtbot, p, "D65", False), _red_over_blue(qtbot, p, "A", False)
    assert "not adapted" in p.info.text()
    # adapted: A and D65 alike within 2 % in R/B (measured 0.2 %: rounding and the metal's spectral shape)
    assert a_on == pytest.approx(d65_on, rel=0.02), (a_on, d65_on)
    # not adapted: D65 is the display's own white, so it barely changes (measured 0.8 %: the renderer's D65
    # white against sRGB's); A is much warmer (measured 6.3 x; a white under A is 4.3 x)
    assert d65_off == pytest.approx(d65_on, rel=0.02), (d65_off, d65_on)
    assert a_off > 3.0 * d65_off, (a_off, d65_off)
