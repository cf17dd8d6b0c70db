"""``python -m bench.screenshots --out docs/screenshots``: drive the window through a simulated session
and save a PNG of each main view (``make screenshots``).

The window runs offscreen against the simulated station of ``kogei gui
--mock`` (its 240 x 160 camera frames and the ColorChecker on the backdrop;
a finer hawk mesh): a reference sphere is scanned and calibrated first
(through the library, as ``kogei calibrate``), then the hawk is captured in
three placements with RAW frames, processed and previewed, every step
through the window's own widgets.  Settings go to a temporary file, so the
user's window settings are untouched.  ``--size 1024x700`` sets the
window's size (default 1360 x 900), to check that nothing is cropped in a
small window; ``--upto spectra`` stops after that view (into a scratch
``--out``, to redo one picture).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["main", "take_screenshots", "VIEWS"]


def _calibration(tmp: Path) -> Path:
    from app.capture.devices import build_devices
    from app.capture.runner import CaptureHooks, CapturePlan, run_capture
    from app.session import Session
    from app.workflows.calibration import calibrate_session
    from mocks.station import SimulatedStation
    from mocks.world import World

    plan = CapturePlan("sphere-calibration", steps=90)           # profiles only, no chart
    with SimulatedStation(World.calibration_sphere(25.0, 60.0), root=tmp / "cal-station", seed=1) as st:
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)}}
        s = Session.create(tmp / "calibration", plan=plan.to_dict(), object_info={"name": "reference sphere r 25"})
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()
    calibrate_session(tmp / "calibration", 25.0)
    return tmp / "calibration"


#: The views in the order the session reaches them (``--upto`` stops after one).
VIEWS = ("devices", "capture", "session", "camera", "spectra", "processing", "preview")


class _Done(Exception):
    """Raised after the ``upto`` view is written: the rest of the session is not needed."""


def take_screenshots(out: Path, *, steps: int = 90, passes: int = 3, log: Callable[[str], None] = print,
                     size: tuple[int, int] = (1360, 900), upto: str | None = None) -> list[Path]:
    """Run the session in the window and write ``devices.png``, ``session.png``, ... into ``out``.

    ``upto``: stop after writing that view (one of :data:`VIEWS`), e.g. ``"spectra"`` to redo the Spectra
    tab's picture without processing the session.
    """
    if upto is not None and upto not in VIEWS:
        raise ValueError(f"upto must be one of {', '.join(VIEWS)}, got {upto!r}")
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QApplication

    from app.gui.main_window import MainWindow

    app = QApplication.instance() or QApplication([])
    out.mkdir(parents=True, exist_ok=True)
    tmp_dir = tempfile.TemporaryDirectory(prefix="kogei-screenshots-")
    tmp = Path(tmp_dir.name)
    saved: list[Path] = []

    def wait(pred: Callable[[], bool], what: str, timeout_s: float = 300.0) -> None:
        end = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > end:
                try:
                    shown = w.error_line.text()
                except NameError:                  # before the window exists
                    shown = ""
                raise TimeoutError(f"screenshots: timed out waiting for {what}"
                                   + (f" (the window says: {shown})" if shown else ""))
            app.processEvents()
            time.sleep(0.01)

    def settle(seconds: float = 0.5) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            app.processEvents()
            time.sleep(0.01)

    def shot(w: Any, name: str) -> None:
        settle(0.3)
        path = out / f"{name}.png"
        w.grab().save(str(path))
        saved.append(path)
        log(f"wrote {path}")
        if name == upto:
            raise _Done

    log("calibrating the simulated scanner (sphere scan)…")
    cal = _calibration(tmp)
    w = MainWindow(QSettings(str(tmp / "settings.ini"), QSettings.Format.IniFormat))
    w.resize(*size)
    w.show()
    try:
        # the --mock station's camera and chart (mocks.world.station_world_settings), a finer hawk
        w.start_simulated_station(triangles=20_000, n_points=400, seed=1, root=tmp / "station")
        w.devices.connect_all()
        wait(lambda: all(w.link.states[n] == "connected" for n in ("turntable", "profiler")), "the instruments")
        w.tabs.setCurrentWidget(w.devices)
        shot(w, "devices")

        w.processing.calibration.setText(str(cal))
        w.session.folder.setText(str(tmp / "hawk-2026-11-24"))
        w.session.set_metadata({"name": "Hawk head, okimono (simulated)", "collection_id": "M-1893-017",
                                "period": "Meiji, c. 1890", "materials": "shibuichi, gold, copper, urushi",
                                "operator": "capture station 2"})
        w.session.new_button.click()
        w.capture.steps.setValue(steps)
        w.capture.passes.setValue(passes)
        w.capture.camera_angles.setText("0,180")
        w.tabs.setCurrentWidget(w.capture)
        w.capture.start.click()
        prompts = 0
        while True:
            wait(lambda: not w.capture.prompt.isHidden() or w.capture.job.done, "the capture")
            if w.capture.job.done:
                break
            prompts += 1
            if prompts == 2:        # pass 1 done: its cloud and the re-placement prompt
                wait(lambda: not w.capture.cloud_plot.busy and not w.capture.profile_plot.busy, "the plots")
                shot(w, "capture")
            w.capture.prompt_go.click()
        wait(lambda: w.capture.start.isEnabled(), "the end of the capture")
        if w.capture.status_text != "complete":
            raise RuntimeError(f"screenshots: the capture did not complete: {w.error_line.text()}")

        w.tabs.setCurrentWidget(w.session)
        w.session.refresh()
        wait(lambda: w.session.thumbs.count() >= 3 * passes and not w.work_lane.busy, "the thumbnails")
        shot(w, "session")

        w.tabs.setCurrentWidget(w.camera)
        w.camera.open_session_chart()
        wait(lambda: w.camera.frame is not None and w.camera.image_plot.draws > 0 and not w.camera.image_plot.busy
             and not w.camera.hist_plot.busy, "the chart frame")
        shot(w, "camera")

        w.tabs.setCurrentWidget(w.spectra)
        w.spectra.list_frames()
        w.spectra.load()
        wait(lambda: w.spectra.scene is not None, "the spectral calibration")
        w.spectra.only_catalogued.setChecked(True)        # the catalogue entry's materials (recalibrates)
        wait(lambda: w.spectra.scene is not None and not w.work_lane.busy, "the spectral calibration")
        from scipy import ndimage

        scene = w.spectra.scene
        # the brightest lit, unclipped part of the object (5 x 5 pixels around the click): the metal's own colour
        usable = ~scene.clipped & ~scene.backdrop
        brightness = np.where(ndimage.minimum_filter(usable, 5), ndimage.uniform_filter(scene.rgb[..., 1], 5), -1.0)
        y, x = np.unravel_index(np.argmax(brightness), brightness.shape)
        w.spectra.pick(int(x), int(y))
        wait(lambda: (w.spectra.last is not None or w.spectra.state.text().startswith("not measured"))
             and not w.spectra.plot.busy, "the spectrum")
        w.spectra.make_map()
        wait(lambda: w.spectra.map is not None, "the material map")
        shot(w, "spectra")

        w.tabs.setCurrentWidget(w.processing)
        w.processing.preset.setCurrentText("standard")
        w.processing.run()
        wait(lambda: not w.processing.running, "processing", 900)
        if w.processing.report is None:
            raise RuntimeError(f"screenshots: processing failed: {w.error_line.text()}")
        wait(lambda: w.processing.mesh_image is not None and w.processing.mesh_busy.isHidden(), "the mesh view")
        shot(w, "processing")

        w.tabs.setCurrentWidget(w.preview)
        w.preview.size.setCurrentText("640x480")
        w.preview.preset.setCurrentText("standard")
        wait(lambda: w.preview.last_kind == "final" and w.preview.last is not None
             and w.preview.last["srgb8"].shape[:2] == (480, 640) and not w.preview._busy
             and w.preview._waiting is None and not w.preview._settle.isActive(), "the preview", 600)
        shot(w, "preview")
    except _Done:
        pass
    finally:
        w.close()
        tmp_dir.cleanup()
    return saved


def posed_screenshot(session: Path, out: Path, frame: int = 20) -> Path:
    """The Camera tab showing one of a projected session's frames with the mesh's outline (``camera-posed.png``).

    ``session`` is a session posed on its mesh, e.g. ``out/demo/capture/session`` after ``make demo``.
    """
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QApplication

    from app.gui.main_window import MainWindow

    app = QApplication.instance() or QApplication([])
    with tempfile.TemporaryDirectory(prefix="kogei-screenshots-") as tmp:
        w = MainWindow(QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat))
        w.resize(1360, 900)
        w.show()
        try:
            w.session.open_session(str(session))
            w.tabs.setCurrentWidget(w.camera)
            names = w.camera.refresh_posed()
            if not names:
                raise RuntimeError(f"screenshots: {session} has no posed frames; run make demo first")
            w.camera.posed_list.setCurrentIndex(min(frame, len(names) - 1))
            w.camera.open_posed()
            end = time.monotonic() + 120
            while w.camera.frame is None or w.camera.frame.mesh_outlines is None or w.camera.image_plot.busy:
                if time.monotonic() > end:
                    raise TimeoutError("screenshots: timed out waiting for the posed frame")
                app.processEvents()
                time.sleep(0.01)
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                app.processEvents()
                time.sleep(0.01)
            out.mkdir(parents=True, exist_ok=True)
            path = out / "camera-posed.png"
            w.grab().save(str(path))
        finally:
            w.close()
    return path


def measured_screenshot(session: Path, out: Path) -> Path:
    """The Preview tab rendering a session's measured object, with a clicked region's observations
    against its fitted model (``preview-measured.png``).  ``session`` has materials on its mesh
    (``kogei fit-materials``), e.g. ``out/demo/capture/session`` after ``make demo``.
    """
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtCore import QSettings
    from PySide6.QtWidgets import QApplication

    from app.gui.main_window import MainWindow

    app = QApplication.instance() or QApplication([])

    def wait(pred: Callable[[], bool], what: str, timeout_s: float = 180.0) -> None:
        end = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > end:
                raise TimeoutError(f"screenshots: timed out waiting for {what}")
            app.processEvents()
            time.sleep(0.01)

    with tempfile.TemporaryDirectory(prefix="kogei-screenshots-") as tmp:
        w = MainWindow(QSettings(str(Path(tmp) / "settings.ini"), QSettings.Format.IniFormat))
        w.resize(1360, 900)
        w.show()
        try:
            w.session.open_session(str(session))
            w.tabs.setCurrentWidget(w.preview)
            w.preview.mesh_changed()
            wait(lambda: w.preview.last_kind == "final" and not w.preview._busy, "the measured object's render")
            img = w.preview.last["srgb8"]
            ys, xs = np.nonzero(w.preview.last["mask"] > 0.99)
            pick = int(np.argmin((ys - ys.mean()) ** 2 + (xs - xs.mean()) ** 2))
            h, wd = img.shape[:2]
            view = w.preview.view
            scale = min(view.width() / wd, view.height() / h)
            x0, y0 = (view.width() - wd * scale) / 2, (view.height() - h * scale) / 2
            w.preview._clicked(x0 + (xs[pick] + 0.5) * scale, y0 + (ys[pick] + 0.5) * scale)
            wait(lambda: w.preview.info.text().startswith("region"), "the clicked region's observations")
            wait(lambda: not w.preview.region_plot.busy, "the region plot")
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                app.processEvents()
                time.sleep(0.01)
            out.mkdir(parents=True, exist_ok=True)
            path = out / "preview-measured.png"
            w.grab().save(str(path))
        finally:
            w.close()
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.screenshots", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/screenshots")
    parser.add_argument("--steps", type=int, default=90)
    parser.add_argument("--size", default="1360x900", metavar="WxH", help="the window's size (default 1360x900)")
    parser.add_argument("--posed", default=None, metavar="SESSION",
                        help="only the Camera tab with the mesh outline on a frame of this projected session "
                             "(e.g. out/demo/capture/session after make demo)")
    parser.add_argument("--measured", default=None, metavar="SESSION",
                        help="only the Preview tab with the measured object and a clicked region's observations "
                             "(a session after kogei fit-materials, e.g. out/demo/capture/session)")
    parser.add_argument("--upto", default=None, choices=VIEWS,
                        help="stop after this view (the views before it are written too)")
    args = parser.parse_args(argv)
    if args.measured:
        print(f"wrote {measured_screenshot(Path(args.measured), Path(args.out))}")
        return 0
    if args.posed:
        print(f"wrote {posed_screenshot(Path(args.posed), Path(args.out))}")
        return 0
    try:
        size = tuple(int(v) for v in args.size.lower().split("x"))
        if len(size) != 2 or min(size) < 200:
            raise ValueError
    except ValueError:
        parser.error(f"--size must be WxH with both at least 200, e.g. 1024x700; got {args.size!r}")
    take_screenshots(Path(args.out), steps=args.steps, size=size, upto=args.upto)
    return 0


if __name__ == "__main__":
    sys.exit(main())
