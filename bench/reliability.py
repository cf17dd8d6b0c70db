"""Is a single-image identification's confidence what it says?  Stated confidence against observed accuracy.

:func:`single_image_reliability` draws many simulated regions and identifies each with
:func:`processing.materials.identification.identify_material` exactly as ``kogei identify``, the
batch's materials step and the colour demo do (candidates
:data:`processing.materials.identification.DEFAULT_CANDIDATES` modelled through the model camera --
the default, :func:`processing.camera.response.camera_sensitivities` -- under D65 with the light
30 deg from the normal; the stated noise 0.01 per pixel; the model error
:data:`processing.materials.identification.DEFAULT_MODEL_ERROR`).  Each region:

* **truth**: a candidate drawn uniformly, its roughness scaled by a factor in [0.7, 1.3], an alloy's
  composition jittered (every constituent's fraction + N(0, 0.01), clipped at 0, renormalised);
* **geometry**: the region's light angle from the normal uniform in [15, 60] deg (the candidates
  stay modelled at 30 deg), each pixel's angle that plus N(0, 5) deg, the view along the normal;
* **size and noise**: pixel count log-uniform in [1, 2000]; relative noise per pixel and channel
  log-uniform in [0.003, 0.03] (the identification is told 0.01, as its callers do);
* **camera**: the true camera is one of colour-science's cameras
  (``colour.MSDS_CAMERA_SENSITIVITIES``: Nikon 5100 (NPL), Sigma SDMerill (NPL)), shifted along
  wavelength by U(-10, 10) nm and widened by a Gaussian of U(0, 10) nm; its values are brought to
  the model camera the way the pipeline does -- a 3 x 3 fitted on the 24 ColorChecker patches
  (:func:`processing.camera.transfer.fit_chart_transform`; patch means with 0.2 % noise);
* **unmodelled colour error**: each channel of the region scaled by 1 + N(0, s) with s log-uniform in
  [0.2 %, 5 %] -- what the steps above leave out (demosaicing at highlights, interreflections, a
  spectral estimate between RAW and camera values, clipping near highlights): the colour demo's gold
  beak, through all of those, misses its candidate by about 5 % per channel.

Answers are scored with :func:`processing.materials.confidence.is_right` ("neutral metal" is right
when the truth is in its group); "no candidate fits" names nothing and is counted as an abstention,
outside the reliability table (:func:`processing.materials.confidence.reliability_table`).
Targets: among answers stated at >= 0.9, at least 90 % right; expected calibration error <= 0.05.

:func:`highlight_reliability` asks the same of what a click in the spectra panel gives: patches drawn
the same way but sampled through a Bayer sensor and the ``bin2x2`` decode, lit flat, by a small
highlight or across an edge, where the CFA fringe moves a few pixels' colour by tens of percent
(:mod:`processing.camera.cfa_fringe`); the identification is told the predicted fringe, as the
panel does.

``python -m bench.reliability [--regions N] [--highlights N] [--seed S] [--out DIR]`` prints the
Markdown tables and, with ``--out``, writes ``reliability.png`` (stated against observed per bin,
with the counts), ``reliability.json`` and, with ``--highlights``, ``reliability-highlights.png`` and
``.json``.

References
----------
.. [1] Guo, C., Pleiss, G., Sun, Y., Weinberger, K. Q. (2017). On calibration of modern neural
   networks. ICML, PMLR 70, 1321-1330. doi:10.48550/arXiv.1706.04599
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["single_image_reliability", "highlight_reliability", "markdown", "figure", "main", "TARGETS", "COLOUR_ERROR",
           "READ_NOISE"]

#: Calibration targets: share right among answers stated >= 0.9, and the expected calibration error.
TARGETS = {"high_accuracy": 0.90, "ece": 0.05}
_LIGHT_DEG = 30.0
_STATED_NOISE = 0.01
_CHART_NOISE = 0.002
#: Green level (fraction of full scale) below which a click is refused as too dark (the spectra panel's).
_MIN_SIGNAL = 0.02
#: Range (log-uniform) of a region's unmodelled relative colour error per channel (module text).
COLOUR_ERROR = (0.002, 0.05)
#: Read noise of one photosite of the simulated Bayer sensor (fraction of full scale), after black subtraction.
READ_NOISE = 0.0005


def _true_camera(rng: np.random.Generator, grid: Any) -> tuple[np.ndarray, str]:
    """A colour-science camera, shifted and widened along wavelength: ``(L, 3)`` and its description."""
    import colour
    from scipy.ndimage import gaussian_filter1d

    names = sorted(colour.MSDS_CAMERA_SENSITIVITIES)
    name = names[int(rng.integers(len(names)))]
    msds = colour.MSDS_CAMERA_SENSITIVITIES[name]
    wl = grid.wavelengths
    shift = float(rng.uniform(-10.0, 10.0))
    width = float(rng.uniform(0.0, 10.0))
    fine = np.arange(max(float(msds.wavelengths[0]), 380.0), min(float(msds.wavelengths[-1]), 720.0) + 0.5, 1.0)
    values = np.stack([np.interp(fine, msds.wavelengths, msds.values[:, c], left=0.0, right=0.0)
                       for c in range(3)], axis=1)
    if width > 0:
        values = gaussian_filter1d(values, sigma=width, axis=0, mode="constant")
    sens = np.stack([np.interp(wl - shift, fine, values[:, c], left=0.0, right=0.0) for c in range(3)], axis=1)
    return np.maximum(sens, 0.0), f"{name} {shift:+.1f} nm, widened {width:.1f} nm"


def _true_material(rng: np.random.Generator, name: str) -> Any:
    """The candidate ``name`` with its roughness scaled by [0.7, 1.3] and an alloy's composition jittered."""
    from processing.materials.presets import get_material

    base = get_material(name)
    params = {"roughness": float(np.clip(base.parameters["roughness"] * rng.uniform(0.7, 1.3), 0.01, 1.0))}
    if base.family == "alloy":
        comp = {k: v for k, v in base.parameters.items() if len(k) <= 2 and k[0].isupper() and v > 0}
        jittered = {k: max(v + 0.01 * float(rng.standard_normal()), 0.0) for k, v in comp.items()}
        total = sum(jittered.values())
        if total > 0:
            params.update({k: v / total for k, v in jittered.items()})
    spec = name + ":" + ",".join(f"{k}={v:.6g}" for k, v in params.items())
    return get_material(spec)


