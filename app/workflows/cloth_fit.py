"""Swatch sessions: capture one on the simulated station, read one, fit the cloth model, plot the fit.

A swatch session is a capture with the ``swatch`` plan (:mod:`app.capture.runner`):
chart frames (4 by default), then one RAW frame per table step.  Its set-up (camera pose,
light direction, swatch size: :class:`processing.cloth.swatch_geometry.SwatchGeometry`)
is a JSON file, by default ``swatch.json`` in the session folder.

:func:`load_swatch_session` decodes the frames (:func:`processing.camera.raw_decode.decode_raw`,
2 x 2 binning, no demosaicing), calibrates them with the chart
(:func:`processing.cloth.fit.chart_gains` of the mean of each pass's chart
frames: the gains are shared by every frame of a pass, so their pixel noise
is not averaged out by the swatch frames) and picks the binned pixels that
see the swatch at every angle; :func:`processing.cloth.fit.fit_swatch` does
the fit; :func:`fit_figure` draws measured and fitted responses over angle.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from processing.common.files import JSONFileError, parse_json

__all__ = ["GEOMETRY_FILE", "SwatchData", "capture_swatch_session", "load_swatch_session", "fit_figure",
           "fit_report"]

GEOMETRY_FILE = "swatch.json"


@dataclass(frozen=True)
class SwatchData:
    """A decoded swatch session: the measurement, its set-up and where it came from."""

    measurement: Any          # processing.cloth.fit.SwatchMeasurement
    geometry: Any             # processing.cloth.swatch_geometry.SwatchGeometry
    gains: np.ndarray
    session: Path


def capture_swatch_session(out: str | Path, cloth: str = "silk", *, steps: int = 24, seed: int = 1,
                           width: int = 96, height: int = 72, camera: str = "hotfolder",
                           lights: Sequence[Sequence[float]] | None = None, chart_frames: int = 16) -> Path:
    """Capture a swatch session of a simulated swatch of ``cloth`` into ``out``.

    ``camera`` is ``"hotfolder"`` (the station writes each frame into its hot
    folder) or ``"gphoto2"`` (the station's fake ``gphoto2`` program, which
    rebuilds the swatch world from its configuration).  ``lights`` (directions
    toward the light, z > 0) makes one pass per light, the lamp moved between
    passes (default: one pass under the world's light).  ``chart_frames``
    chart frames open each pass.  Writes the set-up to
    ``out/swatch.json``.  Returns the session folder.  ``out`` must be new
    or an empty folder; the simulated station runs in a temporary folder
    that is removed afterwards.
    """
    import tempfile

    from app.capture.devices import build_devices
    from app.capture.runner import CaptureHooks, CapturePlan, run_capture
    from app.session import Session
    from mocks.fake_gphoto2 import update_config
    from mocks.station import SimulatedStation
    from mocks.swatch_world import SwatchWorld

    if camera not in ("hotfolder", "gphoto2"):
        raise UsageError(f"simulated swatch camera must be 'hotfolder' or 'gphoto2', got {camera!r}")
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out} exists and is not an empty folder; give a new folder for the swatch session")
    world = SwatchWorld.swatch(cloth, width=width, height=height)
    pass_lights = [tuple(float(v) for v in world.light_direction)] if lights is None else \
        [tuple(float(v) for v in d) for d in lights]
    if not pass_lights or any(len(d) != 3 or not d[2] > 0 for d in pass_lights):
        raise UsageError(f"lights must be directions (x, y, z) with z > 0, one per pass, got {lights!r}")
    try:
        plan = CapturePlan("swatch", steps=steps, passes=len(pass_lights), chart_frames=chart_frames)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    # the station's ports and hot folder live in a private folder removed afterwards: nothing beside ``out``
    with tempfile.TemporaryDirectory(prefix="kogei-swatch-station-") as station_dir, \
            SimulatedStation(world, root=Path(station_dir), seed=seed) as st:
        cam = ({"kind": "hotfolder", "folder": str(st.hotfolder), "stable_s": 0.1} if camera == "hotfolder" else
               {"kind": "gphoto2", "executable": str(st.gphoto2_path)})
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)},
                  "camera": cam}
        session = Session.create(out, plan=plan.to_dict(), object_info={"name": f"swatch ({cloth}, simulated)"},
                                 settings={"unattended": True, "device_config": config})
        devices = build_devices(config, session.root, shutter=st.shoot if camera == "hotfolder" else None)

        def before_pass(p: int, n: int) -> None:
            # the lamp moved to its place for this pass: the in-process world and the fake gphoto2's copy
            world.light_direction = pass_lights[p - 1]
            update_config(st.config_path, light_direction=list(pass_lights[p - 1]))
            st.place(p)

        def before_chart(p: int, k: int) -> None:
            # the chart stays in view for every chart frame of the pass (the station shows it once per placement);
            # each chart frame is a new exposure with its own noise
            update_config(st.config_path, chart_next=True, chart_index=k)

        try:
            run_capture(session, plan, devices, CaptureHooks(before_pass=before_pass, before_chart=before_chart))
        finally:
            session.close()
    geometry = {**world.geometry(), "light_direction": list(pass_lights[0]),
                "pass_light_directions": [list(d) for d in pass_lights[1:]]}
    (out / GEOMETRY_FILE).write_text(json.dumps(geometry, indent=2) + "\n")
    return out


def _decode(path: Path):
    from processing.camera.raw_decode import RawDecodeError, decode_raw

    try:
        return decode_raw(path, mode="bin2x2")
    except (RawDecodeError, OSError) as exc:
        raise UsageError(f"{path}: {exc}") from None


def load_swatch_session(session: str | Path, geometry: str | Path | None = None, *, max_pixels: int = 160,
                        margin_mm: float = 3.0) -> SwatchData:
    """Decode a swatch session into a calibrated :class:`processing.cloth.fit.SwatchMeasurement`.

    Raises
    ------
    UsageError
        Not a session, not a swatch capture, no chart frame, a bad or
        missing geometry file, frames of another size than the geometry.
    """
    from processing.cloth.fit import SwatchMeasurement

    root = Path(session)
    manifest = _swatch_manifest(root)
    gpath = Path(geometry) if geometry is not None else root / GEOMETRY_FILE
    geom = _swatch_geometry(gpath)
    charts, frames = _charts_and_frames(root, manifest.get("captures", {}))
    passes = np.array([int(r.get("pass", 1)) for r in frames])
    if int(passes.max()) > geom.passes:
        raise UsageError(f"{gpath}: the session has frames of {int(passes.max())} passes but the geometry gives "
                         f"{geom.passes} light direction(s); add pass_light_directions (the light of passes 2, "
                         "3, ...)")
    gains_of = _pass_gains(root, gpath, geom, charts, passes)
    angles = np.array([float(r["angle_deg"]) for r in frames])
    px, inside = _inside_pixels(geom, angles, margin_mm)
    images = [_decode(root / r["file"]) for r in frames]
    px = _usable_pixels(root, px, inside, images, max_pixels)
    gain_rows = np.stack([gains_of[int(p)] for p in passes])[:, None, :]
    rgb = np.stack([img.rgb[px[:, 1], px[:, 0]].astype(np.float64) for img in images]) / gain_rows
    measurement = SwatchMeasurement(angles, px, rgb, images[0].cfa_pattern, passes)
    gains = next(iter(gains_of.values())) if len(gains_of) == 1 else np.stack([gains_of[k] for k in sorted(gains_of)])
    return SwatchData(measurement, geom, gains, root)


def _swatch_manifest(root: Path) -> dict[str, Any]:
    """The session's manifest, checked to be a swatch capture."""
    from app.session import Session

    try:
        manifest = Session.read(root)
    except Exception as exc:  # noqa: BLE001 - any unreadable session is one message
        raise UsageError(f"{root}: not a readable capture session ({exc})") from None
    plan = manifest.get("plan", {}) or {}
    if plan.get("kind") != "swatch":
        raise UsageError(f"{root}: a {plan.get('kind', 'unknown')!r} capture, not a swatch capture "
                         "(kogei capture --plan swatch)")
    return manifest


def _swatch_geometry(gpath: Path) -> Any:
    """The set-up (:class:`processing.cloth.swatch_geometry.SwatchGeometry`) from its JSON file."""
    from processing.cloth.swatch_geometry import SwatchGeometry, SwatchGeometryError

    try:
        data = parse_json(gpath.read_bytes(), gpath, "give --geometry FILE.json (camera pose, light direction, "
                                                     "swatch size)")
        return SwatchGeometry.from_dict(data)
    except FileNotFoundError:
        raise UsageError(f"{gpath}: swatch geometry not found; give --geometry FILE.json (camera pose, light "
                         "direction, swatch size)") from None
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    except (SwatchGeometryError, TypeError, AttributeError) as exc:
        raise UsageError(f"{gpath}: {exc}") from None


def _charts_and_frames(root: Path, captures: dict[str, Any]) -> tuple[dict[int, list[dict[str, Any]]],
                                                                      list[dict[str, Any]]]:
    """The chart frames per pass (by file name) and the swatch frames (by pass, then table angle)."""
    charts: dict[int, list[dict[str, Any]]] = {}
    for r in sorted((r for r in captures.values() if r.get("kind") == "chart" and r.get("file")),
                    key=lambda r: r["file"]):
        charts.setdefault(int(r.get("pass", 1)), []).append(r)
    frames = sorted((r for r in captures.values() if r.get("kind") == "frame" and r.get("file")),
                    key=lambda r: (int(r.get("pass", 1)), float(r.get("angle_deg", 0.0))))
    if not charts:
        raise UsageError(f"{root}: no chart frame; the fit calibrates the RAW values with the chart")
    if len(frames) < 3:
        raise UsageError(f"{root}: {len(frames)} swatch frames; the fit needs at least 3 table angles")
    return charts, frames


def _pass_gains(root: Path, gpath: Path, geom: Any, charts: dict[int, list[dict[str, Any]]],
                passes: np.ndarray) -> dict[int, np.ndarray]:
    """Per pass the chart gains of its chart frames, averaged."""
    from processing.cloth.fit import ClothFitError, chart_gains, grid_chart_means

    gains_of = {}
    for p in np.unique(passes):
        # each pass is calibrated by its own chart frames (the lamp moved: its power at the table may differ),
        # averaged: the gain's pixel noise is shared by every frame of the pass
        chart_rgb = []
        for record in charts.get(int(p), charts[min(charts)]):
            chart = _decode(root / record["file"])
            if chart.rgb.shape[:2] != (geom.height // 2, geom.width // 2):
                raise UsageError(f"{gpath}: the frames have {2 * chart.rgb.shape[1]} x {2 * chart.rgb.shape[0]} "
                                 f"photosites, the geometry says {geom.width} x {geom.height}")
            chart_rgb.append(chart.rgb.astype(np.float64))
        try:
            gains_of[int(p)] = chart_gains(grid_chart_means(np.mean(chart_rgb, axis=0)), geom.for_pass(int(p)))
        except ClothFitError as exc:
            raise UsageError(f"{root}: {exc}") from None
    return gains_of


def _inside_pixels(geom: Any, angles: np.ndarray, margin_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Every binned pixel ``(N, 2)`` (x, y) and whether all its photosites see the swatch at every angle."""
    from processing.cloth.swatch_geometry import swatch_samples

    hb, wb = geom.height // 2, geom.width // 2
    ys, xs = np.mgrid[0:hb, 0:wb]
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)
    ok = np.ones(len(px), dtype=bool)
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        s = swatch_samples(geom, angles, 2 * px[:, 0] + dx, 2 * px[:, 1] + dy, margin_mm=margin_mm)
        ok &= s.inside.all(axis=0)
    return px, ok


def _usable_pixels(root: Path, px: np.ndarray, ok: np.ndarray, images: list[Any], max_pixels: int) -> np.ndarray:
    """The inside pixels unclipped in every frame, evenly thinned to ``max_pixels`` (at least 8)."""
    for img in images:
        ok &= ~(img.saturated | img.dead).reshape(-1)
    px = px[ok]
    if px.shape[0] > max_pixels:
        px = px[np.linspace(0, px.shape[0] - 1, max_pixels).round().astype(int)]
    if px.shape[0] < 8:
        raise UsageError(f"{root}: only {px.shape[0]} binned pixels see the swatch at every angle; "
                         "check the geometry file and that the swatch fills the view")
    return px


def fit_figure(data: SwatchData, fit, path: str | Path) -> Path:
    """Measured (left) and fitted (right) swatch responses over table angle, R G B of the mean pixel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = data.measurement
    meas = m.rgb.mean(axis=1)
    pred = fit.predicted.mean(axis=1)
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=True)
    passes = np.unique(m.passes)
    for ax, values, title in ((axes[0], meas, "measured"), (axes[1], pred, "fitted")):
        for c, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            for k, p in enumerate(passes):          # one curve per light position (pass)
                rows = m.passes == p
                label = "RGB"[c] + (f" (light {p})" if passes.size > 1 else "")
                style = ("o" if title == "measured" else "") + ("-", "--", ":", "-.")[k % 4]
                ax.plot(m.angles_deg[rows], values[rows, c], style, color=colour, ms=3, label=label)
                if title == "fitted":
                    ax.plot(m.angles_deg[rows], meas[rows, c], "o", color=colour, ms=2, alpha=0.4)
        ax.set_title(f"{title} (mean of {m.pixels.shape[0]} pixels)")
        ax.set_xlabel("table angle (deg)")
    axes[0].set_ylabel("camera response (chart-calibrated)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"cloth fit: relative residual {100 * fit.relative_residual:.2f} %", fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def fit_report(data: SwatchData, fit) -> dict[str, Any]:
    """JSON-serialisable summary of a fit."""
    return {
        "session": str(data.session),
        "angles": int(data.measurement.angles_deg.size),
        "pixels": int(data.measurement.pixels.shape[0]),
        "parameters": {k: round(v, 6) for k, v in fit.parameters.items()},
        "sigma": {k: (round(v, 6) if math.isfinite(v) else None) for k, v in fit.sigma.items()},
        "fixed": fit.fixed,
        "material": fit.spec,
        "residual_rms": fit.residual_rms,
        "relative_residual": fit.relative_residual,
        "chart_gains": np.asarray(data.gains, dtype=np.float64).tolist(),
    }
