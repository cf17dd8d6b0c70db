"""``kogei spectral``: per-pixel spectral reflectance of a RAW image calibrated by a chart shot.

Matsuda et al., section 4.1, eq. (6)-(10) and the better estimators after it
(docs/colour-pipeline.md):

``kogei spectral estimate IMAGE --chart CHART [--method paper|wiener|rootpoly|more-basis|twolight]
[--second IMAGE2 --second-chart CHART2] [--chart-corners ...] [--mode bin2x2|demosaic] --out RESULT.npz``
decodes both RAW frames (:func:`processing.camera.raw_decode.decode_raw`), finds and
checks the chart (:mod:`processing.camera.chart_detection`,
:mod:`processing.camera.chart_sampling`), fits the chosen estimator for the model
camera and calibrates it to the object camera with the chart's usable patches
(:func:`processing.spectral.estimation.estimator.fit_estimator`, eq. (9)), and writes the
image as basis weights (:func:`processing.spectral.estimation.estimator.spectral_image`).

``kogei spectral at RESULT.npz X Y [--json]`` prints the reflectance at one
pixel with its uncertainty (the method's error on the chart, see below).

The RESULT file (NumPy ``.npz``, no pickled objects) holds

* ``weights`` ``(H, W, p)`` float32, ``basis`` ``(L, p)``, ``wavelengths`` ``(L,)`` nm,
  ``mask`` ``(H, W)`` bool (False: saturated or dead pixels, weights 0);
* ``camera`` ``(H, W, c)`` float32: the image in the model camera's units
  (after the chart transform), which material identification compares
  candidates in (a metal's spectrum is not representable in a small basis);
* ``sensitivities`` ``(L, 3)`` and ``lights`` ``(k, L)`` of the model camera;
* ``method`` and ``metadata`` (a JSON string: the chart checks, condition
  numbers, chart residual and ``chart_rmse``).

``chart_rmse`` is the RMS reflectance error of the calibrated estimator on
the chart's own usable patches.  The estimator is trained on the database
without the near-duplicates of the chart
(:func:`processing.spectral.reflectance_database.without_near_duplicates`), so the
patches are held out from its training; only the 3 x 3 chart transform per
exposure (9 numbers) is fitted on them.  It is the per-pixel uncertainty of
``spectral at`` and the method error of the region spectra of ``kogei identify``.

Exposure: the object and its chart are expected at the same exposure; when
the files' exposure time or ISO differ, the chart's values are scaled by the
ratio of ``time x ISO`` (the raw signal is linear in both).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import UsageError

__all__ = [
    "RESULT_KEYS",
    "METHODS",
    "ChartMeasurement",
    "SpectralResult",
    "add_parser",
    "run",
    "measure_chart",
    "estimate_spectral",
    "save_result",
    "load_result",
    "parse_patch_list",
]

#: Arrays every RESULT.npz holds.
RESULT_KEYS = ("weights", "basis", "wavelengths", "mask", "camera", "sensitivities", "lights", "method", "metadata")
METHODS = ("paper", "wiener", "rootpoly", "more-basis", "twolight")
#: Wavelength grid of the estimate (nm): the range of the training spectra and the camera data.
GRID = (400.0, 700.0, 10.0)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``spectral`` subcommand (``estimate``, ``at``) to ``sub`` and return its parser."""
    p = sub.add_parser(
        "spectral",
        help="spectral reflectance per pixel from a RAW image and its chart shot",
        description="Estimate spectral reflectance as per-pixel basis weights (estimate) and read it back (at).",
    )
    ss = p.add_subparsers(dest="spectral_command", required=True, metavar="ACTION")
    e = ss.add_parser("estimate", help="RAW image + chart shot -> RESULT.npz of basis weights",
                      description="Calibrate a spectral estimator with the chart shot taken with the object and "
                                  "apply it to every pixel of the image.")
    e.add_argument("image", metavar="IMAGE", help="the object's RAW frame (DNG, CR2, NEF, ARW, ...)")
    e.add_argument("--chart", required=True, metavar="CHART", help="RAW frame of the colour chart under the same light")
    e.add_argument("--method", default="rootpoly", choices=METHODS,
                   help="estimator (default rootpoly; twolight needs --second and --second-chart)")
    e.add_argument("--second", default=None, metavar="IMAGE2", help="the same view under the second light (twolight)")
    e.add_argument("--second-chart", default=None, metavar="CHART2", help="the chart under the second light (twolight)")
    e.add_argument("--chart-type", default="classic24", choices=["classic24", "sg140", "vinyl18"])
    e.add_argument("--chart-reflectances", default=None, metavar="CSV",
                   help="the chart's patch reflectances (nm, one column per patch in reading order); "
                        "default: ColorChecker N Ohta for classic24")
    e.add_argument("--chart-corners", default=None, metavar="x1,y1,x2,y2,x3,y3,x4,y4",
                   help="the chart's outer corners in sensor pixels, top-left (next to patch 1) first, clockwise")
    e.add_argument("--second-chart-corners", default=None, metavar="x1,y1,...", help="corners in CHART2")
    e.add_argument("--patches", default=None, metavar="LIST",
                   help="patches used for the calibration, 1-based, e.g. 1-18 or 1,2,5-9 (default: every usable one)")
    e.add_argument("--mode", default="bin2x2", choices=["bin2x2", "demosaic"])
    e.add_argument("--light", default="D65", help="light of IMAGE and CHART (CIE name, CCT such as 3200K, or CSV)")
    e.add_argument("--second-light", default="A", help="light of IMAGE2 and CHART2 (twolight)")
    e.add_argument("--camera", default="Nikon 5100 (NPL)",
                   help="model camera: a colour-science camera name or a CSV of sensitivities (nm, r, g, b)")
    e.add_argument("--database", default="training", help="training reflectances: 'training' or a CSV")
    e.add_argument("--noise", type=float, default=0.01, help="relative noise of the camera values (0.01 = 1 %%)")
    e.add_argument("--out", required=True, metavar="RESULT.npz")
    e.add_argument("--quiet", action="store_true")
    a = ss.add_parser("at", help="the spectrum at one pixel of a RESULT.npz",
                      description="Print the reflectance at pixel (X, Y) of RESULT (image coordinates of the "
                                  "estimate: half the sensor's in bin2x2 mode) with its uncertainty.")
    a.add_argument("result", metavar="RESULT.npz")
    a.add_argument("x", type=int, metavar="X")
    a.add_argument("y", type=int, metavar="Y")
    a.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