def _region_pixels(rng: np.random.Generator, material: Any, e: np.ndarray, sens: np.ndarray, transform: np.ndarray,
                   grid: Any, colour_error: tuple[float, float] | None) -> tuple[np.ndarray, dict[str, float]]:
    """One region's pixels in the model camera's units (after the chart transform), and how it was drawn."""
    from processing.camera.response import channel_matrix
    from processing.materials.lobes import material_brdf

    n = int(round(math.exp(rng.uniform(0.0, math.log(2000.0)))))
    region_deg = float(rng.uniform(15.0, 60.0))
    noise = float(math.exp(rng.uniform(math.log(0.003), math.log(0.03))))
    lo, hi = colour_error or (0.0, 0.0)
    cast = float(math.exp(rng.uniform(math.log(lo), math.log(hi)))) if lo > 0 else 0.0
    t = np.radians(np.clip(region_deg + 5.0 * rng.standard_normal(n), 2.0, 80.0))
    cos_i, cos_h = np.cos(t), np.cos(t / 2)
    signal = material_brdf(material, cos_i, np.ones(n), cos_h, cos_h, grid.wavelengths) * (np.pi * cos_i[:, None])
    rgb = signal @ channel_matrix(sens, e, grid) @ transform
    rgb *= rng.uniform(0.1, 3.0) / max(float(rgb.mean()), 1e-300)
    rgb *= 1.0 + cast * rng.standard_normal(3)                     # the region's unmodelled colour error
    rgb *= 1.0 + noise * rng.standard_normal(rgb.shape)
    return np.maximum(rgb, 0.0), {"pixels": n, "light_deg": region_deg, "noise": noise, "cast": cast}


