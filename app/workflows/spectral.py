"""Per-pixel spectral reflectance of a RAW frame, calibrated by a chart shot.

Matsuda et al., section 4.1, eq. (6)-(10), and the better estimators after it
(docs/colour-pipeline.md, "Spectral estimation" and "Command line").
:func:`estimate_from_chart` is the one chain from a decoded object frame and a
chart measurement to per-pixel basis weights: ``kogei spectral estimate``
(:func:`estimate_spectral`), the window's spectra panel, the batch's materials
step and the colour demo all call it, so they give the same weights for the
same frame and chart.  It

* brings the chart to the object frame's exposure (the raw signal is linear
  in exposure time and ISO: the chart's values are scaled by the ratio of
  ``time x ISO``);
* fits the chosen estimator for the model camera on the training
  reflectances without the near-duplicates of the chart
  (:func:`processing.spectral.reflectance_database.without_near_duplicates`,
  so the chart's patches are held out of the training) and calibrates it to
  the object camera with the chart's usable patches
  (:func:`processing.spectral.estimation.estimator.fit_estimator`, eq. (9));
* estimates every pixel that is neither saturated nor dead
  (:func:`processing.spectral.estimation.estimator.spectral_image`) and
  carries the image into the model camera's units with the chart transform
  (:func:`processing.camera.transfer.fit_chart_transform`), which material
  identification compares candidates in;
* measures ``chart_rmse``, the RMS reflectance error of the calibrated
  estimator on the chart's own usable patches (only the 3 x 3 chart transform
  per exposure is fitted on them): the per-pixel uncertainty of ``kogei
  spectral at`` and the method error of region spectra.

The RESULT file :func:`save_result` writes (NumPy ``.npz``, no pickled
objects) holds :data:`RESULT_KEYS`:

* ``weights`` ``(H, W, p)`` float32, ``basis`` ``(L, p)``, ``wavelengths`` ``(L,)`` nm,
  ``mask`` ``(H, W)`` bool (False: saturated or dead pixels, weights 0);
* ``camera`` ``(H, W, c)`` float32: the image in the model camera's units
  (after the chart transform; a metal's spectrum is not representable in a
  small basis, so identification works on these);
* ``sensitivities`` ``(L, 3)`` and ``lights`` ``(k, L)`` of the model camera;
* ``method`` and ``metadata`` (a JSON string: the chart checks, condition
  numbers, chart residual and ``chart_rmse``).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import UsageError
from app.workflows.chart import ChartMeasurement, measure_chart
from processing.common.files import JSONFileError, atomic_path, parse_json

__all__ = [
    "RESULT_KEYS",
    "METHODS",
    "GRID",
    "EstimatorSetup",
    "ChartEstimate",
    "SpectralResult",
    "estimator_setup",
    "estimate_from_chart",
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


# ---------------------------------------------------------------------------------------------- the estimator


@dataclass(frozen=True)
class EstimatorSetup:
    """What an estimate is computed for: the grid, the model camera, the lights, the chart and the training set.

    Attributes
    ----------
    grid
        Wavelength grid (:data:`GRID`).
    sensitivities
        ``(L, 3)`` model-camera sensitivities.
    lights
        One ``(L,)`` light per exposure (two for ``twolight``).
    light_names
        The lights as given.
    reflectances
        ``(N, L)`` reflectances of the chart's patches.
    training
        ``(n, L)`` training reflectances, less the chart's near-duplicates.
    """

    grid: Any
    sensitivities: NDArray[np.float64]
    lights: list[NDArray[np.float64]]
    light_names: list[str]
    reflectances: NDArray[np.float64]
    training: NDArray[np.float64]


def _chart_reflectances(chart: str, csv: str | None, grid) -> NDArray[np.float64]:
    """The chart's patch reflectances: ColorChecker N Ohta for classic24, else the CSV's."""
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


def estimator_setup(*, two: bool = False, chart_type: str = "classic24", chart_reflectances: str | None = None,
                    light: str = "D65", second_light: str = "A", camera: str = "Nikon 5100 (NPL)",
                    database: str = "training") -> EstimatorSetup:
    """Load the model camera, the light(s), the chart's reflectances and the training set; bad names are UsageErrors.

    ``two``: two exposures (``twolight``), the second under ``second_light``.
    """
    from processing.camera.response import CameraResponseError, camera_sensitivities
    from processing.spectral.reflectance_database import (
        ReflectanceDatabaseError,
        load_reflectances,
        without_near_duplicates,
    )
    from processing.spectral.spectra import SpectralGrid, light_spectrum

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
    return EstimatorSetup(grid, sens, lights, names, refl, train)


@dataclass(frozen=True)
class ChartEstimate:
    """An object frame (two for ``twolight``) as basis weights, calibrated by its chart.

    Attributes
    ----------
    weights
        ``(H, W, p)`` float32 basis weights; 0 where ``mask`` is False.
    mask
        ``(H, W)`` True where no exposure's photosite was saturated or dead.
    camera
        ``(H, W, c)`` float32: the image in the model camera's units (chart transform, clipped at 0; 0 where
        masked).
    fit
        The calibrated estimator (:class:`processing.spectral.estimation.fit.SpectralFit`).
    transform
        The chart transform object camera -> model camera
        (:class:`processing.camera.transfer.ChartTransform`).
    usable
        ``(N,)`` the chart patches the calibration used.
    chart_rmse
        RMS reflectance error of the estimate on those patches.
    lights
        ``(L,)`` light, or ``(2, L)`` lights for ``twolight``.
    """

    weights: NDArray[np.float32]
    mask: NDArray[np.bool_]
    camera: NDArray[np.float32]
    fit: Any
    transform: Any
    usable: NDArray[np.bool_]
    chart_rmse: float
    lights: NDArray[np.float64]


def _scaled(chart: ChartMeasurement, image_exposure: float) -> NDArray[np.float64]:
    """The chart's patch means brought to the image's exposure (the raw signal is linear in time and ISO)."""
    if chart.exposure > 0 and image_exposure > 0:
        return chart.mean * (image_exposure / chart.exposure)
    return chart.mean


def estimate_from_chart(images: Sequence[Any], charts: Sequence[ChartMeasurement], setup: EstimatorSetup, *,
                        method: str = "rootpoly", noise: float = 0.01, patches: NDArray[np.bool_] | None = None,
                        image_name: str = "the object frame", chart_name: str = "the chart frame") -> ChartEstimate:
    """Calibrate the estimator with the chart(s) and estimate basis weights for every pixel of the image(s).

    Parameters
    ----------
    images
        Decoded object frames (:class:`processing.camera.raw_decode.RawImage`): one, or two of the same view
        under the two lights of ``twolight``.
    charts
        The chart measured under each frame's light (:func:`app.workflows.chart.measure_chart`, or
        :meth:`ChartMeasurement.from_report`).
    setup
        Camera, lights, chart reflectances and training set (:func:`estimator_setup`).
    method
        One of :data:`METHODS`.
    noise
        Relative noise of the camera values.
    patches
        Patches the calibration may use (default: every usable one).
    image_name, chart_name
        How error messages name the frame and the chart.

    Returns
    -------
    ChartEstimate
        Weights, mask, model-camera image, the calibrated fit and ``chart_rmse``.
    """
    from processing.camera.response import camera_rgb
    from processing.camera.transfer import fit_chart_transform
    from processing.spectral.estimation.estimator import fit_estimator, spectral_image
    from processing.spectral.estimation.fit import SpectralEstimationError

    two = method == "twolight"
    grid, sens, refl = setup.grid, setup.sensitivities, setup.reflectances
    usable = np.logical_and.reduce([c.usable for c in charts])
    if patches is not None:
        usable &= patches
    chart_rgb = np.hstack([_scaled(c, float(im.exposure_time) * float(im.iso)) for c, im in zip(charts, images)])
    e = np.stack(setup.lights) if two else setup.lights[0]
    try:
        fit = fit_estimator(method, setup.training, sens, e, grid, noise=noise, chart_rgb=chart_rgb[usable],
                            chart_reflectance=refl[usable])
        model = camera_rgb(refl[usable], e, sens, grid)
        transform = fit_chart_transform(chart_rgb[usable], model)
    except SpectralEstimationError as exc:
        raise UsageError(f"{chart_name}: {exc}") from None
    rgb = np.concatenate([im.rgb for im in images], axis=2) if two else images[0].rgb
    mask = np.logical_and.reduce([~(im.saturated | im.dead) for im in images])
    # black-subtracted values may dip below 0 by noise: a reflectance estimate takes them as 0
    rgb = np.maximum(rgb, 0.0, dtype=np.float32)
    try:
        out = spectral_image(fit, rgb, mask=mask)
    except SpectralEstimationError as exc:
        raise UsageError(f"{image_name}: {exc}") from None
    cam = (rgb.reshape(-1, rgb.shape[2]) @ transform.matrix.astype(np.float32)).reshape(rgb.shape)
    # the transform's negative off-diagonal terms take near-black pixels slightly below 0: clip, and
    # masked pixels hold 0 (their input may be anything)
    np.maximum(cam, 0.0, out=cam)
    cam[~mask] = 0.0
    est = fit.estimate_weights(chart_rgb[usable]).astype(np.float64) @ fit.basis.T
    chart_rmse = float(np.sqrt(np.mean((est - refl[usable]) ** 2)))
    return ChartEstimate(out.weights, out.mask, cam.astype(np.float32, copy=False), fit, transform, usable,
                         chart_rmse, np.atleast_2d(e).astype(np.float64))


# ---------------------------------------------------------------------------------------------- the result


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


def _check_estimate_options(method: str, two_given: tuple[bool, bool], noise: float) -> None:
    """The method, its second frame and chart, and the noise level."""
    two = method == "twolight"
    if method not in METHODS:
        raise UsageError(f"--method {method!r}: choose one of {', '.join(METHODS)}")
    if two and not all(two_given):
        raise UsageError("--method twolight needs --second IMAGE2 (the same view under the second light) "
                         "and --second-chart CHART2 (the chart under that light)")
    if not two and any(two_given):
        raise UsageError(f"--second and --second-chart belong to --method twolight, not {method}")
    if not (isinstance(noise, (int, float)) and math.isfinite(noise) and 0 < noise < 1):
        raise UsageError(f"--noise {noise!r}: give the relative noise of the camera values, e.g. 0.01 for 1 %")


def estimate_spectral(
    image: Path,
    chart: Path | ChartMeasurement,
    *,
    method: str = "rootpoly",
    second: Path | None = None,
    second_chart: Path | ChartMeasurement | None = None,
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
    """Decode, calibrate with the chart and estimate basis weights for every pixel (:func:`estimate_from_chart`).

    ``chart`` (and ``second_chart``) is the chart frame's RAW file, located and
    sampled here, or its measurement already made (the batch's colour step).
    Every bad input raises :class:`processing.errors.InputError` with a
    one-line message.
    """
    from processing.camera.raw_decode import decode_raw

    two = method == "twolight"
    _check_estimate_options(method, (second is not None, second_chart is not None), noise)
    setup = estimator_setup(two=two, chart_type=chart_type, chart_reflectances=chart_reflectances, light=light,
                            second_light=second_light, camera=camera, database=database)

    def measured(c: Path | ChartMeasurement, corners: str | None) -> ChartMeasurement:
        return c if isinstance(c, ChartMeasurement) else measure_chart(c, chart=chart_type, corners=corners, mode=mode)

    images = [decode_raw(image, mode=mode)] + ([decode_raw(second, mode=mode)] if two else [])
    charts = [measured(chart, chart_corners)]
    if two:
        charts.append(measured(second_chart, second_chart_corners))
        if images[1].shape != images[0].shape:
            raise UsageError(f"--second {second}: {images[1].shape[1]} x {images[1].shape[0]} pixels, but {image} has "
                             f"{images[0].shape[1]} x {images[0].shape[0]}; the two exposures must be of the same view")
    selection = None if patches is None else parse_patch_list(patches, charts[0].usable.size)
    est = estimate_from_chart(images, charts, setup, method=method, noise=noise, patches=selection,
                              image_name=f"{image}", chart_name=charts[0].source)
    metadata = {
        "format": "kogei-spectral",
        "version": 1,
        "method": method,
        "mode": mode,
        "image": [os.fspath(image)] + ([os.fspath(second)] if two else []),
        "chart": [c.source for c in charts],
        "chart_type": chart_type,
        "chart_found_by": [c.method for c in charts],
        "lights": setup.light_names,
        "camera": camera,
        "patches_used": [int(k) + 1 for k in np.flatnonzero(est.usable)],
        "chart_warnings": [w for c in charts for w in c.warnings],
        "condition": {k: float(v) for k, v in est.fit.condition.items()},
        "chart_residual": float(est.transform.residual),
        "cfa_pattern": images[0].cfa_pattern,
        "chart_transform": np.asarray(est.transform.matrix, dtype=np.float64).tolist(),
        "chart_rmse": est.chart_rmse,
        "training_rmse": float(est.fit.training_rmse),
        "training_spectra": int(setup.training.shape[0]),
        "masked_pixels": int((~est.mask).sum()),
    }
    return SpectralResult(est.weights, np.asarray(est.fit.basis, dtype=np.float64), setup.grid.wavelengths.copy(),
                          est.mask, est.camera, np.asarray(setup.sensitivities, dtype=np.float64), est.lights,
                          method, metadata)


def save_result(result: SpectralResult, path: Path) -> Path:
    """Write ``result`` as an uncompressed ``.npz`` (atomically, no pickled objects)."""
    path = Path(path)
    if not path.parent.is_dir():
        raise UsageError(f"--out {path}: the folder {path.parent} does not exist")
    with atomic_path(path, durable=False, make_parents=False) as tmp, open(tmp, "wb") as fh:
        # uncompressed: float weights barely shrink (about 10 %) and zlib took 50x longer (6 s, 2000 x 3000 x 8)
        np.savez(fh, weights=result.weights, basis=result.basis, wavelengths=result.wavelengths,
                 mask=result.mask, camera=result.camera, sensitivities=result.sensitivities,
                 lights=result.lights, method=np.array(result.method),
                 metadata=np.array(json.dumps(result.metadata)))
    return path


#: What to do about a file that is not a usable result.
_REMEDY = "write it with 'kogei spectral estimate'"


def load_result(path: Path) -> SpectralResult:
    """Read a RESULT.npz written by :func:`save_result`.

    The file is untrusted: anything that is not such a result (a missing
    file, a text file or a single ``.npy`` named ``.npz``, a zip that is not
    an ``.npz``, a missing array, pickled objects, an array header that
    claims more data than the archive holds, a wrong dtype or shape) is one
    :class:`UsageError` line naming the file and the array.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"{path}: no such file; give the RESULT.npz written by 'kogei spectral estimate'")
    data = _read_arrays(path)
    _check_arrays(path, data)
    return SpectralResult(data["weights"], data["basis"], data["wavelengths"], data["mask"], data["camera"],
                          data["sensitivities"], data["lights"], str(data["method"]), _metadata(path, data))


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    """The arrays of :data:`RESULT_KEYS`, each checked against its member's size before it is read."""
    from processing.common.npz import read_npz
    from render.renderer import available_memory_bytes

    return read_npz(path, RESULT_KEYS, what="a kogei spectral result file", remedy=_REMEDY, error=UsageError,
                    available_bytes=available_memory_bytes(),
                    memory_remedy="free memory or estimate a smaller image")


