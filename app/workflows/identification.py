"""The material of each region of a spectral result.

Matsuda et al., section 4.2, eq. (11) and eq. (3)-(4), as implemented by
:mod:`processing.materials.identification`: every candidate material (metals,
the alloys, urushi) is forward-modelled into the model camera and compared
with the region's values in that camera (the ``camera`` array of a
:class:`app.workflows.spectral.SpectralResult`, i.e. after the chart
transform), with a free brightness; the answer comes with a confidence (the
posterior tempered by the best candidate's misfit,
:func:`processing.materials.confidence.decide`), the runner-up, the misfit
(reduced chi-square of the best candidate), and for a metal or alloy the Ag,
Cu, Au weights of the alloy model.  When even the best candidate misses the
region by more than the noise and model error allow (misfit above
:data:`processing.materials.confidence.MAX_MISFIT`) the material is
``"no candidate fits"`` and ``group`` lists the best few candidates.  The
model error defaults to
:data:`processing.materials.identification.DEFAULT_MODEL_ERROR`.  The region's mean reflectance and its uncertainty
(:func:`processing.spectral.estimation.estimator.region_spectra`, with the
estimate's error on the chart as the method error) ride along.
``kogei identify``, the batch's materials step and the colour demo call
:func:`identify_result`.  A result decoded ``bin2x2`` carries its sensor's CFA
pattern and chart transform; with ``fringe=True`` every region's pixels go to
the identification with the colour error the binning predicts for them
(:func:`result_fringe`: small highlights and edges, where red and blue are
sampled on different sides of a steep brightness change), counted as an error
the region's pixels share.  That suits a small patch around one highlight (a
click); over a segmented region the fringe changes sign across each highlight
and largely cancels, and counting it as shared made the simulated hawk's gold
beak a short list (confidence 0.23 instead of a name), so regions do not carry
it by default.

Masked pixels (saturated or dead in the RAW) never count, nor do pixels whose
brightest channel is below ``min_level`` (default 0.005) times that of a white
diffuser lit like the chart (``(1, ..., 1) @ K`` in the model camera's units,
which the chart transform fixes): a glossy metal under one light is black away
from its highlights, and such pixels carry read noise, not colour (noise
clipped at 0 would pull a region's colour toward the camera's black).  A
region with no such pixel is reported with ``material`` None and the reason.
The pixels kept still carry the sensor's read noise, equal in the RAW channels
and turned by the chart transform into the colour of a RAW grey (a strong red
for most cameras); the identification is told it (:func:`result_dark_noise`),
so a dim region is not named with a confidence its noise cannot support, and
the transform itself, so that the relative noise and model error are taken in
the sensor's channels and carried through it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import UsageError
from app.workflows.spectral import SpectralResult

__all__ = ["ALLOY_METALS", "MIN_LEVEL", "RegionReport", "read_labels", "binned_labels", "identify_result",
           "result_fringe", "result_dark_noise",
           "usable_regions", "white_response", "pixel_level"]

#: Metals of the alloy model (Matsuda et al., eq. (3)-(4); Table 1's shibuichi and shakudo are Ag-Cu-Au).
ALLOY_METALS = ("Ag", "Cu", "Au")

#: Pixels whose brightest channel is below this fraction of a white diffuser lit like the chart hold noise,
#: not colour (backdrop, shadow, a glossy metal away from its highlights): identification leaves them out.
MIN_LEVEL = 0.005


def read_labels(path: Path, shape: tuple[int, int], *, mode: str | None = None,
                note: Callable[[str], None] | None = None) -> NDArray[np.int64]:
    """Read a label PNG and check it against the result's ``(H, W)``; errors are :class:`UsageError`.

    A result estimated in ``bin2x2`` ``mode`` is half the sensor's size: a label image drawn at the
    photo's full resolution (``2H`` or ``2H + 1`` rows, likewise columns) is resampled to the
    result nearest-neighbour (:func:`binned_labels`), and ``note`` is told so.
    """
    import cv2

    if not path.is_file():
        raise UsageError(f"--regions {path}: no such file")
    try:
        lab = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error:       # a header declaring more pixels than OpenCV's limit (an image bomb), or damaged data
        raise UsageError(f"--regions {path}: OpenCV refuses to read it (a header declaring more pixels than it "
                         "reads, or damaged data); give a single-channel PNG of region labels") from None
    if lab is None:
        raise UsageError(f"--regions {path}: not a readable image; give a single-channel PNG of region labels")
    if lab.ndim != 2 or lab.dtype.kind not in "iu":
        raise UsageError(f"--regions {path}: a {lab.shape[2] if lab.ndim == 3 else ''}-channel {lab.dtype} image; "
                         "give a single-channel (grey) 8- or 16-bit PNG with one integer label per region")
    if lab.shape != shape and mode == "bin2x2" and all(n // 2 == m for n, m in zip(lab.shape, shape)):
        if note is not None:
            note(f"--regions {path.name}: {lab.shape[1]} x {lab.shape[0]} pixels (the photo's full resolution), "
                 f"resampled nearest-neighbour to the 2x2-binned result's {shape[1]} x {shape[0]}")
        return binned_labels(lab.astype(np.int64), shape)
    if lab.shape != shape:
        full = (f" or {2 * shape[1]} x {2 * shape[0]} (the photo's full resolution, resampled)"
                if mode == "bin2x2" else "")
        raise UsageError(f"--regions {path}: {lab.shape[1]} x {lab.shape[0]} pixels, but the result is "
                         f"{shape[1]} x {shape[0]} (mode {mode or 'unknown'}); give a label image of "
                         f"{shape[1]} x {shape[0]}{full}")
    return lab.astype(np.int64)


def binned_labels(labels: NDArray[np.int64], shape: tuple[int, int]) -> NDArray[np.int64]:
    """Labels at the sensor's resolution -> a 2x2-binned result's ``(H, W)``, nearest-neighbour.

    Result pixel ``(i, j)`` is the Bayer cell of sensor rows ``2i, 2i + 1`` and columns ``2j, 2j + 1``;
    it takes the label of the cell's top-left photosite (labels are categories: never averaged).

    Examples
    --------
    >>> full = np.repeat(np.repeat(np.array([[1, 2], [3, 0]]), 2, axis=0), 2, axis=1)
    >>> binned_labels(np.pad(full, ((0, 1), (0, 1))), (2, 2)).tolist()
    [[1, 2], [3, 0]]
    """
    h, w = shape
    return np.ascontiguousarray(labels[0:2 * h:2, 0:2 * w:2])


@dataclass(frozen=True)
class RegionReport:
    """One region's identification (JSON-ready through :meth:`as_dict`).

    ``chi2`` is the best candidate's chi-square under the noise model (c - 1 degrees of freedom
    for c channels, the brightness being free) and ``misfit`` that chi-square over its degrees of
    freedom: far above 1 no candidate explains the region, and beyond
    :data:`processing.materials.confidence.MAX_MISFIT` ``material`` is ``"no candidate fits"``.
    """

    label: int
    pixels: int
    material: str | None
    confidence: float | None
    runner_up: str | None
    likelihood_ratio: float | None
    group: tuple[str, ...]
    alloy_weights: dict[str, float] | None
    alloy_std: dict[str, float] | None
    reflectance: list[float] | None
    uncertainty: list[float] | None
    note: str = ""
    chi2: float | None = None
    misfit: float | None = None

    def as_dict(self) -> dict[str, Any]:
        """The fields as a dict."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