# ---------------------------------------------------------------------------------------------- the chart


def parse_patch_list(text: str, count: int) -> NDArray[np.bool_]:
    """A 1-based patch list such as ``"1-18,22"`` as a boolean selection of ``count`` patches.

    Examples
    --------
    >>> parse_patch_list("1-3,6", 6).tolist()
    [True, True, True, False, False, True]
    """
    sel = np.zeros(count, dtype=bool)
    for part in text.split(","):
        part = part.strip()
        try:
            lo, _, hi = part.partition("-")
            a, b = int(lo), int(hi or lo)
        except ValueError:
            raise UsageError(f"--patches {text!r}: {part!r} is not a patch number or a range like 1-18") from None
        if not 1 <= a <= b <= count:
            raise UsageError(f"--patches {text!r}: {part!r} is outside the chart's patches 1-{count}")
        sel[a - 1:b] = True
    return sel


@dataclass(frozen=True)
class ChartMeasurement:
    """A chart shot, decoded, located, sampled and checked.

    Attributes
    ----------
    mean
        ``(N, 3)`` trimmed-mean linear camera RGB per patch (1.0 = saturation).
    usable
        ``(N,)`` patches that passed the checks.
    warnings
        One message per excluded patch.
    exposure
        ``exposure_time * iso`` of the file (0 when it does not say).
    shape
        ``(H, W)`` of the decoded frame.
    method
        ``"mcc"`` or ``"manual"`` (from ``--chart-corners``).
    """

    mean: NDArray[np.float64]
    usable: NDArray[np.bool_]
    warnings: list[str]
    exposure: float
    shape: tuple[int, int]
    method: str


