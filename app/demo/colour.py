"""The colour demo: the simulated hawk's head photographed with a chart, its materials identified and checked.

Matsuda et al., section 4 (spectral estimation, eq. (6)-(10); identification,
eq. (11) and (3)-(4)), run end to end on the simulated station
(:class:`mocks.world.World`): the chart frame (a ColorChecker Classic laid out
on the backdrop) and the object at a few turntable angles go through the
simulated Nikon D5100 into DNG files, and then through the same library calls
as ``kogei spectral estimate`` and ``kogei identify``
(:func:`app.workflows.spectral.estimate_spectral`, the chart measured once by
:func:`app.workflows.chart.measure_chart`;
:func:`app.workflows.identification.identify_result`), with the world's own
region labels as the regions.  The answers are compared with the world's true
materials and alloy compositions.

Why several views and a light near the camera: a glossy metal under one
directional light is black except near its highlights, and a highlight lies
where the surface normal halves the light and the view.  With the light
15 deg from the camera, each region facing the camera shows highlights in
some view; the pixels of all views are pooled per region.  The candidates are
modelled with the light 40 deg from the normal (``light_deg``), away from the
highlight geometry (15 deg): there a lacquer shows its pigment, as most of a
lacquered region's pixels do, while a metal's Fresnel colour hardly changes
between half-angles of 7.5 and 20 deg (on this scene, modelling at 15 deg
turns the pupil's black urushi into a shibuichi and leaves the rest as they
are).  A model error
(:data:`processing.materials.identification.DEFAULT_MODEL_ERROR`, 1.75 %) is added to the noise of a region's mean:
across a region the Fresnel colour changes a little with the angle and
urushi mixes pigment and gloss in varying proportions, which the one-geometry
candidates do not follow; without it thousands of pooled pixels would make
every answer look certain.

The radiance is blurred by a Gaussian of one sensor pixel before the mosaic
(a lens and its anti-aliasing filter, :func:`mocks.camera_sim.lens_blur`: the
world's object photos carry it, the chart is blurred here); region labels leave out the ring of
pixels the blur mixes with the neighbouring region.

Writes into ``out_dir``: ``chart.dng``, ``object_<angle>.dng`` and
``labels_<angle>.png`` (binned resolution, region index + 1), ``identify.json``
(the comparison) and ``spectra.png`` (per region the estimated spectrum with
its uncertainty against the identified material's model spectrum, and the
material map of the first view).
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["colour_demo", "LIGHT_DIRECTION", "model_spectrum"]

#: Toward the light, table frame: about 15 deg from the camera (which looks from -y, 15 deg up).
LIGHT_DIRECTION = (0.2, -0.93, 0.45)
_CHART_EXPOSURE_S = 0.01        # the simulated camera's white diffuser at about 70 % of full scale


def _binned_labels(labels: NDArray[np.integer]) -> NDArray[np.int64]:
    """Region index + 1 per 2 x 2 cell whose neighbourhood (the cell and the cells around it) is one region.

    The ring of cells is left out because the lens blur mixes neighbouring regions there.
    """
    from scipy.ndimage import maximum_filter, minimum_filter

    lab = labels.astype(np.int64) + 1
    cells = np.stack([lab[0::2, 0::2], lab[0::2, 1::2], lab[1::2, 0::2], lab[1::2, 1::2]])
    lo, hi = cells.min(axis=0), cells.max(axis=0)
    same = (minimum_filter(lo, size=3, mode="nearest") == maximum_filter(hi, size=3, mode="nearest"))
    return np.where(same, cells[0], 0)


def model_spectrum(material: str, wavelengths: NDArray[np.float64], cos_d: float) -> NDArray[np.float64]:
    """The spectral factor of a material at ``cos_d``: a metal's Fresnel reflectance, urushi's pigment.

    Examples
    --------
    >>> wl = np.array([450.0, 650.0])
    >>> r = model_spectrum("gold", wl, 1.0)
    >>> bool(r[1] > r[0])        # gold reflects red more than blue
    True
    """
    from processing.materials.presets import get_material

    mat = get_material(material)
    # the lobe with the largest weight carries the colour (the gloss lobe of a lacquer is nearly white)
    lobe = max(mat.lobes, key=lambda lb: lb.weight if mat.family in ("metal", "alloy") or lb.kind == "lambert"
               else -1.0)
    return np.asarray(lobe.spectral.reflectance(cos_d, wavelengths), dtype=np.float64)


def _angle_deg(a: tuple[float, float, float], b: NDArray[np.float64]) -> float:
    u = np.asarray(a, dtype=np.float64)
    return math.degrees(math.acos(float(np.clip(u @ b / (np.linalg.norm(u) * np.linalg.norm(b)), -1, 1))))


def colour_demo(
    out_dir: str | Path,
    *,
    triangles: int = 8_000,
    size: tuple[int, int] = (600, 400),
    angles: tuple[float, ...] = (-25.0, 0.0, 25.0),
    method: str = "rootpoly",
    model_error: float | None = None,
    object_exposure: float = 0.25,
    light_direction: tuple[float, float, float] = LIGHT_DIRECTION,
    light_deg: float | None = 40.0,
    seed: int = 0,
) -> dict[str, Any]:
    """Simulate, estimate, identify and compare with the truth; write the files; return the comparison.

    Parameters
    ----------
    out_dir
        Folder for the DNGs, labels, ``identify.json`` and ``spectra.png`` (created).
    triangles
        Triangle count of the procedural hawk.
    size
        Image size (width, height) in sensor pixels; ``cv2.mcc`` needs 600 x 400 or more.
    angles
        Turntable angles of the object frames (degrees).
    method
        Spectral estimator (default rootpoly, the best one-shot method in docs/BENCHMARKS.md).
    model_error
        Relative model error of the candidates (see the module text); None:
        :data:`processing.materials.identification.DEFAULT_MODEL_ERROR`, as ``kogei identify`` and the batch.
    object_exposure
        Exposure of the object frames relative to the chart's (metal highlights are many times
        brighter than the chart's white; the chart's values are scaled by the files' exposure times).
    light_direction
        Toward the light in the table's frame.
    light_deg
        Light angle from the normal at which the candidates are modelled (see the module text);
        None: the angle between the light and the camera, the geometry of a highlight.
    seed
        Noise seed of the first frame.

    Returns
    -------
    dict
        ``regions`` (per region: true material, identified material, confidence, runner-up,
        true and estimated alloy weights, pixels), ``correct`` / ``regions_identified``, the
        estimate's metadata, ``seconds`` and the paths written.
    """
    from app.workflows.identification import identify_result, usable_regions
    from mocks.world import World
    from processing.materials.identification import DEFAULT_MODEL_ERROR

    if model_error is None:
        model_error = DEFAULT_MODEL_ERROR
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    width, height = size
    world = World.hawk(triangles, chart_layout="classic24", width=width, height=height,
                       light_direction=light_direction)
    chart_path, results, label_images = _shoot_and_estimate(world, out, angles, method, object_exposure, seed)
    pooled = _pooled(results, method)
    labels = np.concatenate(label_images, axis=1)
    el = math.radians(world.camera_elevation_deg)
    if light_deg is None:
        light_deg = _angle_deg(light_direction, np.array([0.0, -math.cos(el), math.sin(el)]))
    reports = identify_result(pooled, labels, light_deg=light_deg, model_error=model_error)
    shapes = _relative_spectra(pooled, usable_regions(pooled, labels))
    cos_d = math.cos(math.radians(light_deg / 2))
    regions = [_region_row(world, rep, shapes) for rep in reports]
    summary = {
        "format": "kogei-colour-demo",
        "version": 1,
        "method": method,
        "angles_deg": list(angles),
        "light_deg": light_deg,
        "model_error": model_error,
        "chart_rmse": [r.method_error for r in results],
        "chart_condition": [r.metadata["condition"].get("chart") for r in results],
        "masked_pixels": [r.metadata["masked_pixels"] for r in results],
        "wavelengths": results[0].wavelengths.tolist(),
        "regions": regions,
        "regions_identified": sum(r["material"] is not None for r in regions),
        "correct": sum(bool(r["correct"]) for r in regions),
    }
    (out / "identify.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    _figure(out / "spectra.png", summary, cos_d, label_images[0], pooled.mask[:, :label_images[0].shape[1]],
            world.region_names)
    summary["seconds"] = time.perf_counter() - t0
    summary["files"] = {"identify": str(out / "identify.json"), "figure": str(out / "spectra.png"),
                        "chart": str(chart_path)}
    return summary


def _shoot_and_estimate(world: Any, out: Path, angles: tuple[float, ...], method: str, object_exposure: float,
                        seed: int) -> tuple[Path, list[Any], list[NDArray[np.int64]]]:
    """The chart and object frames as DNGs (and label PNGs), each view estimated through the chart measured once."""
    from app.workflows.chart import measure_chart
    from app.workflows.spectral import estimate_spectral
    from mocks.camera_sim import lens_blur, simulate_raw, write_raw

    chart = world.frame("chart")
    chart_raw = simulate_raw(lens_blur(chart.radiance), chart.grid, chart.light, seed=seed,
                             exposure_s=_CHART_EXPOSURE_S)
    chart_path = write_raw(out / "chart.dng", chart_raw)
    chart_measured = measure_chart(chart_path)
    results, label_images = [], []
    for k, angle in enumerate(angles):
        frame = world.frame("object", angle)
        name = f"object_{angle:+04.0f}"
        raw = simulate_raw(frame.radiance, frame.grid, frame.light, seed=seed + 1 + k,
                           exposure_s=_CHART_EXPOSURE_S * object_exposure)
        dng = write_raw(out / f"{name}.dng", raw)
        labels = _binned_labels(frame.labels)
        _write_png(out / f"labels_{angle:+04.0f}.png", labels.astype(np.uint16))
        results.append(estimate_spectral(dng, chart_measured, method=method))
        label_images.append(labels)
    return chart_path, results, label_images


def _pooled(results: list[Any], method: str) -> Any:
    """One result of the views side by side: regions pool their pixels over the views."""
    from app.workflows.spectral import SpectralResult

    return SpectralResult(
        np.concatenate([r.weights for r in results], axis=1), results[0].basis, results[0].wavelengths,
        np.concatenate([r.mask for r in results], axis=1), np.concatenate([r.camera for r in results], axis=1),
        results[0].sensitivities, results[0].lights, method,
        {**results[0].metadata, "chart_rmse": max(r.method_error for r in results)},
    )


def _region_row(world: Any, rep: Any, shapes: dict[int, dict[str, list[float]]]) -> dict[str, Any]:
    """One region's identification beside the world's true material and alloy composition."""
    from processing.materials.identification import NEUTRAL_METAL
    from processing.materials.presets import get_material

    region = world.region_names[rep.label - 1]
    true = world.materials[region]
    mat = get_material(true)
    true_comp = ({m: float(mat.parameters.get(m, 0.0)) for m in ("Ag", "Cu", "Au")}
                 if mat.family in ("metal", "alloy") else None)
    return {
        "region": region,
        "true_material": true,
        "material": rep.material,
        # right: the material named, or a neutral-metal group holding it ("no candidate fits" names none, and
        # the contenders listed beside a named material do not make it right)
        "correct": rep.material == true or (rep.material == NEUTRAL_METAL and true in rep.group),
        "confidence": rep.confidence,
        "chi2": rep.chi2,
        "misfit": rep.misfit,
        "runner_up": rep.runner_up,
        "group": list(rep.group),
        "pixels": rep.pixels,
        "true_alloy_weights": true_comp,
        "alloy_weights": rep.alloy_weights,
        "alloy_std": rep.alloy_std,
        "reflectance": rep.reflectance,
        "uncertainty": rep.uncertainty,
        "note": rep.note,
        "relative": shapes.get(rep.label),
    }


def _relative_spectra(result, live: NDArray[np.int64]) -> dict[int, dict[str, list[float]]]:
    """Per region the mean and spread of the pixels' spectra, each scaled to a mean of 1 over wavelength.

    A metal's brightness changes across a region with the angle to its highlight, its colour
    hardly: dividing each pixel by its own level leaves the spread of the colour.
    """
    out = {}
    flat = live.ravel()
    w = result.weights.reshape(-1, result.weights.shape[2])
    for r in np.unique(flat[flat > 0]):
        s = w[flat == r].astype(np.float64) @ result.basis.T
        level = s.mean(axis=1)
        s = s[level > 0] / level[level > 0, None]
        if len(s):
            out[int(r)] = {"mean": s.mean(axis=0).tolist(), "std": s.std(axis=0).tolist()}
    return out


def _write_png(path: Path, image: NDArray) -> None:
    import cv2

    if not cv2.imwrite(str(path), image):
        raise OSError(f"could not write {path}")


def _figure(path: Path, summary: dict[str, Any], cos_d: float, labels: NDArray[np.int64], mask: NDArray[np.bool_],
            region_names: tuple[str, ...]) -> None:
    """spectra.png: per region its spectrum against the models, the material map, the table of answers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    wl = np.asarray(summary["wavelengths"])
    regions = summary["regions"]
    n = len(regions)
    fig, axes = plt.subplots(2, max(n, 2), figsize=(3.2 * max(n, 2), 6.4), squeeze=False)
    for i, reg in enumerate(regions):
        _spectrum_axes(axes[0, i], reg, wl, cos_d)
    for j in range(n, axes.shape[1]):
        axes[0, j].axis("off")
    _map_axes(axes, regions, labels, mask, region_names)
    for j in range(2, axes.shape[1]):
        axes[1, j].axis("off")
    if axes.shape[1] > 2:
        _answer_table(fig, axes, regions)
    views = len(summary["angles_deg"])
    fig.suptitle(f"Simulated hawk: {summary['correct']} of {len(regions)} regions identified right "
                 f"({summary['method']}, {views} view{'s' if views > 1 else ''})", fontsize=11)
    fig.subplots_adjust(left=0.05, right=0.99, top=0.86, bottom=0.04, wspace=0.35, hspace=0.35)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _spectrum_axes(ax: Any, reg: dict[str, Any], wl: NDArray[np.float64], cos_d: float) -> None:
    """One region's estimated spectrum (shape, with its spread) against the identified and the true model."""
    if reg["relative"] is None or reg["material"] is None:
        ax.set_title(f"{reg['region']}: not identified\ntrue {reg['true_material']}", fontsize=9)
        ax.text(0.5, 0.5, reg["note"].replace(" (", "\n("), ha="center", va="center", fontsize=8,
                transform=ax.transAxes)
        ax.axis("off")
        return
    est = np.asarray(reg["relative"]["mean"])
    spread = np.asarray(reg["relative"]["std"])
    ax.fill_between(wl, est - spread, est + spread, color="0.82", label="estimate +- spread over pixels")
    ax.plot(wl, est, "k-", label="estimate")
    for name, style in ((reg["material"], "r--"), (reg["true_material"], "b:")):
        if name in ("neutral metal", "no candidate fits"):
            continue
        model = model_spectrum(name, wl, cos_d)
        # brightness depends on gloss and angles, not on the material: compare the shapes
        ax.plot(wl, model / model.mean(), style, label=f"{name} (model)")
        if reg["material"] == reg["true_material"]:
            break
    verdict = "right" if reg["correct"] else "WRONG"
    ax.set_title(f"{reg['region']}: {reg['material']} ({reg['confidence']:.2f})\ntrue {reg['true_material']}: "
                 f"{verdict}", fontsize=9)
    ax.set_xlabel("wavelength (nm)", fontsize=8)
    ax.set_ylabel("reflectance / its mean", fontsize=8)
    ax.set_ylim(0, max(2.0, float(np.max(est + spread)) * 1.05))
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=6, loc="upper left")