def _chart_transform(rng: np.random.Generator, sens: np.ndarray, model_sens: np.ndarray, e: np.ndarray,
                     chart: np.ndarray, grid: Any) -> np.ndarray:
    """The pipeline's 3 x 3 from the true camera to the model camera, fitted on noisy ColorChecker patch means."""
    from processing.camera.response import camera_rgb
    from processing.camera.transfer import fit_chart_transform

    measured = camera_rgb(chart, e, sens, grid)
    measured = measured * (1.0 + _CHART_NOISE * rng.standard_normal(measured.shape))
    return fit_chart_transform(np.maximum(measured, 0.0), camera_rgb(chart, e, model_sens, grid)).matrix


def _draws(n_regions: int, seed: int, model_error: float | None,
           colour_error: tuple[float, float] | None) -> list[dict[str, Any]]:
    """Every region's truth, answer, confidence and whether it was right."""
    from processing.camera.response import camera_sensitivities
    from processing.materials.confidence import Decision, is_right
    from processing.materials.identification import DEFAULT_CANDIDATES, candidate_set, identify_material
    from processing.spectral.reflectance_database import load_reflectances
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    grid = SpectralGrid(400, 700, 10)
    e = light_spectrum("D65", grid)
    model_sens = camera_sensitivities(grid)
    chart = load_reflectances("colorchecker", grid).spectra
    cands = candidate_set(model_sens, e, grid, light_deg=_LIGHT_DEG)
    kwargs = {} if model_error is None else {"model_error": model_error}
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n_regions):
        truth = DEFAULT_CANDIDATES[int(rng.integers(len(DEFAULT_CANDIDATES)))]
        sens, camera = _true_camera(rng, grid)
        transform = _chart_transform(rng, sens, model_sens, e, chart, grid)
        px, drawn = _region_pixels(rng, _true_material(rng, truth), e, sens, transform, grid,
                                   colour_error)
        if not np.any(px.mean(axis=0) > 0):
            continue
        r = identify_material(px, cands, noise=_STATED_NOISE, **kwargs)
        decision = Decision(r.material, r.confidence, tuple(r.group), 0, np.zeros(0), float("nan"))
        rows.append({"truth": truth, "answer": r.material, "confidence": float(r.confidence),
                     "right": bool(is_right(decision, truth)), "misfit": float(getattr(r, "misfit", float("nan"))),
                     "camera": camera, **drawn})
    return rows


