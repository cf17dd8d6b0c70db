"""A light probe: exposure brackets of a mirror sphere -> a spectral environment map in the room frame.

:func:`build_probe` is the one chain ``kogei probe`` (and anything else that makes a probe) calls:

1. **merge** the brackets into linear HDR camera RGB (:func:`processing.lighting.hdr_merge.merge_brackets`,
   exposures from each file's shutter, aperture and ISO);
2. **find the sphere** in the HDR image with the station's sphere finding
   (:func:`processing.geometry.sphere_image.sphere_silhouette` and
   :func:`processing.geometry.sphere_image.fit_sphere_centre`, as the lamp calibration does) and place it
   with the station's camera calibration (intrinsics and ``room_to_camera``);
3. **unwrap** it into an equirectangular map in the room frame, the caps toward and away from the camera
   marked and filled (:func:`processing.lighting.probe_unwrap.unwrap_probe`);
4. make it **spectral** with the chart shot in the same light: the chart frame's patches calibrate the
   project's estimator (:func:`processing.spectral.estimation.estimator.fit_estimator`, the same setup as
   :func:`app.workflows.spectral.estimator_setup`), whose linear map from camera RGB to spectra becomes the
   map's basis (:func:`processing.lighting.probe_spectral.probe_environment`).

:func:`write_probe` writes the map as OpenEXR (:func:`processing.lighting.environment_map.write_environment`)
and a JSON report next to it (``probe.json`` for ``probe.exr``).  The inputs are RAW files, a folder of RAW
files, or a session captured with ``kogei capture --plan probe`` (its brackets and chart frame).
docs/lighting.md describes the capture and each step's cost and error.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError

__all__ = ["ProbeResult", "ProbeInputs", "probe_inputs", "build_probe", "write_probe", "RAW_SUFFIXES",
           "MAX_OUTLINE_RMS_PX", "FIND_WIDTH_PX", "SPHERE_RADIUS_MM", "record_probe", "PROBE_FILE", "PROBE_REPORT_FILE"]

#: File name endings taken as RAW frames in a folder.
RAW_SUFFIXES = (".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2")
#: A sphere outline fitting worse than this (px RMS) is not the probe sphere of the given radius.
MAX_OUTLINE_RMS_PX = 1.0
#: The mirror sphere's radius a probe accepts (mm), inclusive: a 2 mm ball bearing to a 1 m garden globe.
SPHERE_RADIUS_MM = (1.0, 500.0)
#: The sphere is found on the HDR image binned to at most this width (px).
FIND_WIDTH_PX = 2000
#: Where a probe session keeps its map and the map's report (``products.probe``, ``products.probe_report``).
PROBE_FILE = "products/probe.exr"
PROBE_REPORT_FILE = "products/probe.json"


@dataclass
class ProbeInputs:
    """The brackets, the chart frame and the camera calibration a probe is made from."""

    frames: list[Path]
    chart: Path | None
    camera_calibration: Any = None
    sphere_radius_mm: float | None = None
    source: str = ""
    session: Path | None = None       # the probe session the frames came from, if any
    filter_frames: list[Path] = field(default_factory=list)   # a second bracket set through a colour filter
    filter_chart: Path | None = None  # the chart shot through that filter
    filter_transmission: Path | None = None    # the filter's transmission (CSV)


@dataclass
class ProbeResult:
    """A probe and how it was made.

    Attributes
    ----------
    environment
        The spectral map (:class:`processing.lighting.environment_map.EnvironmentMap`).
    observed
        ``(H, 2H)`` bool: directions seen on the sphere.
    report
        JSON-ready figures: frames and their settings, the sphere, the masked caps, the chart
        calibration, timings.
    """

    environment: Any
    observed: np.ndarray = field(repr=False)
    report: dict[str, Any] = field(default_factory=dict)


def _raw_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in RAW_SUFFIXES)


def probe_inputs(sources: Sequence[str | os.PathLike[str]], *, chart: str | None = None,
                 camera_calibration: str | None = None, sphere_radius_mm: float | None = None,
                 filter_frames: str | None = None, filter_chart: str | None = None,
                 filter_transmission: str | None = None) -> ProbeInputs:
    """The probe's inputs from the command line's SESSION_OR_FRAMES and options.

    A session folder (``session.json``) of a ``probe`` plan gives its brackets, its chart frame, its
    sphere radius and, when installed, its camera calibration; any folder else gives its RAW files;
    files are the brackets themselves.  ``chart``, ``camera_calibration`` and ``sphere_radius_mm``
    override the session's.  ``filter_frames`` (a probe session or a folder of RAW files) is the second
    bracket set, shot through the filter whose transmission CSV is ``filter_transmission``, with its
    chart frame (the session's, or ``filter_chart``).
    """
    from app.workflows.station_calibration import load_station_source, parse_station_calibration

    paths = [Path(s) for s in sources]
    if not paths:
        raise UsageError("give the brackets' RAW files, a folder of them or a probe session")
    inputs = ProbeInputs([], None, None, sphere_radius_mm, ", ".join(str(p) for p in paths))
    if len(paths) == 1 and paths[0].is_dir():
        if (paths[0] / "session.json").is_file():
            inputs = _session_inputs(paths[0], sphere_radius_mm)
        else:
            inputs.frames = [p for p in _raw_files(paths[0]) if chart is None or p.resolve() != Path(chart).resolve()]
            if not inputs.frames:
                raise UsageError(f"{paths[0]}: no RAW files ({', '.join(RAW_SUFFIXES)}) in this folder")
    else:
        for p in paths:
            if not p.is_file():
                raise UsageError(f"{p}: no such RAW file; give the brackets' files, a folder of them or a session")
        inputs.frames = paths
    if chart is not None:
        inputs.chart = Path(chart)
    if camera_calibration is not None:
        data = load_station_source(camera_calibration, "camera_calibration")
        inputs.camera_calibration = parse_station_calibration("camera_calibration", data,
                                                              f"--camera-calibration {camera_calibration}")
    if inputs.chart is None:
        raise UsageError(f"{inputs.source}: no chart frame; give --chart RAW (the colour chart shot in the same "
                         "light) so the probe can be made spectral")
    if inputs.camera_calibration is None:
        raise UsageError(f"{inputs.source}: no camera calibration; give --camera-calibration BOARD_SESSION (or its "
                         "camera_calibration.json) so the sphere can be placed in the room")
    if inputs.camera_calibration.room_to_camera is None:
        raise UsageError(f"--camera-calibration {camera_calibration}: the camera is not tied to the room (scanner) "
                         "frame; calibrate it with --scanner SPHERE_SESSION")
    if inputs.sphere_radius_mm is None:
        raise UsageError(f"{inputs.source}: give the mirror sphere's radius with --sphere-radius MM")
    _filter_inputs(inputs, filter_frames, filter_chart, filter_transmission)
    r = inputs.sphere_radius_mm
    lo, hi = SPHERE_RADIUS_MM
    if isinstance(r, bool) or not isinstance(r, (int, float)) or not (math.isfinite(r) and lo <= r <= hi):
        raise UsageError(f"--sphere-radius must be the mirror sphere's radius in mm, {lo:g} to {hi:g} (half its "
                         f"diameter), got {r!r}")
    return inputs


def _filter_inputs(inputs: ProbeInputs, frames: str | None, chart: str | None, transmission: str | None) -> None:
    """The filtered bracket set, its chart and the filter's transmission into ``inputs`` (all or none)."""
    if frames is None:
        if chart is not None or transmission is not None:
            raise UsageError("--filter-chart and --filter belong to --filter-frames (the bracket set shot through "
                             "the filter); give it too, or neither")
        return
    if transmission is None:
        raise UsageError(f"--filter-frames {frames}: give the filter's transmission with --filter CSV "
                         "(wavelength_nm, transmission 0-1, from its data sheet)")
    folder = Path(frames)
    if not folder.is_dir():
        raise UsageError(f"--filter-frames {folder}: not a folder; give the probe session or the folder of the "
                         "brackets shot through the filter")
    if (folder / "session.json").is_file():
        second = _session_inputs(folder, inputs.sphere_radius_mm)
        inputs.filter_frames, inputs.filter_chart = second.frames, second.chart
    else:
        inputs.filter_frames = [p for p in _raw_files(folder)
                                if chart is None or p.resolve() != Path(chart).resolve()]
        if not inputs.filter_frames:
            raise UsageError(f"--filter-frames {folder}: no RAW files ({', '.join(RAW_SUFFIXES)}) in this folder")
    if chart is not None:
        inputs.filter_chart = Path(chart)
    shared = {p.resolve() for p in inputs.filter_frames} & {p.resolve() for p in inputs.frames}
    if shared:
        raise UsageError(f"--filter-frames {folder}: {sorted(shared)[0].name} is also one of the brackets without the "
                         "filter; give the set shot through the filter")
    if inputs.filter_chart is None:
        raise UsageError(f"--filter-frames {folder}: no chart frame shot through the filter; give --filter-chart RAW")
    inputs.filter_transmission = Path(transmission)
    if not inputs.filter_transmission.is_file():
        raise UsageError(f"--filter {transmission}: no such file; give the filter's transmission as a CSV of "
                         "wavelength_nm, transmission rows")


def _session_inputs(root: Path, sphere_radius_mm: float | None) -> ProbeInputs:
    """A ``probe`` session's brackets, chart frame, sphere radius and camera calibration."""
    from app.session import Session, SessionError
    from app.session_paths import confined_file
    from app.workflows.station_calibration import session_camera_calibration

    try:
        manifest = Session.read(root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    plan = manifest.get("plan") or {}
    if plan.get("kind") != "probe":
        raise UsageError(f"session {root} is a {plan.get('kind')!r} capture, not a probe; capture the mirror sphere "
                         "with 'kogei capture --plan probe'")
    frames, chart = [], None
    for cid, rec in sorted((manifest.get("captures") or {}).items()):
        if not isinstance(rec, dict) or rec.get("status") != "done":
            continue
        try:
            path = confined_file(root, rec.get("file"), f"captures.{cid}.file")
        except FileNotFoundError:
            raise UsageError(f"session {root}: {rec.get('file')} ({cid}) is missing; capture the probe again") from None
        if rec.get("kind") == "chart":
            chart = path
        elif rec.get("kind") == "frame":
            frames.append(path)
    if not frames:
        raise UsageError(f"session {root} has no bracket frames; capture them with 'kogei capture --plan probe'")
    radius = sphere_radius_mm if sphere_radius_mm is not None else plan.get("sphere_radius_mm")
    return ProbeInputs(frames, chart, session_camera_calibration(root, manifest), radius, str(root), root)


def _find_sphere(hdr, calib, radius_mm: float, name: str) -> tuple[np.ndarray, float]:
    """The sphere's centre (camera frame, mm) from its outline in the HDR image.

    Found on the image binned by the smallest integer factor that brings it to at most
    :data:`FIND_WIDTH_PX` wide (a 24-megapixel frame: 4, about 50 times less work), with the
    calibration's intrinsics for that size.
    """
    import cv2

    from processing.geometry.sphere_image import (
        SphereImageError,
        fit_sphere_centre,
        sphere_radius_px,
        sphere_silhouette,
    )

    h, w = hdr.shape
    b = next(f for f in range(1, w + 1) if w % f == 0 and h % f == 0 and (w // f <= FIND_WIDTH_PX or f == w))
    img = hdr.rgb if b == 1 else cv2.resize(hdr.rgb, (w // b, h // b), interpolation=cv2.INTER_AREA)
    try:
        k, dist = calib.for_image_size(w // b, h // b)
    except Exception as exc:  # noqa: BLE001 - CameraCalibrationError is the geometry domain's InputError
        raise UsageError(f"{name}: {exc}") from None
    try:
        edge = sphere_silhouette(img, name=name)
        centre, _, rms = fit_sphere_centre(edge, k, dist, radius_mm)
        sphere_radius_px(centre, radius_mm, k, (w // b, h // b), name)
    except SphereImageError as exc:
        msg = str(exc)
        raise UsageError(msg if name in msg else f"{name}: {msg}") from None
    if rms > MAX_OUTLINE_RMS_PX:
        raise UsageError(f"{name}: no probe sphere of radius {radius_mm:g} mm found (the outline found fits a sphere "
                         f"with {rms:.2f} px RMS > {MAX_OUTLINE_RMS_PX:g} px); check --sphere-radius and that the "
                         "sphere stands whole in front of a plain backdrop")
    return centre, float(rms)


def _chart_rgb(chart: Path, chart_type: str, decode: str, f_number: float | None):
    """The chart frame's patch means in the HDR image's units (exposure by its metadata) and its measurement."""
    from app.workflows.chart import measure_chart
    from processing.camera.raw_decode import decode_raw
    from processing.lighting.hdr_merge import exposure_scale, exposure_settings

    ch = measure_chart(chart, chart=chart_type, mode=decode)
    scale = exposure_scale(*exposure_settings(decode_raw(chart, mode="bin2x2"), f_number))
    return ch.mean * scale, ch


def _chart_fit(chart: Path, *, light: str, method: str, chart_type: str, decode: str, f_number: float | None,
               noise: float, filter_chart: Path | None = None,
               transmission: Path | None = None) -> tuple[Any, Any, dict[str, Any]]:
    """The estimator calibrated by the chart frame (and the chart through the filter), in the HDR image's units."""
    from app.workflows.spectral import estimator_setup
    from processing.errors import InputError
    from processing.spectral.estimation.estimator import fit_estimator
    from processing.spectral.estimation.fit import SpectralEstimationError
    from processing.spectral.spectra import transmission_spectrum

    setup = estimator_setup(light=light, chart_type=chart_type)
    rgb, ch = _chart_rgb(chart, chart_type, decode, f_number)
    usable = ch.usable
    warnings = list(ch.warnings)
    lights = setup.lights[0]
    info: dict[str, Any] = {}
    if filter_chart is not None:
        try:
            t = transmission_spectrum(transmission, setup.grid)
        except InputError as exc:
            raise UsageError(f"--filter {exc}" if str(transmission) not in str(exc) else str(exc)) from None
        rgb2, ch2 = _chart_rgb(filter_chart, chart_type, decode, f_number)
        rgb = np.hstack([rgb, rgb2])
        usable = usable & ch2.usable
        warnings += list(ch2.warnings)
        lights = np.stack([setup.lights[0], setup.lights[0] * t])
        info = {"filter_chart": os.fspath(filter_chart), "filter": os.fspath(transmission),
                "filter_transmission_mean": float(t.mean())}
    try:
        fit = fit_estimator(method, setup.training, setup.sensitivities, lights, setup.grid, noise=noise,
                            chart_rgb=rgb[usable], chart_reflectance=setup.reflectances[usable])
    except SpectralEstimationError as exc:
        raise UsageError(f"{chart}: {exc}") from None
    est = fit.estimate_weights(rgb[usable]).astype(np.float64) @ fit.basis.T
    info = {"chart": os.fspath(chart), "chart_type": chart_type, "light": light, "method": method,
            "patches_used": int(usable.sum()), "chart_warnings": warnings,
            "chart_rmse": float(np.sqrt(np.mean((est - setup.reflectances[usable]) ** 2))), **info}
    return fit, setup.lights[0], info


def build_probe(inputs: ProbeInputs, *, light: str = "D65", method: str | None = None, chart_type: str = "classic24",
                decode: str = "demosaic", reflectance: float = 0.6, height: int | None = None,
                f_number: float | None = None, camera_mask_deg: float = 12.0, back_mask_deg: float = 45.0,
                noise: float = 0.01, components: int | None = None,
                message: Callable[[str], None] | None = None) -> ProbeResult:
    """Merge, find the sphere, unwrap, make spectral (see the module).

    ``method``: the estimator; default ``wiener`` for one bracket set, ``twolight`` (the root
    polynomial of six channels) when ``inputs`` has a set shot through a filter, the only one that reads
    six.  ``components``: basis spectra of a two-set map
    (:data:`processing.lighting.probe_spectral.COMPONENTS` by default).

    Every bad input raises :class:`processing.errors.InputError` with a one-line message naming the file.
    """
    from processing.lighting.hdr_merge import merge_brackets
    from processing.lighting.nmf_lee2001 import MAX_COMPONENTS
    from processing.lighting.probe_spectral import COMPONENTS, probe_environment, two_set_environment
    from processing.lighting.probe_unwrap import MIN_REFLECTANCE, unwrap_probe

    if isinstance(reflectance, bool) or not isinstance(reflectance, (int, float)) or not (
            math.isfinite(reflectance) and MIN_REFLECTANCE <= reflectance <= 1.0):
        raise UsageError(f"--sphere-reflectance must be the mirror's reflectance, {MIN_REFLECTANCE:g} to 1 (chrome is "
                         f"about 0.6; under {MIN_REFLECTANCE:g} it is not a mirror), got {reflectance!r}")
    note = message or (lambda text: None)
    two = bool(inputs.filter_frames)
    if method is None:
        method = "twolight" if two else "wiener"
    if two != (method == "twolight"):
        raise UsageError("--method twolight reads two bracket sets: give --filter-frames, --filter-chart and --filter"
                         if not two else f"--method {method} reads one bracket set; two (--filter-frames) are read by "
                         "the default, twolight")
    if components is not None and not two:
        raise UsageError("--components sets the basis of a map from two bracket sets; give --filter-frames too")
    if components is not None and (isinstance(components, bool) or not isinstance(components, int)
                                   or not 1 <= components <= MAX_COMPONENTS):
        raise UsageError(f"--components must be 1-{MAX_COMPONENTS} basis spectra, got {components!r}")
    t0 = time.perf_counter()
    fit, chart_light, chart_info = _chart_fit(inputs.chart, light=light, method=method, chart_type=chart_type,
                                              decode=decode, f_number=f_number, noise=noise,
                                              filter_chart=inputs.filter_chart,
                                              transmission=inputs.filter_transmission)
    t1 = time.perf_counter()
    hdr = merge_brackets(inputs.frames, mode=decode, f_number=f_number)
    for line in hdr.notes:
        note(line)
    hdr2 = None
    if two:
        hdr2 = merge_brackets(inputs.filter_frames, mode=decode, f_number=f_number)
        for line in hdr2.notes:
            note(f"through the filter: {line}")
        if hdr2.shape != hdr.shape:
            raise UsageError(f"--filter-frames {inputs.filter_frames[0]}: {hdr2.shape[1]} x {hdr2.shape[0]} pixels, "
                             f"but the brackets are {hdr.shape[1]} x {hdr.shape[0]}; shoot both sets from one place")
    t2 = time.perf_counter()
    name = f"{inputs.frames[0]} (HDR of {len(inputs.frames)} brackets)"
    calib = inputs.camera_calibration
    h_img, w_img = hdr.shape
    try:
        k, dist = calib.for_image_size(w_img, h_img)
    except Exception as exc:  # noqa: BLE001 - CameraCalibrationError is the geometry domain's InputError
        raise UsageError(f"{inputs.frames[0]}: {exc}") from None
    centre, rms = _find_sphere(hdr, calib, float(inputs.sphere_radius_mm), name)
    unwrap = unwrap_probe(hdr.rgb, centre, float(inputs.sphere_radius_mm), k, dist, calib.room_to_camera,
                          height=height, reflectance=reflectance, camera_mask_deg=camera_mask_deg,
                          back_mask_deg=back_mask_deg)
    for line in unwrap.notes:
        note(line)
    t3 = time.perf_counter()
    if hdr2 is None:
        env = probe_environment(unwrap.rgb, fit, chart_light, source=f"probe {inputs.source}")
    else:
        # the filter is in front of the lens: the same sphere, the same pixels
        second = unwrap_probe(hdr2.rgb, centre, float(inputs.sphere_radius_mm), k, dist, calib.room_to_camera,
                              height=height, reflectance=reflectance, camera_mask_deg=camera_mask_deg,
                              back_mask_deg=back_mask_deg)
        del hdr2
        env, kept = two_set_environment(np.concatenate([unwrap.rgb, second.rgb], axis=2), fit, chart_light,
                                        components=COMPONENTS if components is None else components,
                                        source=f"probe {inputs.source}")
        chart_info = {**chart_info, "filter_frames": [os.fspath(p) for p in inputs.filter_frames], **kept}
        note(f"the map keeps {kept['components']} basis spectra: 99 % of directions within "
             f"{kept['projection_dxy_p99']:.4f} in xy of the estimated spectra")
    t4 = time.perf_counter()
    lum = env.pixel_luminance()
    report = {
        "format": "kogei-probe", "version": 1,
        "frames": [os.fspath(p) for p in inputs.frames],
        "settings": [{"exposure_time_s": t, "f_number": n, "iso": s} for t, n, s in hdr.settings],
        "decode": decode, "image_size": [w_img, h_img],
        "saturated_everywhere_fraction": float(hdr.saturated.mean()),
        "sphere": {"radius_mm": float(inputs.sphere_radius_mm), "centre_room_mm": unwrap.sphere_centre_mm.tolist(),
                   "outline_rms_px": rms, "radius_px": unwrap.radius_px, "reflectance": reflectance},
        "map": {"height": env.height, "width": env.width, "frame": "room (table at angle 0): z up, row 0 zenith",
                "toward_camera": unwrap.toward_camera.tolist(), "camera_mask_deg": camera_mask_deg,
                "back_mask_deg": back_mask_deg, "observed_fraction": float(unwrap.observed.mean()),
                "luminance_max": float(lum.max()), "luminance_mean": float(
                    (lum * env.solid_angles()).sum() / (env.solid_angles().sum() * env.width)),
                "units": "luminance relative to a white diffuser where the chart lies"},
        "spectral": chart_info,
        "seconds": {"chart": t1 - t0, "merge": t2 - t1, "unwrap": t3 - t2, "spectral": t4 - t3},
        "notes": hdr.notes + unwrap.notes,
    }
    return ProbeResult(env, unwrap.observed, report)


def write_probe(result: ProbeResult, out: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Write the map (``.exr``) and its report (the same name, ``.json``); returns both paths."""
    from processing.common.files import atomic_path
    from processing.lighting.environment_map import write_environment

    p = Path(out)
    if p.suffix.lower() != ".exr":
        raise UsageError(f"--out {p}: a probe is written as OpenEXR; give a file name ending in .exr")
    if not p.parent.is_dir():
        raise UsageError(f"--out {p}: the folder {p.parent} does not exist; create it first")
    with atomic_path(p, durable=False, make_parents=False) as tmp:     # the temporary name ends in .exr too
        write_environment(tmp, result.environment)
    report_path = p.with_suffix(".json")
    with atomic_path(report_path, durable=False, make_parents=False) as tmp:
        tmp.write_text(json.dumps(result.report, indent=1), encoding="utf-8")
    return p, report_path


def record_probe(session_root: str | os.PathLike[str], result: ProbeResult) -> tuple[Path, Path]:
    """Keep the probe in its session: :data:`PROBE_FILE` and :data:`PROBE_REPORT_FILE`, in the manifest.

    The session report (``kogei report``) shows them.  Returns both paths.
    """
    import tempfile

    from app.session import Session, SessionError
    from processing.lighting.environment_map import write_environment

    root = Path(session_root)
    with tempfile.TemporaryDirectory(prefix="kogei-probe-") as tmp:
        exr = write_environment(Path(tmp) / "probe.exr", result.environment).read_bytes()
    report = json.dumps(result.report, indent=1).encode("utf-8")
    try:
        with Session.open(root) as session:
            info = session.write_file(PROBE_FILE, exr)
            rep = session.write_file(PROBE_REPORT_FILE, report)
            products = dict(session.manifest.get("products") or {})
            products["probe"] = {"file": info.path, "sha256": info.sha256, "bytes": info.bytes}
            products["probe_report"] = {"file": rep.path, "sha256": rep.sha256, "bytes": rep.bytes}
            session.update("products", products)
    except SessionError as exc:
        raise UsageError(f"{exc}; or give the brackets' files instead of the session") from None
    return root / PROBE_FILE, root / PROBE_REPORT_FILE