def _map_axes(axes: Any, regions: list[dict[str, Any]], labels: NDArray[np.int64], mask: NDArray[np.bool_],
              region_names: tuple[str, ...]) -> None:
    """The first view's true regions and its material map (each region in its material's sRGB under D65)."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    from app.workflows.materials import preset_srgb

    colours = [(0.1, 0.1, 0.1)]
    for reg in regions:
        name = reg["material"]
        if name is None or name in ("neutral metal", "no candidate fits"):
            colours.append((0.75, 0.75, 0.78) if name == "neutral metal" else (1.0, 0.0, 1.0))
        else:
            colours.append(tuple(np.asarray(preset_srgb(name)) / 255.0))
    lut = np.zeros(labels.max() + 1, dtype=np.int64)
    for k, reg in enumerate(regions, start=1):
        lut[region_names.index(reg["region"]) + 1] = k
    index = np.where(mask, lut[labels], 0)
    for j, (img, title) in enumerate(((labels, "true regions (first view)"), (index, "identified materials"))):
        ax = axes[1, j]
        if j == 0:
            ax.imshow(img, cmap="tab10", interpolation="nearest", vmin=0, vmax=9)
        else:
            ax.imshow(img, cmap=ListedColormap(colours), interpolation="nearest", vmin=0, vmax=len(colours) - 1)
            handles = [plt.Rectangle((0, 0), 1, 1, color=colours[k]) for k in range(1, len(colours))]
            key = axes[1, 2] if axes.shape[1] > 2 else ax
            names = [f"{r['region']}: {r['material'] or 'not identified'}" for r in regions]
            key.legend(handles, names, fontsize=7, loc="upper left", title="identified", title_fontsize=8)
        ax.set_title(title, fontsize=9)
        ax.axis("off")


def _answer_table(fig: Any, axes: Any, regions: list[dict[str, Any]]) -> None:
    """A text table: per region the true and the identified material, and the alloy weights."""
    lines = ["region    true -> identified (confidence)   Ag / Cu / Au true -> estimated"]
    for reg in regions:
        conf = "" if reg["confidence"] is None else f" ({reg['confidence']:.2f})"
        alloy = ""
        if reg["true_alloy_weights"] and reg["alloy_weights"]:
            t, e = reg["true_alloy_weights"], reg["alloy_weights"]
            alloy = ("   " + " / ".join(f"{100 * t[m]:.0f}" for m in ("Ag", "Cu", "Au")) + " -> "
                     + " / ".join(f"{100 * e[m]:.0f}" for m in ("Ag", "Cu", "Au")) + " %")
        lines.append(f"{reg['region']}: {reg['true_material']} -> {reg['material']}{conf}{alloy}")
    fig.text(0.6 if axes.shape[1] > 3 else 0.02, 0.42, "\n".join(lines), va="top", ha="left", fontsize=8,
             family="monospace")