def _is_metal(name: str) -> bool:
    from processing.materials.identification import NEUTRAL_METAL, NO_FIT
    from processing.materials.presets import get_material

    if name == NO_FIT:
        return False                # no material: no alloy weights either
    return name == NEUTRAL_METAL or get_material(name).family in ("metal", "alloy")


def white_response(result: SpectralResult) -> NDArray[np.float64]:
    """Camera values of a white diffuser lit like the chart (``(1, ..., 1) @ K``, the model camera's units).

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import SpectralGrid
    >>> g = SpectralGrid(400, 700, 10)
    >>> r = SpectralResult(np.zeros((1, 1, 3), np.float32), np.eye(31, 3), g.wavelengths, np.ones((1, 1), bool),
    ...                    np.zeros((1, 1, 3), np.float32), camera_sensitivities(g), np.ones((1, 31)), "demo")
    >>> white_response(r).shape
    (3,)
    """
    from processing.camera.response import channel_matrix

    lights = result.lights[0] if result.lights.shape[0] == 1 else result.lights
    return np.asarray(np.ones(result.grid.size) @ channel_matrix(result.sensitivities, lights, result.grid),
                      dtype=np.float64)


def pixel_level(result: SpectralResult, x: int, y: int) -> float:
    """Brightest channel of pixel ``(x, y)`` as a fraction of a white diffuser lit like the chart.

    Below :data:`MIN_LEVEL` the pixel is backdrop or shadow: its estimated spectrum is noise.

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import SpectralGrid
    >>> g = SpectralGrid(400, 700, 10)
    >>> r = SpectralResult(np.zeros((1, 2, 3), np.float32), np.eye(31, 3), g.wavelengths, np.ones((1, 2), bool),
    ...                    np.zeros((1, 2, 3), np.float32), camera_sensitivities(g), np.ones((1, 31)), "demo")
    >>> r.camera[0, 1] = white_response(r) / 2
    >>> pixel_level(r, 0, 0), round(pixel_level(r, 1, 0), 6)
    (0.0, 0.5)
    """
    white = white_response(result)
    return float(np.max(result.camera[y, x].astype(np.float64) / white))