def measure_chart(path: Path, *, chart: str = "classic24", corners: str | None = None,
                  mode: str = "bin2x2") -> ChartMeasurement:
    """Decode, locate, sample and check a chart frame; errors are :class:`UsageError` naming the file."""
    from processing.camera.chart_detection import ChartDetectionError, chart_from_corners, detect_chart, parse_corners
    from processing.camera.chart_sampling import ChartRejectedError, ChartSamplingError, check_patches, sample_patches
    from processing.camera.raw_decode import RawDecodeError, decode_raw

    try:
        img = decode_raw(path, mode=mode)
        h, w = img.shape
        if corners is not None:
            det = chart_from_corners(parse_corners(corners), chart, image_size=(w * img.scale, h * img.scale))
        else:
            det = detect_chart(img, chart)
        samples = sample_patches(img, det)
        check = check_patches(samples)
    except (RawDecodeError, ChartDetectionError, ChartSamplingError, ChartRejectedError) as exc:
        msg = str(exc)
        raise UsageError(msg if os.fspath(path) in msg or path.name in msg else f"{path}: {msg}") from None
    return ChartMeasurement(np.asarray(samples.mean, dtype=np.float64), np.asarray(check.usable, dtype=bool),
                            list(check.warnings), float(img.exposure_time) * float(img.iso), (h, w), det.method)


# ---------------------------------------------------------------------------------------------- the estimate


@dataclass(frozen=True)
class SpectralResult:
    """What ``kogei spectral estimate`` writes (see the module text for each array)."""

    weights: NDArray[np.float32]
    basis: NDArray[np.float64]
    wavelengths: NDArray[np.float64]
    mask: NDArray[np.bool_]
    camera: NDArray[np.float32]
    sensitivities: NDArray[np.float64]
    lights: NDArray[np.float64]
    method: str
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def grid(self):
        """The wavelength grid of the basis (:class:`processing.spectral.spectra.SpectralGrid`)."""
        from processing.spectral.spectra import SpectralGrid

        wl = self.wavelengths
        return SpectralGrid(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))

    @property
    def method_error(self) -> float:
        """RMS reflectance error of the estimate on the chart's patches (``chart_rmse``)."""
        return float(self.metadata.get("chart_rmse", 0.0))


def _decode_image(path: Path, mode: str):
    from processing.camera.raw_decode import RawDecodeError, decode_raw

    try:
        return decode_raw(path, mode=mode)
    except RawDecodeError as exc:
        raise UsageError(str(exc)) from None


def _chart_reflectances(chart: str, csv: str | None, grid) -> NDArray[np.float64]:
    from processing.camera.chart_layout import chart_layout
    from processing.spectral.reflectance_database import ReflectanceDatabaseError, load_reflectances

    n = chart_layout(chart).size
    if csv is None:
        if chart != "classic24":
            raise UsageError(f"--chart-type {chart}: its patches have no published reflectances here; "
                             f"give them with --chart-reflectances CSV ({n} columns)")
        return load_reflectances("colorchecker", grid).spectra
    try:
        spectra = load_reflectances(Path(csv), grid).spectra
    except ReflectanceDatabaseError as exc:
        raise UsageError(f"--chart-reflectances: {exc}") from None
    if spectra.shape[0] != n:
        raise UsageError(f"--chart-reflectances {csv}: {spectra.shape[0]} spectra, but a {chart} chart has {n} patches")
    return spectra


