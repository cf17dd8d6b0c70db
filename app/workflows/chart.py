"""The colour chart of a RAW frame: decoded, located, sampled and checked.

:func:`processing.camera.raw_decode.decode_raw` decodes the frame,
:func:`processing.camera.chart_detection.detect_chart` finds the chart with
``cv2.mcc`` (or :func:`processing.camera.chart_detection.chart_from_corners`
takes its four outer corners, sensor pixels, top-left first, clockwise),
:func:`processing.camera.chart_sampling.sample_patches` samples the linear RGB
of every patch and :func:`processing.camera.chart_sampling.check_patches`
checks the shot.  :func:`chart_report` is the JSON form (``kogei chart``, the
batch's colour step); :class:`ChartMeasurement` is what calibrates a spectral
estimate (``kogei spectral estimate``, the window's spectra panel, the batch's
materials step, the colour demo).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.errors import UsageError

__all__ = ["ChartMeasurement", "chart_report", "measure_chart"]


def _locate_and_sample(path: Path, chart: str, corners: str | None, mode: str, inset: float, trim: float):
    """The decoded frame, the chart's detection, its patch samples and their check."""
    from processing.camera.chart_detection import chart_from_corners, detect_chart, parse_corners
    from processing.camera.chart_sampling import check_patches, sample_patches
    from processing.camera.raw_decode import decode_raw

    img = decode_raw(path, mode=mode)
    h, w = img.shape
    if corners is not None:
        det = chart_from_corners(parse_corners(corners), chart, image_size=(w * img.scale, h * img.scale))
    else:
        det = detect_chart(img, chart)
    samples = sample_patches(img, det, inset=inset, trim=trim)
    return img, det, samples, check_patches(samples)


def chart_report(raw_path: Path, *, chart: str = "classic24", corners: str | None = None, mode: str = "bin2x2",
                 inset: float = 0.6, trim: float = 0.1) -> dict:
    """Decode, locate, sample and check; the JSON-ready report.

    Bad input raises the decoder's, the detector's or the sampler's
    :class:`processing.errors.InputError` (their messages name the file).
    """
    img, det, samples, check = _locate_and_sample(raw_path, chart, corners, mode, inset, trim)
    layout = det.layout
    return {
        "format": "kogei-chart",
        "version": 1,
        "raw": os.fspath(raw_path),
        "chart": chart,
        "method": det.method,
        "confidence": det.confidence,
        "detect_seconds": det.seconds,
        "mode": mode,
        "exposure_time": img.exposure_time,
        "iso": img.iso,
        "f_number": img.f_number,
        "make": img.make,
        "model": img.model,
        "black_levels": list(img.black_levels),
        "white_level": img.white_level,
        "corners": det.corners.tolist(),
        "warnings": check.warnings,
        "patches": [
            {
                "number": k + 1,
                "name": layout.names[k],
                "centre": det.centres[k].tolist(),
                "mean": samples.mean[k].tolist(),
                "std": samples.std[k].tolist(),
                "clipped": float(samples.clipped[k]),
                "count": int(samples.count[k]),
                "nonuniformity": float(samples.nonuniformity[k]),
                "usable": bool(check.usable[k]),
            }
            for k in range(layout.size)
        ],
    }


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
        ``(H, W)`` of the decoded frame (None when rebuilt from a chart report).
    method
        ``"mcc"`` or ``"manual"`` (from ``--chart-corners``).
    source
        The chart frame's file, as given.
    """

    mean: NDArray[np.float64]
    usable: NDArray[np.bool_]
    warnings: list[str]
    exposure: float
    shape: tuple[int, int] | None
    method: str
    source: str = ""

    @classmethod
    def from_report(cls, report: dict[str, Any]) -> ChartMeasurement:
        """The measurement a :func:`chart_report` (e.g. read back from the batch's colour product) holds.

        Its patch means are those :func:`measure_chart` finds on the same file
        (the same sampling; JSON keeps every float64 exactly).

        Examples
        --------
        >>> rep = {"raw": "c.dng", "method": "mcc", "exposure_time": 0.01, "iso": 100, "warnings": [],
        ...        "patches": [{"mean": [0.1, 0.2, 0.3], "usable": True}]}
        >>> m = ChartMeasurement.from_report(rep)
        >>> m.mean.tolist(), m.usable.tolist(), m.exposure, m.source
        ([[0.1, 0.2, 0.3]], [True], 1.0, 'c.dng')
        """
        patches = report["patches"]
        return cls(np.array([p["mean"] for p in patches], dtype=np.float64),
                   np.array([p["usable"] for p in patches], dtype=bool), list(report["warnings"]),
                   float(report["exposure_time"]) * float(report["iso"]), None, report["method"],
                   os.fspath(report["raw"]))


def measure_chart(path: Path, *, chart: str = "classic24", corners: str | None = None,
                  mode: str = "bin2x2") -> ChartMeasurement:
    """Decode, locate, sample and check a chart frame; errors are :class:`UsageError` naming the file."""
    from processing.camera.chart_detection import ChartDetectionError
    from processing.camera.chart_sampling import ChartRejectedError, ChartSamplingError
    from processing.camera.raw_decode import RawDecodeError

    path = Path(path)
    try:
        img, det, samples, check = _locate_and_sample(path, chart, corners, mode, 0.6, 0.1)
    except (RawDecodeError, ChartDetectionError, ChartSamplingError, ChartRejectedError) as exc:
        msg = str(exc)
        raise UsageError(msg if os.fspath(path) in msg or path.name in msg else f"{path}: {msg}") from None
    h, w = img.shape
    return ChartMeasurement(np.asarray(samples.mean, dtype=np.float64), np.asarray(check.usable, dtype=bool),
                            list(check.warnings), float(img.exposure_time) * float(img.iso), (h, w), det.method,
                            os.fspath(path))