def usable_regions(result: SpectralResult, labels: NDArray[np.integer], min_level: float = MIN_LEVEL) -> NDArray[np.int64]:
    """``labels`` with 0 where a pixel is masked or darker than ``min_level`` of a white diffuser (module text).

    Examples
    --------
    >>> from processing.camera.response import camera_sensitivities
    >>> from processing.spectral.spectra import SpectralGrid
    >>> g = SpectralGrid(400, 700, 10)
    >>> cam = np.zeros((1, 2, 3), np.float32); cam[0, 0] = 5.0
    >>> r = SpectralResult(np.zeros((1, 2, 3), np.float32), np.eye(31, 3), g.wavelengths, np.ones((1, 2), bool),
    ...                    cam, camera_sensitivities(g), np.ones((1, 31)), "demo")
    >>> usable_regions(r, np.array([[1, 1]])).tolist()
    [[1, 0]]
    """
    white = white_response(result)
    live = np.asarray(labels, dtype=np.int64) * result.mask
    # shadows and the off-highlight pixels of a glossy surface hold noise, not colour
    live[(result.camera < min_level * white.astype(np.float32)).all(axis=2)] = 0
    return live


def result_fringe(result: SpectralResult) -> NDArray[np.float64] | None:
    """The predicted CFA fringe of a ``bin2x2`` result in the model camera's units, or None.

    :func:`processing.camera.cfa_fringe.transformed_fringe` on the frame brought back to the object camera by
    the inverse of the chart transform the result records (``metadata``: ``mode``, ``cfa_pattern``,
    ``chart_transform``); None for a result without them (written before they were recorded), a demosaicked
    one or a two-exposure one.
    """
    from processing.camera.cfa_fringe import transformed_fringe

    meta = result.metadata
    matrix = np.asarray(meta.get("chart_transform", []), dtype=np.float64)
    if meta.get("mode") != "bin2x2" or not meta.get("cfa_pattern") or matrix.shape != (3, 3) \
            or result.camera.shape[2] != 3 or abs(float(np.linalg.det(matrix))) < 1e-12:
        return None
    raw = result.camera.astype(np.float64) @ np.linalg.inv(matrix)
    return transformed_fringe(np.maximum(raw, 0.0), str(meta["cfa_pattern"]), matrix)


def result_dark_noise(result: SpectralResult) -> NDArray[np.float64] | None:
    """``(3, 3)`` covariance of one pixel's read noise in the model camera's units, or None.

    :func:`processing.camera.transfer.transformed_read_noise` (the assumed
    :data:`processing.camera.transfer.READ_NOISE` of a photosite) through the chart transform the result
    records (``metadata``: ``chart_transform``, ``mode``); None for a result without a 3 x 3 transform.
    """
    from processing.camera.transfer import transformed_read_noise

    meta = result.metadata
    matrix = np.asarray(meta.get("chart_transform", []), dtype=np.float64)
    if matrix.shape != (3, 3) or result.camera.shape[2] != 3 or not np.all(np.isfinite(matrix)):
        return None
    return transformed_read_noise(matrix, mode=str(meta.get("mode", "bin2x2")))


