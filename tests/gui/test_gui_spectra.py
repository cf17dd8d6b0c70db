"""The spectra and materials panel on a simulated session: a lacquered (urushi-red) sphere shot with the
chart through the fake gphoto2 and captured by the window; a click gives the estimated reflectance, its
uncertainty and the identified material; the material map covers the sphere.

Ground truth: the simulated world's material of the sphere (urushi-red) and its spectral radiance image
(:meth:`mocks.world.World.frame`): the estimated spectrum must follow the simulated radiance factor's
shape at the clicked pixel.
"""

from __future__ import annotations

import pytest

pytest.importorskip("PySide6.QtWidgets", reason="the GUI tests need PySide6 (pip install PySide6-Essentials)")

import numpy as np
from PySide6.QtCore import Qt
from scipy import ndimage

from mocks.world import World
from tests.gui.helpers import station_window, wait_capture

LEFT = Qt.MouseButton.LeftButton


def test_click_gives_spectrum_and_material_and_the_map_covers_the_sphere(qtbot, tmp_path):
    world = World.calibration_sphere(40.0, 0.0, width=600, height=400, chart_layout="classic24")
    w, _ = station_window(qtbot, tmp_path, camera=True, world=world, seed=4, n_points=96)
    w.session.folder.setText(str(tmp_path / "s"))
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(4)
    w.capture.passes.setValue(1)
    w.capture.camera_angles.setText("0")
    qtbot.mouseClick(w.capture.start, LEFT)
    wait_capture(qtbot, w, timeout_s=120)
    assert w.capture.status_text == "complete", w.error_line.text()
    truth = world.frame("object", 0.0)           # the frame p01/frame/00 was shot at table angle 0

    w.tabs.setCurrentWidget(w.spectra)
    qtbot.mouseClick(w.spectra.list_button, LEFT)
    assert w.spectra.frames.currentText() == "p01/frame/00"
    qtbot.mouseClick(w.spectra.load_button, LEFT)
    qtbot.waitUntil(lambda: w.spectra.scene is not None, timeout=60_000)
    # the pixel deepest inside the sphere, in the binned image's coordinates
    depth = ndimage.distance_transform_edt(truth.labels == 0)
    y, x = np.unravel_index(np.argmax(depth), depth.shape)
    w.spectra.pick(int(x) // 2, int(y) // 2)
    qtbot.waitUntil(lambda: w.spectra.last is not None, timeout=30_000)
    res = w.spectra.last
    assert res["identification"].material == "urushi-red" == world.materials["sphere"]
    assert "urushi-red" in w.spectra.state.text()
    factor = truth.radiance[y - 4:y + 6, x - 4:x + 6].reshape(-1, truth.radiance.shape[2]).mean(axis=0) / truth.light
    expected = np.interp(res["wavelengths"], truth.grid.wavelengths, factor)
    assert np.corrcoef(res["mean"], expected)[0, 1] > 0.95        # the red lacquer's spectral shape
    assert np.all(res["uncertainty"] > 0) and np.all(np.isfinite(res["mean"]))
    qtbot.waitUntil(lambda: not w.spectra.plot.busy and w.spectra.plot.draws >= 2, timeout=30_000)
    assert w.spectra.plot.failure == ""

    qtbot.mouseClick(w.spectra.map_button, LEFT)
    qtbot.waitUntil(lambda: w.spectra.map is not None, timeout=60_000)
    labels, names = w.spectra.map
    inside = (truth.labels == 0)[::2, ::2][:labels.shape[0], :labels.shape[1]]
    core = ndimage.binary_erosion(inside, iterations=8)      # away from the rim and the blocks it cuts
    found = labels[core]
    judged = found[found > 0]                                 # blocks in the sphere's shadow are too dark
    red = [k for k, n in names.items() if n == "urushi-red"]
    assert judged.size > 0.5 * found.size
    assert red and np.mean(judged == red[0]) > 0.9
    assert "urushi-red" in w.spectra.legend.text()
    if "uncertain" in names.values():
        assert "uncertain (confidence below 0.50)" in w.spectra.legend.text()

    # Raising the confidence a block needs only turns names into 'uncertain', never into another name; with
    # no bound nothing is uncertain; a bound outside 0..1 is refused
    from app.gui.spectra_panel import UNCERTAIN, material_map

    free, free_names = material_map(w.spectra.scene, 6, min_confidence=0.0)
    strict, strict_names = material_map(w.spectra.scene, 6, min_confidence=0.99)
    assert UNCERTAIN not in free_names.values()
    assert np.array_equal(free > 0, strict > 0)
    lookup_free = np.array([""] + [free_names[i] for i in range(1, max(free_names) + 1)], dtype=object)
    lookup_strict = np.array([""] + [strict_names[i] for i in range(1, max(strict_names) + 1)], dtype=object)
    a, b = lookup_free[free], lookup_strict[strict]
    assert np.all((a == b) | (b == UNCERTAIN))
    with pytest.raises(ValueError, match="min_confidence must be within 0..1"):
        material_map(w.spectra.scene, 6, min_confidence=1.5)

    # A clipped pixel has no colour to measure: its value never reaches a spectrum or the map (here the
    # clipped pixels are also made white, which would pull the estimate off if they were used), and a
    # click where everything is clipped says so
    import dataclasses

    from app.gui.spectra_panel import spectrum_at

    scene = w.spectra.scene
    cy, cx = int(y) // 2, int(x) // 2
    mask = np.zeros(scene.rgb.shape[:2], bool)
    mask[cy - 2:cy + 3, cx - 2:cx] = True                     # two of the five columns around the click
    clean = spectrum_at(dataclasses.replace(scene, clipped=mask), cx, cy)
    white = scene.rgb.copy()
    white[mask] = 1.0
    burnt = spectrum_at(dataclasses.replace(scene, rgb=white, clipped=mask), cx, cy)
    assert clean["pixels"] == burnt["pixels"] == 15
    np.testing.assert_array_equal(burnt["mean"], clean["mean"])
    assert burnt["identification"].material == "urushi-red"
    with pytest.raises(ValueError, match=r"clipped \(saturated\)"):
        spectrum_at(dataclasses.replace(scene, clipped=np.ones_like(mask)), cx, cy)
    block = np.zeros_like(mask)
    block[cy - 12:cy + 12, cx - 12:cx + 12] = True
    labels_clipped, _ = material_map(dataclasses.replace(scene, rgb=np.where(block[..., None], 1.0, scene.rgb),
                                                         clipped=block), 6)
    assert not labels_clipped[block].any() and labels_clipped[~block].any()


def test_dark_and_backdrop_clicks_are_refused_the_map_says_what_it_judged_and_the_catalogue_restricts(qtbot,
                                                                                                      tmp_path):
    """Nothing is named where nothing can be measured; the map reports its coverage of the object; the
    session's catalogued materials become the candidates, and a catalogue that leaves out the true material
    gets "no candidate fits" through the confidence rule rather than a confident wrong name.

    Ground truth: the sphere is red lacquer (urushi-red); the backdrop's reflectance is 0.05
    (:data:`mocks.world.BACKDROP_REFLECTANCE`) and the simulated world's labels give the sphere's pixels."""
    from app.gui.spectra_panel import MIN_SIGNAL, map_coverage

    world = World.calibration_sphere(40.0, 0.0, width=600, height=400, chart_layout="classic24")
    w, _ = station_window(qtbot, tmp_path, camera=True, world=world, seed=4, n_points=96)
    w.session.folder.setText(str(tmp_path / "s"))
    w.session.meta_edits["materials"].setText("urushi, gold")
    qtbot.mouseClick(w.session.new_button, LEFT)
    w.capture.steps.setValue(4)
    w.capture.passes.setValue(1)
    w.capture.camera_angles.setText("0")
    qtbot.mouseClick(w.capture.start, LEFT)
    wait_capture(qtbot, w, timeout_s=120)
    truth = world.frame("object", 0.0)
    w.tabs.setCurrentWidget(w.spectra)
    qtbot.mouseClick(w.spectra.list_button, LEFT)
    qtbot.mouseClick(w.spectra.load_button, LEFT)
    qtbot.waitUntil(lambda: w.spectra.scene is not None, timeout=60_000)
    scene = w.spectra.scene

    # the frame's corner is the backdrop: refused with the reason, nothing named
    w.spectra.pick(2, 2)
    qtbot.waitUntil(lambda: "spectrum:" in w.error_line.text(), timeout=30_000)
    assert "is the backdrop, not the object" in w.error_line.text() and w.spectra.last is None
    assert w.spectra.state.text().startswith("not measured:")
    # the sphere's unlit side: too dark to have a colour (the 5 x 5 pixels around the click below 2 %)
    green = ndimage.uniform_filter(scene.rgb[..., 1], 5)
    dark = np.argwhere((green < 0.8 * MIN_SIGNAL) & ~scene.backdrop)
    assert len(dark), "the simulated sphere has an unlit side"
    dy, dx = dark[len(dark) // 2]
    w.error_line.setText("")
    w.spectra.pick(int(dx), int(dy))
    qtbot.waitUntil(lambda: "spectrum:" in w.error_line.text(), timeout=30_000)
    assert "too dark to measure a colour" in w.error_line.text() and w.spectra.last is None

    # the map: how much of the object was judged, and the parts left out, add up to the object
    qtbot.mouseClick(w.spectra.map_button, LEFT)
    qtbot.waitUntil(lambda: w.spectra.map is not None, timeout=60_000)
    cov = map_coverage(scene, w.spectra.map[0])
    assert cov["judged"] + cov["dark"] + cov["clipped"] + cov["sparse"] == cov["object"] > 0
    sphere = int((truth.labels == 0)[::2, ::2].sum())
    assert cov["judged"] <= cov["object"] and abs(cov["object"] - sphere) < 0.5 * sphere   # the object ~ the sphere
    assert f"judged {100 * cov['judged'] / cov['object']:.0f}% of the object" in w.spectra.state.text()

    # the catalogue "urushi, gold": three candidates; the sphere is still the red lacquer
    depth = ndimage.distance_transform_edt(truth.labels == 0)
    y, x = np.unravel_index(np.argmax(depth), depth.shape)
    w.spectra.only_catalogued.setChecked(True)                 # recalibrates with the catalogued candidates
    assert w.spectra.candidates_label.text() == "candidates: urushi-black, urushi-red, gold"
    qtbot.waitUntil(lambda: w.spectra.scene is not scene and w.spectra.scene is not None, timeout=60_000)
    assert list(w.spectra.scene.candidates.names) == ["urushi-black", "urushi-red", "gold"]
    w.spectra.pick(int(x) // 2, int(y) // 2)
    qtbot.waitUntil(lambda: w.spectra.last is not None, timeout=30_000)
    assert w.spectra.last["identification"].material == "urushi-red"

    # a catalogue without the lacquer: the red sphere fits none of silver, tin, aluminium -- said so
    w.session.meta_edits["materials"].setText("silver, tin, aluminium")
    w.spectra.only_catalogued.setChecked(False)
    w.spectra.only_catalogued.setChecked(True)
    last_scene = w.spectra.scene
    qtbot.waitUntil(lambda: w.spectra.scene is not last_scene and not w.work_lane.busy, timeout=60_000)
    w.spectra.pick(int(x) // 2, int(y) // 2)
    qtbot.waitUntil(lambda: w.spectra.last is not None, timeout=30_000)
    assert list(w.spectra.scene.candidates.names) == ["silver", "tin", "aluminium"], w.spectra.candidates_label.text()
    assert w.spectra.last["identification"].material == "no candidate fits", w.spectra.state.text()
    assert "no candidate fits" in w.spectra.state.text()
