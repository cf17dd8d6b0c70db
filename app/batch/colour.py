"""The ``colour`` step of ``kogei batch``: every pass's chart frame located, sampled, checked and scored.

docs/batch.md.  For each pass's chart frame (``pNN/chart``; the first,
``pNN/chart/00``, of a swatch pass that took several) the RAW frame is decoded,
the chart found and its patches sampled and checked by
:func:`app.workflows.chart.chart_report` (``kogei chart``:
:mod:`processing.camera.raw_decode`, :mod:`processing.camera.chart_detection`,
:mod:`processing.camera.chart_sampling`).  The **patch errors** are the CIEDE2000
differences left by the least-squares 3 x 3 matrix from the usable patches'
linear camera RGB to the chart's reference XYZ (D65,
:func:`processing.camera.chart_layout.reference_lab`): the residual of a linear
colour calibration on the chart itself (in-sample, so a lower bound of the
error elsewhere in the frame), large where a patch is mis-sampled, clipped
or the camera is far from linear.  Each pass's result and a white-balanced
preview of its frame (:func:`processing.camera.raw_decode.preview_srgb8`) become
products ``products/colour/pNN-chart.json`` and ``pNN-chart.png``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from app.session_paths import check_not_symlink, confined_file
from processing.common.png import png_bytes
from processing.errors import InputError

__all__ = ["colour_inputs", "colour_params", "colour_run", "first_chart_frames", "patch_errors", "CHARTS"]

CHARTS = ("classic24", "sg140", "vinyl18")
COLOUR_DIR = "products/colour"


def patch_errors(camera_rgb: np.ndarray, reference_lab: np.ndarray, usable: np.ndarray) -> dict[str, Any]:
    """CIEDE2000 of every patch after the least-squares 3 x 3 map camera RGB -> reference XYZ (D65).

    Parameters
    ----------
    camera_rgb
        ``(N, 3)`` linear camera RGB of the patches.
    reference_lab
        ``(N, 3)`` CIE L*a*b* (D65 white) of the patches.
    usable
        ``(N,)`` patches the fit may use (at least 3, not all grey).

    Returns
    -------
    dict
        ``matrix`` (3 x 3, row-vector form ``xyz = rgb @ matrix``), ``delta_e00`` per patch (all
        patches, predicted by the fit of the usable ones), ``mean`` and ``max`` over the usable ones.

    Examples
    --------
    A camera whose RGB is an exact linear map of XYZ is fitted with no error:

    >>> import colour
    >>> lab = np.array([[50, 10, -5], [70, -20, 30], [40, 35, 10], [90, 0, 2], [60, 5, 50.0]])
    >>> xyz = colour.Lab_to_XYZ(lab, colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"])
    >>> rgb = xyz @ np.array([[2.0, -0.5, 0.1], [-0.8, 1.6, -0.2], [0.1, -0.2, 1.1]])
    >>> round(patch_errors(rgb, lab, np.ones(5, bool))["max"], 6)
    0.0
    """
    import colour

    rgb = np.asarray(camera_rgb, dtype=np.float64)
    lab = np.asarray(reference_lab, dtype=np.float64)
    use = np.asarray(usable, dtype=bool)
    if rgb.shape != lab.shape or rgb.ndim != 2 or rgb.shape[1] != 3 or use.shape != (len(rgb),):
        raise ValueError(f"patch_errors: camera_rgb {rgb.shape}, reference_lab {lab.shape} and usable {use.shape} "
                         "must describe the same N patches")
    if use.sum() < 3:
        raise ValueError(f"patch_errors: {int(use.sum())} usable patches; a 3 x 3 fit needs 3 or more")
    if not np.all(np.isfinite(rgb[use])):
        bad = [int(i) + 1 for i in np.flatnonzero(use & ~np.isfinite(rgb).all(axis=1))]
        raise ValueError(f"patch_errors: usable patch(es) {bad} have no finite camera RGB")
    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    xyz = colour.Lab_to_XYZ(lab, white)
    matrix, *_ = np.linalg.lstsq(rgb[use], xyz[use], rcond=None)
    predicted = colour.XYZ_to_Lab(np.clip(rgb @ matrix, 1e-9, None), white)
    de = np.asarray(colour.delta_E(lab, predicted, method="CIE 2000"), dtype=np.float64)
    return {"matrix": matrix.tolist(), "delta_e00": de.tolist(), "mean": float(de[use].mean()),
            "max": float(de[use].max())}


def first_chart_frames(manifest: dict[str, Any]) -> dict[str, tuple[str, dict[str, Any], int]]:
    """Per pass (``pNN``): its first chart frame taken (id and record) and how many the pass has.

    A scan pass opens with one chart frame (``pNN/chart``), a swatch pass
    with several (``pNN/chart/00`` ...; ``CapturePlan.chart_frames``): the
    first calibrates the pass, as in the window's spectra panel.

    >>> done = {"kind": "chart", "status": "done"}
    >>> caps = {"p01/chart/01": done, "p01/chart/00": done, "p02/chart": done,
    ...         "p01/frame/00": {"kind": "frame", "status": "done"}}
    >>> {tag: (cid, n) for tag, (cid, rec, n) in first_chart_frames({"captures": caps}).items()}
    {'p01': ('p01/chart/00', 2), 'p02': ('p02/chart', 1)}
    """
    out: dict[str, tuple[str, dict[str, Any], int]] = {}
    for cid, rec in sorted(manifest["captures"].items()):
        if rec.get("kind") != "chart" or rec.get("status") != "done":
            continue
        tag = cid.split("/")[0]
        first = out.get(tag)
        out[tag] = (cid, rec, 1) if first is None else (first[0], first[1], first[2] + 1)
    return out


def colour_inputs(root: Path, manifest: dict[str, Any], options: Any) -> dict[str, str]:
    return {cid: rec.get("sha256", "") for cid, rec, _ in first_chart_frames(manifest).values()}


def colour_params(options: Any) -> dict[str, Any]:
    return {"chart": options.chart, "mode": "bin2x2"}


def colour_run(root: Path, options: Any, log: Callable[[str], None]) -> dict[str, Any]:
    from app.session import Session
    from app.workflows.chart import chart_report
    from processing.camera.chart_layout import reference_lab
    from processing.camera.raw_decode import RawDecodeError, decode_raw, preview_srgb8

    manifest = Session.read(root)
    charts = first_chart_frames(manifest)
    if not charts:
        raise UsageError(f"session {root} has no colour-chart frame (captured without camera or chart); capture "
                         "with the camera on, the chart in the first frame of every pass")
    results = {}
    for tag, (cid, rec, count) in charts.items():
        if count > 1:
            log(f"{tag}: {count} chart frames; the first ({cid}) calibrates the pass (the others are for the "
                "cloth fit's average gain)")
        path = confined_file(root, rec.get("file"), f"captures.{cid}.file")
        try:
            report = chart_report(path, chart=options.chart)
        except InputError as exc:
            raise UsageError(f"{cid} ({rec['file']}): {exc}") from None
        usable = np.array([p["usable"] for p in report["patches"]])
        rgb = np.array([p["mean"] for p in report["patches"]])
        try:
            report["patch_errors"] = patch_errors(rgb, reference_lab(options.chart), usable)
        except ValueError as exc:
            raise UsageError(f"{cid}: {exc}") from None
        try:
            img = decode_raw(path, mode="bin2x2")
        except RawDecodeError as exc:
            raise UsageError(f"{cid}: {exc}") from None
        report["preview_scale"] = img.scale          # sensor pixels per preview pixel
        report["raw"] = rec["file"]
        results[tag] = (report, png_bytes(preview_srgb8(img)))
        log(f"{cid}: {report['method']} (confidence {report['confidence']:.2f}), "
            f"{int(usable.sum())} of {len(usable)} patches usable, patch error mean "
            f"{report['patch_errors']['mean']:.2f} / max {report['patch_errors']['max']:.2f} dE00")
    check_not_symlink(root, f"{COLOUR_DIR}/x", "colour products")
    with Session.open(root) as session:
        passes = {}
        for tag, (report, png) in results.items():
            rep = session.write_file(f"{COLOUR_DIR}/{tag}-chart.json",
                                     (json.dumps(report, indent=1) + "\n").encode())
            pre = session.write_file(f"{COLOUR_DIR}/{tag}-chart.png", png)
            passes[tag] = {"chart": {"file": rep.path, "sha256": rep.sha256, "bytes": rep.bytes},
                           "preview": {"file": pre.path, "sha256": pre.sha256, "bytes": pre.bytes}}
        products = dict(session.manifest.get("products") or {})
        products["colour"] = {"chart": options.chart, "passes": passes}
        session.update("products", products)
    worst = max(r["patch_errors"]["max"] for r, _ in results.values())
    return {"products": ("colour",), "summary": {"charts": len(results), "worst_patch_de00": round(worst, 3)}}