def identify_result(
    result: SpectralResult,
    labels: NDArray[np.integer] | None = None,
    *,
    light_deg: float = 30.0,
    noise: float = 0.01,
    model_error: float | None = None,
    min_level: float = MIN_LEVEL,
    fringe: bool = False,
) -> list[RegionReport]:
    """Identify every region (label > 0) of ``result``; ``labels=None``: the whole unmasked image.

    ``model_error`` None: :data:`processing.materials.identification.DEFAULT_MODEL_ERROR`.  ``fringe``: carry
    the ``bin2x2`` decode's predicted false colour (:func:`result_fringe`) as a shared colour error (see the
    module docstring: for a small patch around one highlight, not for segmented regions).
    """
    from processing.materials.identification import (
        DEFAULT_MODEL_ERROR,
        candidate_set,
        estimate_alloy_weights,
        identify_material,
    )
    from processing.spectral.estimation.estimator import region_spectra
    from processing.spectral.estimation.fit import SpectralEstimationError

    if model_error is None:
        model_error = DEFAULT_MODEL_ERROR
    h, w = result.mask.shape
    lab = np.ones((h, w), np.int64) if labels is None else np.asarray(labels, dtype=np.int64)
    if lab.shape != (h, w):
        raise UsageError(f"labels of {lab.shape[1]} x {lab.shape[0]} pixels for a result of {w} x {h}")
    if np.any(lab < 0):
        raise UsageError("labels must be >= 0 (0 = ignore)")
    ids = [int(v) for v in np.unique(lab) if v > 0]
    if not ids:
        raise UsageError("the label image has no region (every label is 0)")
    grid = result.grid
    lights = result.lights[0] if result.lights.shape[0] == 1 else result.lights
    cands = candidate_set(result.sensitivities, lights, grid, light_deg=light_deg)
    live = usable_regions(result, lab, min_level)
    spectra = region_spectra(result.weights, live, result.basis, result.method_error) if live.any() else None
    row = {} if spectra is None else {int(v): i for i, v in enumerate(spectra.labels)}
    flat_cam = result.camera.reshape(-1, result.camera.shape[2])
    predicted = result_fringe(result) if fringe else None
    flat_err = None if predicted is None else predicted.reshape(-1, predicted.shape[2])
    dark = result_dark_noise(result)
    matrix = None if dark is None else np.asarray(result.metadata["chart_transform"], dtype=np.float64)
    if matrix is not None and abs(float(np.linalg.det(matrix))) < 1e-12:
        matrix = None
    flat_lab = live.ravel()
    reports = []
    for r in ids:
        px = flat_cam[flat_lab == r].astype(np.float64)
        if px.shape[0] == 0:
            reports.append(RegionReport(r, 0, None, None, None, None, (), None, None, None, None,
                                        "no usable pixel (saturated or dead in the RAW, or black)"))
            continue
        try:
            found = identify_material(px, cands, noise=noise, model_error=model_error,
                                      colour_error=None if flat_err is None else flat_err[flat_lab == r],
                                      dark_noise=dark, transform=matrix)
        except SpectralEstimationError as exc:
            reports.append(RegionReport(r, px.shape[0], None, None, None, None, (), None, None, None, None, str(exc)))
            continue
        alloy = alloy_std = None
        if _is_metal(found.material):
            est = estimate_alloy_weights(px, result.sensitivities, lights, grid, metals=ALLOY_METALS,
                                         light_deg=light_deg, noise=max(noise, 1e-6))
            alloy = est.as_dict()
            alloy_std = {m: float(s) for m, s in zip(est.metals, est.std)}
        i = row[r]
        reports.append(RegionReport(
            r, int(px.shape[0]), found.material, float(found.confidence), found.runner_up,
            float(found.likelihood_ratio), tuple(found.group), alloy, alloy_std,
            spectra.mean[i].tolist(), spectra.uncertainty[i].tolist(),
            chi2=float(found.chi2[found.chi2.argmin()]), misfit=float(found.misfit),
        ))
    return reports