def _highlight_patch(rng: np.random.Generator, material: Any, e: np.ndarray, sens: np.ndarray,
                     transform: np.ndarray, grid: Any, colour_error: tuple[float, float] | None
                     ) -> tuple[np.ndarray, np.ndarray, dict[str, Any]] | None:
    """One clicked patch through a Bayer sensor and the ``bin2x2`` decode: its usable pixels, their predicted CFA
    fringe (both in the model camera's units), and how it was drawn; None when the patch is too dark to click."""
    from processing.camera.cfa_fringe import transformed_fringe
    from processing.camera.raw_decode import bin2x2
    from processing.camera.response import channel_matrix
    from processing.materials.lobes import material_brdf

    side = int(round(math.exp(rng.uniform(math.log(2.0), math.log(40.0)))))      # binned pixels
    full = 2 * side
    pattern = ("RGGB", "BGGR", "GRBG", "GBRG")[int(rng.integers(4))]
    shape = ("flat", "highlight", "edge")[int(rng.integers(3))]
    yy, xx = np.mgrid[0:full, 0:full] + 0.5
    if shape == "flat":
        level = np.ones((full, full))
        width = 0.0
    elif shape == "highlight":            # a highlight of width sigma photosites, centred anywhere in the patch
        width = float(math.exp(rng.uniform(math.log(0.7), math.log(12.0))))
        cy, cx = rng.uniform(0, full, 2)
        level = np.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * width**2)) + rng.uniform(0.0, 0.2)
    else:                                 # the edge of a lit part: a smooth step across the patch
        width = float(math.exp(rng.uniform(math.log(0.5), math.log(8.0))))
        ang = rng.uniform(0, 2 * math.pi)
        d = (yy - full / 2) * math.sin(ang) + (xx - full / 2) * math.cos(ang)
        level = 1.0 / (1.0 + np.exp(-d / width)) + 0.01
    region_deg = float(rng.uniform(15.0, 60.0))
    noise = float(math.exp(rng.uniform(math.log(0.003), math.log(0.03))))
    lo, hi = colour_error or (0.0, 0.0)
    cast = float(math.exp(rng.uniform(math.log(lo), math.log(hi)))) if lo > 0 else 0.0
    tilt = 5.0 * rng.standard_normal(2)                  # neighbouring photosites share the surface's normal
    deg = region_deg + tilt[0] * (yy / full - 0.5) * 2 + tilt[1] * (xx / full - 0.5) * 2
    t = np.radians(np.clip(deg.ravel(), 2.0, 80.0))
    cos_i, cos_h = np.cos(t), np.cos(t / 2)
    signal = material_brdf(material, cos_i, np.ones(t.size), cos_h, cos_h, grid.wavelengths) * (np.pi * cos_i[:, None])
    raw = (signal @ channel_matrix(sens, e, grid)).reshape(full, full, 3) * level[..., None]
    raw *= 1.0 + cast * rng.standard_normal(3)
    green = float(math.exp(rng.uniform(math.log(0.01), math.log(0.6))))          # the patch's mean green level
    raw *= green / max(float(raw[..., 1].mean()), 1e-300)
    idx = np.array(["RGB".index(c) for c in pattern])
    cfa = np.empty((full, full), np.intp)
    for k in range(4):
        cfa[k // 2::2, k % 2::2] = idx[k]
    mosaic = np.take_along_axis(raw, cfa[..., None], axis=2)[..., 0]
    mosaic = mosaic * (1.0 + noise * rng.standard_normal(mosaic.shape)) + READ_NOISE * rng.standard_normal(mosaic.shape)
    sat = mosaic >= 1.0
    rgb, clipped, _ = bin2x2(np.clip(mosaic, 0.0, 1.0).astype(np.float32), idx, sat, np.zeros_like(sat))
    rgb = np.maximum(rgb.astype(np.float64), 0.0)
    if float(rgb[..., 1][~clipped].mean()) < _MIN_SIGNAL if (~clipped).any() else True:
        return None
    cam = rgb @ transform
    fringe = transformed_fringe(rgb, pattern, transform)
    keep = ~clipped
    return np.maximum(cam[keep], 0.0), fringe[keep], {"pixels": int(keep.sum()), "shape": shape, "width": width,
                                                     "pattern": pattern, "light_deg": region_deg, "noise": noise,
                                                     "cast": cast}


def _highlight_draws(n_patches: int, seed: int, fringe: bool,
                     colour_error: tuple[float, float] | None, sensor: bool = True) -> list[dict[str, Any]]:
    """Every clicked patch's truth and answer, with (``fringe``) or without the predicted CFA fringe, with
    (``sensor``) or without the sensor's read noise and the chart transform the pixels went through."""
    from processing.camera.response import camera_sensitivities
    from processing.camera.transfer import transformed_read_noise
    from processing.materials.confidence import Decision, is_right
    from processing.materials.identification import (
        DEFAULT_CANDIDATES,
        candidate_set,
        identify_material,
    )
    from processing.spectral.estimation.fit import SpectralEstimationError
    from processing.spectral.reflectance_database import load_reflectances
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    grid = SpectralGrid(400, 700, 10)
    e = light_spectrum("D65", grid)
    model_sens = camera_sensitivities(grid)
    chart = load_reflectances("colorchecker", grid).spectra
    cands = candidate_set(model_sens, e, grid, light_deg=_LIGHT_DEG)
    rng = np.random.default_rng(seed)
    rows = []
    for _ in range(n_patches):
        truth = DEFAULT_CANDIDATES[int(rng.integers(len(DEFAULT_CANDIDATES)))]
        sens, camera = _true_camera(rng, grid)
        transform = _chart_transform(rng, sens, model_sens, e, chart, grid)
        drawn = _highlight_patch(rng, _true_material(rng, truth), e, sens, transform, grid, colour_error)
        if drawn is None:
            continue                      # refused: too dark to have a colour (the panel says so)
        px, err, info = drawn
        try:
            r = identify_material(px, cands, noise=_STATED_NOISE, colour_error=err if fringe else None,
                                  dark_noise=transformed_read_noise(transform, READ_NOISE) if sensor else None,
                                  transform=transform if sensor else None)
        except SpectralEstimationError:
            continue                      # refused: every pixel's colour is mostly fringe (FringeOnlyError) or black
        decision = Decision(r.material, r.confidence, tuple(r.group), 0, np.zeros(0), float("nan"))
        rows.append({"truth": truth, "answer": r.material, "confidence": float(r.confidence),
                     "right": bool(is_right(decision, truth)), "misfit": float(r.misfit), "camera": camera,
                     "fringe_max": float(np.abs(err).max(initial=0.0)), **info})
    return rows


def highlight_reliability(n_patches: int = 3000, seed: int = 0, *, fringe: bool = True,
                          colour_error: tuple[float, float] | None = COLOUR_ERROR, bins: int = 10,
                          sensor: bool = True) -> dict[str, Any]:
    """Clicked patches through a Bayer sensor and the ``bin2x2`` decode: stated confidence against accuracy.

    Each patch: a candidate drawn as in :func:`single_image_reliability` (material, camera, chart
    transform, noise, unmodelled colour error; the angle 15-60 deg tilting smoothly by N(0, 5) deg across the patch), 2-40 binned pixels on a side (log-uniform),
    lit flat, by a highlight (a Gaussian of 0.7-12 photosites) or across the edge of a lit part (a
    smooth step 0.5-8 photosites wide), the mean green at 1-60 % of full scale (log-uniform; brighter
    photosites clip); mosaicked
    through one of the four Bayer patterns, photosite noise, clipped photosites left out, binned
    (:func:`processing.camera.raw_decode.bin2x2`) and carried to the model camera by the chart
    transform.  Patches whose green averages below 2 % of full scale are refused, as the spectra
    panel refuses such a click, and so are patches whose every pixel is mostly fringe
    (:class:`processing.materials.identification.FringeOnlyError`).  ``fringe``: give the identification the predicted CFA fringe
    (:func:`processing.camera.cfa_fringe.transformed_fringe`), as the spectra panel does.  ``sensor``:
    give it the sensor's read noise (:data:`READ_NOISE` per photosite, binned and carried by the
    patch's chart transform) and that transform (``dark_noise`` and ``transform`` of
    :func:`processing.materials.identification.identify_material`), as the spectra panel does.

    Returns
    -------
    dict
        As :func:`single_image_reliability`, plus ``refused`` (too dark), ``fringe`` and
        ``high_wrong`` (answers stated >= 0.9 and wrong: truth, answer, shape, pixels), ``by_shape``.
    """
    from processing.materials.confidence import NO_FIT, reliability_table

    t0 = time.perf_counter()
    rows = _highlight_draws(n_patches, seed, fringe, colour_error, sensor)
    named = [r for r in rows if r["answer"] != NO_FIT]
    rel = reliability_table([r["confidence"] for r in named], [r["right"] for r in named], bins=bins)
    met = bool(rel.high_count > 0 and rel.high_accuracy >= TARGETS["high_accuracy"] and rel.ece <= TARGETS["ece"])
    wrong = [{k: r[k] for k in ("truth", "answer", "confidence", "shape", "pixels", "fringe_max")}
             for r in named if r["confidence"] >= 0.9 and not r["right"]]
    by_shape = {}
    for shape in ("flat", "highlight", "edge"):
        mine = [r for r in named if r["shape"] == shape]
        by_shape[shape] = {"answered": len(mine),
                           "right": float(np.mean([r["right"] for r in mine])) if mine else float("nan"),
                           "high": sum(r["confidence"] >= 0.9 for r in mine),
                           "high_right": (float(np.mean([r["right"] for r in mine if r["confidence"] >= 0.9]))
                                          if any(r["confidence"] >= 0.9 for r in mine) else float("nan"))}
    return {
        "regions": len(rows), "refused": n_patches - len(rows), "answered": len(named),
        "abstained": len(rows) - len(named), "abstention_share": (len(rows) - len(named)) / max(len(rows), 1),
        "accuracy": float(np.mean([r["right"] for r in named])) if named else float("nan"),
        "mean_confidence": float(np.mean([r["confidence"] for r in named])) if named else float("nan"),
        "table": {"edges": rel.edges.tolist(), "count": rel.count.tolist(),
                  "stated": [None if math.isnan(v) else float(v) for v in rel.stated],
                  "observed": [None if math.isnan(v) else float(v) for v in rel.observed]},
        "ece": rel.ece, "high_accuracy": rel.high_accuracy, "high_count": rel.high_count,
        "high_wrong": wrong, "by_shape": by_shape, "fringe": fringe, "sensor": sensor,
        "targets": dict(TARGETS), "met": met and not wrong, "seed": seed, "seconds": time.perf_counter() - t0,
    }


def single_image_reliability(n_regions: int = 3000, seed: int = 0, *, model_error: float | None = None,
                             colour_error: tuple[float, float] | None = COLOUR_ERROR,
                             bins: int = 10) -> dict[str, Any]:
    """Draw ``n_regions`` simulated regions, identify each, tabulate stated confidence against accuracy.

    Parameters
    ----------
    n_regions
        Regions drawn (module text for how).
    seed
        Seed of the draws.
    model_error
        Model error given to the identification; None: its default.
    colour_error
        ``(low, high)`` range of the unmodelled per-region colour error (log-uniform, relative per
        channel); None: none (the camera, geometry, material and noise draws only).
    bins
        Equal-width confidence bins of the table.

    Returns
    -------
    dict
        ``regions``, ``answered`` (naming a material or a neutral-metal group), ``abstained``
        ("no candidate fits"), ``abstention_share``, ``accuracy`` (right among answered),
        ``table`` (``edges``, ``count``, ``stated``, ``observed`` per bin), ``ece``,
        ``high_accuracy`` and ``high_count`` (answers stated >= 0.9), ``targets`` and ``met``,
        ``per_material`` (truth -> right share, abstention share), ``seconds``.
    """
    from processing.materials.confidence import NO_FIT, reliability_table

    t0 = time.perf_counter()
    rows = _draws(n_regions, seed, model_error, colour_error)
    named = [r for r in rows if r["answer"] != NO_FIT]
    rel = reliability_table([r["confidence"] for r in named], [r["right"] for r in named], bins=bins)
    per: dict[str, dict[str, float]] = {}
    for name in sorted({r["truth"] for r in rows}):
        mine = [r for r in rows if r["truth"] == name]
        ans = [r for r in mine if r["answer"] != NO_FIT]
        per[name] = {"regions": len(mine), "right": float(np.mean([r["right"] for r in ans])) if ans else float("nan"),
                     "abstained": 1.0 - len(ans) / len(mine)}
    met = bool(rel.high_count > 0 and rel.high_accuracy >= TARGETS["high_accuracy"] and rel.ece <= TARGETS["ece"])
    return {
        "regions": len(rows), "answered": len(named), "abstained": len(rows) - len(named),
        "abstention_share": (len(rows) - len(named)) / max(len(rows), 1),
        "accuracy": float(np.mean([r["right"] for r in named])) if named else float("nan"),
        "mean_confidence": float(np.mean([r["confidence"] for r in named])) if named else float("nan"),
        "table": {"edges": rel.edges.tolist(), "count": rel.count.tolist(),
                  "stated": [None if math.isnan(v) else float(v) for v in rel.stated],
                  "observed": [None if math.isnan(v) else float(v) for v in rel.observed]},
        "ece": rel.ece, "high_accuracy": rel.high_accuracy, "high_count": rel.high_count,
        "targets": dict(TARGETS), "met": met, "per_material": per, "seed": seed,
        "model_error": model_error, "colour_error": None if colour_error is None else list(colour_error), "seconds": time.perf_counter() - t0,
    }


def markdown(result: dict[str, Any]) -> str:
    """The reliability table and the headline figures as Markdown."""
    t = result["table"]
    lines = ["| stated confidence | answers | mean stated | observed right |", "|---|---:|---:|---:|"]
    for k, count in enumerate(t["count"]):
        if count:
            lines.append(f"| {t['edges'][k]:.1f}-{t['edges'][k + 1]:.1f} | {count} | {t['stated'][k]:.3f} | "
                         f"{t['observed'][k]:.3f} |")
    lines += ["", f"{result['regions']} regions: {result['answered']} answered, {result['abstained']} "
              f"'no candidate fits' ({100 * result['abstention_share']:.1f} %); right among answered "
              f"{100 * result['accuracy']:.1f} % (mean stated {100 * result['mean_confidence']:.1f} %).",
              f"Stated >= 0.9: {result['high_count']} answers, {100 * result['high_accuracy']:.1f} % right "
              f"(target >= {100 * TARGETS['high_accuracy']:.0f} %); ECE {result['ece']:.3f} "
              f"(target <= {TARGETS['ece']:.2f}); targets {'met' if result['met'] else 'NOT met'}."]
    return "\n".join(lines)


def figure(result: dict[str, Any], path: Path) -> Path:
    """Write the reliability diagram (stated against observed per bin, counts below) as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result["table"]
    edges = np.asarray(t["edges"])
    mid = 0.5 * (edges[:-1] + edges[1:])
    filled = np.asarray(t["count"]) > 0
    stated = np.array([np.nan if v is None else v for v in t["stated"]])
    observed = np.array([np.nan if v is None else v for v in t["observed"]])
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(4.6, 6.0), gridspec_kw={"height_ratios": [3, 1]}, sharex=True)
    ax.plot([0, 1], [0, 1], "k:", label="calibrated")
    ax.bar(mid[filled], observed[filled], width=np.diff(edges)[filled] * 0.9, color="0.75", edgecolor="0.3",
           label="observed right")
    ax.plot(stated[filled], observed[filled], "ro-", label="(mean stated, observed)")
    ax.set_ylabel("share right")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.legend(fontsize=7, loc="upper left")
    what = "clicked patches (Bayer, bin2x2)" if "by_shape" in result else "single-image identification"
    ax.set_title(f"{what}: ECE {result['ece']:.3f}, >= 0.9: "
                 f"{100 * result['high_accuracy']:.1f} % right", fontsize=9)
    bx.bar(mid, t["count"], width=np.diff(edges) * 0.9, color="0.5")
    bx.set_xlabel("stated confidence")
    bx.set_ylabel("answers")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    """``python -m bench.reliability``: print the Markdown table; with ``--out`` write the PNG and JSON."""
    ap = argparse.ArgumentParser(prog="python -m bench.reliability", description=__doc__.split("\n")[0])
    ap.add_argument("--regions", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--model-error", type=float, default=None)
    ap.add_argument("--no-colour-error", action="store_true", help="leave out the unmodelled colour error")
    ap.add_argument("--highlights", type=int, default=0, metavar="N",
                    help="also N clicked patches through a Bayer sensor and the bin2x2 decode (highlight_reliability)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    result = single_image_reliability(args.regions, args.seed, model_error=args.model_error,
                                      colour_error=None if args.no_colour_error else COLOUR_ERROR)
    print(markdown(result))
    patches = highlight_reliability(args.highlights, args.seed + 1) if args.highlights > 0 else None
    if patches is not None:
        print("\nClicked patches (Bayer sensor, bin2x2 decode, CFA fringe told):\n")
        print(markdown(patches))
        print(f"Refused (too dark, or fringe only): {patches['refused']}; stated >= 0.9 and wrong: "
              f"{len(patches['high_wrong'])}.")
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        figure(result, args.out / "reliability.png")
        (args.out / "reliability.json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
        if patches is not None:
            figure(patches, args.out / "reliability-highlights.png")
            (args.out / "reliability-highlights.json").write_text(json.dumps(patches, indent=1) + "\n",
                                                                  encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