def _scaled(chart: ChartMeasurement, image_exposure: float) -> NDArray[np.float64]:
    # the raw signal is linear in exposure time and ISO: bring the chart to the image's exposure
    if chart.exposure > 0 and image_exposure > 0:
        return chart.mean * (image_exposure / chart.exposure)
    return chart.mean


def estimate_spectral(
    image: Path,
    chart: Path,
    *,
    method: str = "rootpoly",
    second: Path | None = None,
    second_chart: Path | None = None,
    chart_type: str = "classic24",
    chart_reflectances: str | None = None,
    chart_corners: str | None = None,
    second_chart_corners: str | None = None,
    patches: str | None = None,
    mode: str = "bin2x2",
    light: str = "D65",
    second_light: str = "A",
    camera: str = "Nikon 5100 (NPL)",
    database: str = "training",
    noise: float = 0.01,
) -> SpectralResult:
    """Decode, calibrate with the chart and estimate basis weights for every pixel.

    Every bad input raises :class:`UsageError` with a one-line message.
    """
    from processing.camera.response import CameraResponseError, camera_rgb, camera_sensitivities
    from processing.camera.transfer import fit_chart_transform
    from processing.spectral.estimation.estimator import fit_estimator, spectral_image
    from processing.spectral.estimation.fit import SpectralEstimationError
    from processing.spectral.reflectance_database import (
        ReflectanceDatabaseError,
        load_reflectances,
        without_near_duplicates,
    )
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    if method not in METHODS:
        raise UsageError(f"--method {method!r}: choose one of {', '.join(METHODS)}")
    two = method == "twolight"
    if two and (second is None or second_chart is None):
        raise UsageError("--method twolight needs --second IMAGE2 (the same view under the second light) "
                         "and --second-chart CHART2 (the chart under that light)")
    if not two and (second is not None or second_chart is not None):
        raise UsageError(f"--second and --second-chart belong to --method twolight, not {method}")
    if not (isinstance(noise, (int, float)) and math.isfinite(noise) and 0 < noise < 1):
        raise UsageError(f"--noise {noise!r}: give the relative noise of the camera values, e.g. 0.01 for 1 %")
    grid = SpectralGrid(*GRID)
    try:
        sens = camera_sensitivities(grid, camera)
    except (CameraResponseError, ValueError) as exc:
        raise UsageError(f"--camera: {exc}") from None
    names = [light] + ([second_light] if two else [])
    lights = []
    for flag, name in zip(("--light", "--second-light"), names):
        try:
            lights.append(light_spectrum(name, grid))
        except (ValueError, OSError) as exc:
            raise UsageError(f"{flag} {name!r}: {exc}") from None
    refl = _chart_reflectances(chart_type, chart_reflectances, grid)
    try:
        db = load_reflectances(database if database == "training" else Path(database), grid)
        train = without_near_duplicates(db, load_reflectances("colorchecker", grid) if chart_reflectances is None
                                        else load_reflectances(Path(chart_reflectances), grid)).spectra
    except ReflectanceDatabaseError as exc:
        raise UsageError(f"--database: {exc}") from None

    images = [_decode_image(image, mode)] + ([_decode_image(second, mode)] if two else [])
    charts = [measure_chart(chart, chart=chart_type, corners=chart_corners, mode=mode)]
    if two:
        charts.append(measure_chart(second_chart, chart=chart_type, corners=second_chart_corners, mode=mode))
        if images[1].shape != images[0].shape:
            raise UsageError(f"--second {second}: {images[1].shape[1]} x {images[1].shape[0]} pixels, but {image} has "
                             f"{images[0].shape[1]} x {images[0].shape[0]}; the two exposures must be of the same view")
    usable = np.logical_and.reduce([c.usable for c in charts])
    if patches is not None:
        usable &= parse_patch_list(patches, usable.size)
    chart_rgb = np.hstack([_scaled(c, float(im.exposure_time) * float(im.iso)) for c, im in zip(charts, images)])
    e = np.stack(lights) if two else lights[0]
    try:
        fit = fit_estimator(method, train, sens, e, grid, noise=noise, chart_rgb=chart_rgb[usable],
                            chart_reflectance=refl[usable])
        model = camera_rgb(refl[usable], e, sens, grid)
        transform = fit_chart_transform(chart_rgb[usable], model)
    except SpectralEstimationError as exc:
        raise UsageError(f"{chart}: {exc}") from None
    rgb = np.concatenate([im.rgb for im in images], axis=2) if two else images[0].rgb
    mask = np.logical_and.reduce([~(im.saturated | im.dead) for im in images])
    # black-subtracted values may dip below 0 by noise: a reflectance estimate takes them as 0
    rgb = np.maximum(rgb, 0.0, dtype=np.float32)
    try:
        out = spectral_image(fit, rgb, mask=mask)
    except SpectralEstimationError as exc:
        raise UsageError(f"{image}: {exc}") from None
    cam = (rgb.reshape(-1, rgb.shape[2]) @ transform.matrix.astype(np.float32)).reshape(rgb.shape)
    # the transform's negative off-diagonal terms take near-black pixels slightly below 0: clip, and
    # masked pixels hold 0 (their input may be anything)
    np.maximum(cam, 0.0, out=cam)
    cam[~mask] = 0.0
    est = fit.estimate_weights(chart_rgb[usable]).astype(np.float64) @ fit.basis.T
    chart_rmse = float(np.sqrt(np.mean((est - refl[usable]) ** 2)))
    metadata = {
        "format": "kogei-spectral",
        "version": 1,
        "method": method,
        "mode": mode,
        "image": [os.fspath(image)] + ([os.fspath(second)] if two else []),
        "chart": [os.fspath(chart)] + ([os.fspath(second_chart)] if two else []),
        "chart_type": chart_type,
        "chart_found_by": [c.method for c in charts],
        "lights": names,
        "camera": camera,
        "patches_used": [int(k) + 1 for k in np.flatnonzero(usable)],
        "chart_warnings": [w for c in charts for w in c.warnings],
        "condition": {k: float(v) for k, v in fit.condition.items()},
        "chart_residual": float(transform.residual),
        "chart_rmse": chart_rmse,
        "training_rmse": float(fit.training_rmse),
        "training_spectra": int(train.shape[0]),
        "masked_pixels": int((~mask).sum()),
    }
    return SpectralResult(out.weights, np.asarray(fit.basis, dtype=np.float64), grid.wavelengths.copy(), out.mask,
                          cam.astype(np.float32, copy=False), np.asarray(sens, dtype=np.float64),
                          np.atleast_2d(e).astype(np.float64), method, metadata)