#: Array -> (dtype kinds allowed, number of dimensions) of a RESULT file.
_ARRAY_KINDS = {"weights": ("f", 3), "basis": ("f", 2), "wavelengths": ("fiu", 1), "mask": ("b", 2),
                "camera": ("f", 3), "sensitivities": ("f", 2), "lights": ("f", 2), "method": ("U", 0),
                "metadata": ("U", 0)}
_KIND_NAMES = {"f": "floating-point", "fiu": "numeric", "b": "boolean", "U": "a string"}


def _check_arrays(path: Path, data: dict[str, np.ndarray]) -> None:
    """Dtypes, dimensions and the shapes that must agree (one image size, one wavelength grid, one basis)."""
    for key, (kinds, ndim) in _ARRAY_KINDS.items():
        a = data[key]
        if a.dtype.kind not in kinds or a.ndim != ndim:
            raise UsageError(f"{path}: array {key!r} must be {_KIND_NAMES[kinds]} with {ndim} dimension(s), "
                             f"got {a.dtype} of shape {a.shape}; {_REMEDY}")
    w, b, wl, m = data["weights"], data["basis"], data["wavelengths"], data["mask"]
    if (b.shape[1] != w.shape[2] or wl.shape != (b.shape[0],) or wl.size < 2 or m.shape != w.shape[:2]
            or data["camera"].shape[:2] != w.shape[:2] or data["sensitivities"].shape[0] != wl.size
            or data["lights"].shape[1] != wl.size):
        raise UsageError(f"{path}: inconsistent arrays (weights {w.shape}, basis {b.shape}, wavelengths {wl.shape}, "
                         f"mask {m.shape}); write it again with 'kogei spectral estimate'")
    step = np.diff(wl.astype(np.float64))
    if not (np.all(np.isfinite(wl)) and step[0] > 0 and np.allclose(step, step[0])):
        raise UsageError(f"{path}: array 'wavelengths' must be an evenly spaced increasing grid in nm, "
                         f"got {wl[:4].tolist()}...; {_REMEDY}")
    if str(data["method"]) not in METHODS:
        raise UsageError(f"{path}: method {str(data['method'])[:40]!r} is not one of {', '.join(METHODS)}; {_REMEDY}")


def _metadata(path: Path, data: dict[str, np.ndarray]) -> dict[str, Any]:
    """The metadata JSON object (its ``chart_rmse``, when given, a finite number)."""
    try:
        meta = parse_json(str(data["metadata"]), f"{path}: its metadata", _REMEDY)
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    if not isinstance(meta, dict):
        raise UsageError(f"{path}: its metadata must be a JSON object, got {type(meta).__name__}; {_REMEDY}")
    rmse = meta.get("chart_rmse", 0.0)
    if isinstance(rmse, bool) or not isinstance(rmse, (int, float)) or not math.isfinite(rmse) or rmse < 0:
        raise UsageError(f"{path}: metadata chart_rmse must be a non-negative number, got {rmse!r}; {_REMEDY}")
    return meta