def save_result(result: SpectralResult, path: Path) -> Path:
    """Write ``result`` as an uncompressed ``.npz`` (atomically, no pickled objects)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise UsageError(f"--out {path}: the folder {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".spectral-", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            # uncompressed: float weights barely shrink (about 10 %) and zlib took 50x longer (6 s, 2000 x 3000 x 8)
            np.savez(fh, weights=result.weights, basis=result.basis, wavelengths=result.wavelengths,
                     mask=result.mask, camera=result.camera, sensitivities=result.sensitivities,
                     lights=result.lights, method=np.array(result.method),
                     metadata=np.array(json.dumps(result.metadata)))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_result(path: Path) -> SpectralResult:
    """Read a RESULT.npz written by :func:`save_result`; a missing file or key is a :class:`UsageError`."""
    import zipfile

    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such file; give the RESULT.npz written by 'kogei spectral estimate'")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in RESULT_KEYS if k not in z.files]
            if missing:
                raise UsageError(f"{path}: not a spectral result, missing {', '.join(missing)}; "
                                 "write it with 'kogei spectral estimate'")
            data = {k: z[k] for k in RESULT_KEYS}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        if isinstance(exc, UsageError):
            raise
        raise UsageError(f"{path}: not a readable .npz file ({exc}); write it with 'kogei spectral estimate'") from None
    w, b, wl, m = data["weights"], data["basis"], data["wavelengths"], data["mask"]
    if (w.ndim != 3 or b.ndim != 2 or b.shape[1] != w.shape[2] or wl.shape != (b.shape[0],) or wl.size < 2
            or m.shape != w.shape[:2] or m.dtype != bool or data["camera"].shape[:2] != w.shape[:2]):
        raise UsageError(f"{path}: inconsistent arrays (weights {w.shape}, basis {b.shape}, wavelengths {wl.shape}, "
                         f"mask {m.shape}); write it again with 'kogei spectral estimate'")
    try:
        meta = json.loads(str(data["metadata"]))
    except json.JSONDecodeError:
        raise UsageError(f"{path}: its metadata is not JSON; write it again with 'kogei spectral estimate'") from None
    return SpectralResult(w, b, wl, m, data["camera"], data["sensitivities"], data["lights"], str(data["method"]), meta)


# ---------------------------------------------------------------------------------------------- the commands


def _run_estimate(args: argparse.Namespace) -> int:
    for flag, value in (("IMAGE", args.image), ("--chart", args.chart), ("--second", args.second),
                        ("--second-chart", args.second_chart)):
        if value is not None and not Path(value).exists():
            raise UsageError(f"{flag} {value}: no such file")
    if not Path(args.out).parent.is_dir():       # before the work, not after it
        raise UsageError(f"--out {args.out}: the folder {Path(args.out).parent} does not exist")
    result = estimate_spectral(
        Path(args.image), Path(args.chart), method=args.method,
        second=None if args.second is None else Path(args.second),
        second_chart=None if args.second_chart is None else Path(args.second_chart),
        chart_type=args.chart_type, chart_reflectances=args.chart_reflectances, chart_corners=args.chart_corners,
        second_chart_corners=args.second_chart_corners, patches=args.patches, mode=args.mode, light=args.light,
        second_light=args.second_light, camera=args.camera, database=args.database, noise=args.noise,
    )
    save_result(result, Path(args.out))
    if not args.quiet:
        h, w, p = result.weights.shape
        md = result.metadata
        print(f"{Path(args.out).name}: {w} x {h} pixels, {p} basis weights ({result.method}); "
              f"{len(md['patches_used'])} chart patches, condition {md['condition'].get('chart', float('nan')):.3g}, "
              f"chart RMSE {md['chart_rmse']:.4f}; {md['masked_pixels']} pixels masked")
        for line in md["chart_warnings"]:
            print(f"  {line}")
    return 0


def _run_at(args: argparse.Namespace) -> int:
    res = load_result(Path(args.result))
    h, w = res.mask.shape
    if not (0 <= args.x < w and 0 <= args.y < h):
        raise UsageError(f"pixel ({args.x}, {args.y}) is outside the image of {w} x {h} pixels "
                         f"(x in 0-{w - 1}, y in 0-{h - 1})")
    if not res.mask[args.y, args.x]:
        raise UsageError(f"pixel ({args.x}, {args.y}) is masked (saturated or dead in the RAW); pick another pixel")
    spectrum = res.weights[args.y, args.x].astype(np.float64) @ res.basis.T
    err = res.method_error
    if args.json:
        print(json.dumps({"x": args.x, "y": args.y, "method": res.method,
                          "wavelengths": res.wavelengths.tolist(), "reflectance": spectrum.tolist(),
                          "uncertainty": err}))
    else:
        print(f"pixel ({args.x}, {args.y}), {res.method}; uncertainty +-{err:.3f} (RMS error on the chart)")
        print("nm  reflectance")
        for lam, v in zip(res.wavelengths, spectrum):
            print(f"{lam:.0f} {v:.4f}")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``kogei spectral estimate`` or ``kogei spectral at``; returns the exit status."""
    if args.spectral_command == "estimate":
        return _run_estimate(args)
    return _run_at(args)
