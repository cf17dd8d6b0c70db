"""The plots of the session report (``kogei report``): matplotlib figures returned as PNG bytes.

Each function takes plain data read from the session (docs/report.md) and
returns the PNG; :mod:`app.report.html` embeds it as a base64 data URI so the
report is one self-contained file.  The Agg backend is used (no display).
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["png_of", "calibration_residuals_figure", "frame_residuals_figure", "overlay_sheet", "pose_graph_figure", "coverage_figure", "holes_figure",
           "timing_figure", "data_uri", "chart_overlay_figure", "patch_error_figure",
           "material_spectra_figure", "region_map_figure", "probe_tone_map", "probe_map_figure", "PALETTE",
           "palette_colour"]

DPI = 100

#: Colours of regions on maps: the Okabe-Ito palette (distinguishable with common colour-vision deficiencies;
#: Okabe & Ito 2008, https://jfly.uni-koeln.de/color/), then further saturated colours; no greys (grey means
#: backdrop or not measured).
PALETTE = ((230, 159, 0), (86, 180, 233), (0, 158, 115), (240, 228, 66), (0, 114, 178), (204, 121, 167),
           (140, 86, 75), (23, 190, 207), (188, 189, 34), (148, 103, 189), (31, 119, 180), (255, 187, 120))
#: Map colour of a region with no trustworthy material (not identified, no candidate fits, unreliable).
NO_MATERIAL_RGB = (200, 0, 0)
#: Map colours of the backdrop and of object pixels not used (too dark, clipped or at an edge).
MAP_BACKDROP_RGB = (235, 235, 235)
MAP_UNUSED_RGB = (95, 95, 95)


def palette_colour(i: int) -> tuple[int, int, int]:
    """The ``i``-th map colour (cycling).

    Examples
    --------
    >>> palette_colour(0), palette_colour(len(PALETTE))
    ((230, 159, 0), (230, 159, 0))
    """
    return PALETTE[i % len(PALETTE)]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png_of(fig: Any) -> bytes:
    """Render a matplotlib figure to PNG bytes and close it."""
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    return buf.getvalue()


def data_uri(png: bytes) -> str:
    """A ``data:image/png;base64,...`` URI of PNG bytes.

    Examples
    --------
    >>> data_uri(b"\\x89PNG")[:30]
    'data:image/png;base64,iVBORw=='
    """
    import base64

    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def calibration_residuals_figure(step_indices: Sequence[int], step_rms_mm: Sequence[float], rms_mm: float) -> bytes:
    """RMS distance of each used profile's points to the fitted sphere, against the profile's step."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 2.6), constrained_layout=True)
    ax.bar(np.asarray(step_indices), np.asarray(step_rms_mm) * 1000.0, width=0.8, color="#4a7ab5")
    ax.axhline(rms_mm * 1000.0, color="#c0392b", lw=1, ls="--", label=f"overall RMS {rms_mm * 1000:.1f} µm")
    ax.set_xlabel("profile step of the sphere scan")
    ax.set_ylabel("sphere residual RMS (µm)")
    ax.legend(loc="upper right", fontsize=8)
    return png_of(fig)


def frame_residuals_figure(names: Sequence[str], rms_px: Sequence[float], overall_px: float) -> bytes:
    """Reprojection RMS of each calibration frame (board corners), with the overall RMS."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.0, 2.6), constrained_layout=True)
    x = np.arange(len(names))
    ax.bar(x, np.asarray(rms_px, dtype=float), width=0.8, color="#4a7ab5")
    ax.axhline(overall_px, color="#c0392b", lw=1, ls="--", label=f"overall RMS {overall_px:.3f} px")
    step = max(1, len(names) // 12)
    ax.set_xticks(x[::step], [str(n).replace("/frame/", " f") for n in names][::step], rotation=60, fontsize=7)
    ax.set_ylabel("reprojection RMS (px)")
    ax.legend(loc="upper right", fontsize=8)
    return png_of(fig)


def overlay_sheet(tiles: Sequence[tuple[bytes, str]], width_px: int = 240, columns: int = 6) -> bytes:
    """A contact sheet: PNG images (overlays) scaled to ``width_px`` wide, ``columns`` per row, each captioned."""
    import io

    import cv2
    from PIL import Image

    from processing.common.png import png_bytes

    cells = []
    for blob, caption in tiles:
        img = np.asarray(Image.open(io.BytesIO(blob)).convert("RGB"))
        h = max(1, round(img.shape[0] * width_px / img.shape[1]))
        cell = np.full((h + 18, width_px, 3), 255, np.uint8)
        cell[:h] = cv2.resize(img, (width_px, h), interpolation=cv2.INTER_AREA)
        cv2.putText(cell, caption, (3, h + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (30, 30, 30), 1, cv2.LINE_AA)
        cells.append(cell)
    height = max(c.shape[0] for c in cells)
    cells = [np.vstack([c, np.full((height - c.shape[0], width_px, 3), 255, np.uint8)]) for c in cells]
    cells += [np.full_like(cells[0], 255)] * ((-len(cells)) % columns)
    rows = [np.hstack(cells[i:i + columns]) for i in range(0, len(cells), columns)]
    return png_bytes(np.vstack(rows))


def pose_graph_figure(passes: Sequence[dict[str, Any]], pairs: Sequence[dict[str, Any]]) -> bytes:
    """Passes as nodes on a circle; verified pairs solid green, rejected pairs dashed red, labelled with the RMS."""
    plt = _plt()
    n = len(passes)
    fig, ax = plt.subplots(figsize=(4.2, 3.6), constrained_layout=True)
    ang = np.pi / 2 - 2 * np.pi * np.arange(n) / max(n, 1)
    xy = np.stack([np.cos(ang), np.sin(ang)], axis=1) if n > 1 else np.zeros((1, 2))
    index = {int(p["pass"]): i for i, p in enumerate(passes)}
    usable = [int(p["pass"]) for p in passes if "registered" in p]   # the passes that reached registration
    for pr in pairs:
        # pair indices count the passes that had usable clouds, in order
        try:
            a, b = index[usable[int(pr["source"])]], index[usable[int(pr["target"])]]
        except (IndexError, KeyError):
            continue
        ok = bool(pr.get("verified"))
        ax.plot(*xy[[a, b]].T, color="#2e8b57" if ok else "#c0392b", ls="-" if ok else "--", lw=2 if ok else 1.2)
        mid = xy[[a, b]].mean(axis=0)
        rmse = pr.get("rmse_mm")
        if rmse is not None and math.isfinite(rmse):
            ax.annotate(f"{rmse:.3f} mm", mid, fontsize=8, ha="center", va="center",
                        bbox={"boxstyle": "round", "fc": "white", "ec": "none", "alpha": 0.8})
    for p, (x, y) in zip(passes, xy):
        reg = p.get("registered")
        colour = "#2e8b57" if reg else ("#999999" if reg is None else "#c0392b")
        ax.scatter([x], [y], s=700, color=colour, zorder=3)
        ax.annotate(f"{p['pass']}", (x, y), color="white", ha="center", va="center", fontsize=12,
                    fontweight="bold", zorder=4)
    ax.set_xlim(-1.6, 1.6)
    ax.set_ylim(-1.5, 1.5)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.set_title("passes (green: registered) and pairs\n(solid: verified, dashed: rejected; RMS residual)",
                 fontsize=9)
    return png_of(fig)


def coverage_figure(profiles: Sequence[dict[str, np.ndarray]]) -> bytes:
    """Each pass's profiles as a range image (table angle down, point along the laser line across)."""
    from app.demo.capture import profiles_figure

    buf = io.BytesIO()
    profiles_figure(list(profiles), buf)  # savefig accepts a file object
    return buf.getvalue()


def holes_figure(vertices: np.ndarray, holes: Sequence[dict[str, Any]], max_points: int = 20_000) -> bytes:
    """The mesh's vertices from above and from the side, with the holes' centroids (marker area ~ hole area)."""
    plt = _plt()
    v = np.asarray(vertices, dtype=float)
    if len(v) > max_points:
        v = v[np.random.default_rng(0).choice(len(v), max_points, replace=False)]
    fig, axes = plt.subplots(1, 2, figsize=(7.0, 3.2), constrained_layout=True)
    for ax, (i, j, title) in zip(axes, [(0, 1, "from above (x, y)"), (0, 2, "from the side (x, z)")]):
        ax.scatter(v[:, i], v[:, j], s=0.2, color="#888888", rasterized=True)
        for h in holes:
            c = h.get("centroid")
            if c is None:
                continue
            filled = bool(h.get("closed"))
            size = 30 + 4 * math.sqrt(max(float(h.get("area_mm2", 0.0)), 0.0))
            ax.scatter([c[i]], [c[j]], s=size, facecolor="none", edgecolor="#2e8b57" if filled else "#c0392b",
                       lw=2)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("mm")
    axes[0].set_ylabel("mm")
    fig.suptitle("holes: green = filled and closed, red = left open", fontsize=9)
    return png_of(fig)


def timing_figure(rows: Sequence[tuple[str, float]]) -> bytes:
    """Horizontal bars of seconds per step."""
    plt = _plt()
    labels = [r[0] for r in rows]
    secs = [r[1] for r in rows]
    fig, ax = plt.subplots(figsize=(6.0, 0.45 * len(rows) + 0.9), constrained_layout=True)
    y = np.arange(len(rows))
    ax.barh(y, secs, color="#4a7ab5")
    ax.set_yticks(y, labels, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("seconds")
    for yi, s in zip(y, secs):
        ax.annotate(f"{s:.2f} s", (s, yi), xytext=(3, 0), textcoords="offset points", va="center", fontsize=8)
    ax.set_xlim(0, max(secs + [1e-3]) * 1.25)
    return png_of(fig)


def chart_overlay_figure(preview: np.ndarray, chart: dict[str, Any]) -> bytes:
    """The chart frame's preview with the detected outline and each patch's centre and CIEDE2000 error.

    ``chart`` is a colour-step result (``products/colour/pNN-chart.json``): corners and centres are
    sensor pixels, ``preview_scale`` sensor pixels per preview pixel.
    """
    plt = _plt()
    scale = float(chart.get("preview_scale", 1))
    h, w = preview.shape[:2]
    fig, ax = plt.subplots(figsize=(6.4, 6.4 * h / w + 0.5), constrained_layout=True)
    ax.imshow(preview)
    corners = np.asarray(chart["corners"], dtype=float) / scale
    ring = np.vstack([corners, corners[:1]])
    ax.plot(ring[:, 0], ring[:, 1], color="#00e5ff", lw=1.5)
    de = chart.get("patch_errors", {}).get("delta_e00") or [float("nan")] * len(chart["patches"])
    for p, d in zip(chart["patches"], de):
        x, y = np.asarray(p["centre"], dtype=float) / scale
        ax.scatter([x], [y], s=18, color="#2ecc71" if p["usable"] else "#e74c3c", edgecolor="black", lw=0.5)
        ax.annotate(f"{d:.1f}", (x, y), xytext=(0, 5), textcoords="offset points", ha="center", fontsize=6,
                    color="white", bbox={"boxstyle": "round,pad=0.1", "fc": "black", "ec": "none", "alpha": 0.5})
    ax.set_axis_off()
    ax.set_title(f"{chart['chart']} found by {chart['method']} (confidence {chart['confidence']:.2f}); "
                 "dots: green usable, red excluded; labels: ΔE00", fontsize=8)
    return png_of(fig)


def patch_error_figure(names: Sequence[str], delta_e: Sequence[float], usable: Sequence[bool]) -> bytes:
    """CIEDE2000 of each patch after the chart's 3 x 3 colour fit (bars; excluded patches hatched)."""
    plt = _plt()
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(7.0, 2.8), constrained_layout=True)
    colours = ["#4a7ab5" if u else "#cccccc" for u in usable]
    ax.bar(x, delta_e, color=colours, hatch=None)
    ax.set_xticks(x, [str(n) for n in names], rotation=90, fontsize=6)
    ax.set_ylabel("ΔE00 after the colour fit")
    ax.set_title("patch errors (grey: excluded from the fit)", fontsize=9)
    return png_of(fig)


def material_spectra_figure(wavelengths: Sequence[float], entries: Sequence[dict[str, Any]], light_deg: float) -> bytes:
    """One plot per identified material: its estimated reflectance, the uncertainty band, the model's shape.

    ``entries`` hold ``material``, ``title``, ``reflectance``, ``uncertainty`` (lists over ``wavelengths``)
    and ``level`` (the verdict: an ``"unreliable"`` title is drawn in red).  The band is clipped to the
    physical range, 0 up to 1 (or to the estimate's own peak where a glossy highlight exceeds a white
    diffuser), and the vertical axis follows the curves, not the band, so a wide band cannot hide them.
    The model spectrum is scaled to the estimate's mean: a region's brightness follows gloss and angles,
    not the material, so the shapes are what is compared.
    """
    from app.demo.colour import model_spectrum
    from processing.materials.identification import NEUTRAL_METAL, NO_FIT

    plt = _plt()
    wl = np.asarray(wavelengths, dtype=np.float64)
    n = len(entries)
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.9 * cols, 3.1 * rows), squeeze=False, constrained_layout=True)
    cos_d = math.cos(math.radians(light_deg / 2))
    for ax, ent in zip(axes.ravel(), entries):
        est = np.asarray(ent["reflectance"], dtype=np.float64)
        unc = np.asarray(ent["uncertainty"], dtype=np.float64)
        top = max(1.0, float(est.max()))
        lo, hi = np.clip(est - unc, 0.0, top), np.clip(est + unc, 0.0, top)
        ax.fill_between(wl, lo, hi, color="#c6dbef", label="uncertainty (clipped to 0..1)")
        ax.plot(wl, est, color="#08306b", lw=2, label="measured")
        peak = float(est.max())
        if ent["material"] not in (NEUTRAL_METAL, NO_FIT):
            model = model_spectrum(ent["material"], wl, cos_d)
            model = model * float(est.mean()) / max(float(model.mean()), 1e-9)
            ax.plot(wl, model, color="#d62728", ls="--", lw=1.5, label=f"{ent['material']} (model shape)")
            peak = max(peak, float(model.max()))
        ax.set_ylim(0.0, max(peak * 1.35, 1e-3))
        ax.set_xlim(float(wl[0]), float(wl[-1]))
        ax.set_title(ent["title"], fontsize=9, color="#c0392b" if ent.get("level") == "unreliable" else "black")
        ax.set_xlabel("wavelength (nm)", fontsize=8)
        ax.set_ylabel("reflectance", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7, loc="upper left")
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    return png_of(fig)


def region_map_figure(image: np.ndarray, keys: Sequence[tuple[tuple[int, int, int], tuple[int, int, int], str]],
                      backdrop_rgb: tuple[int, int, int], title: str = "") -> bytes:
    """A material map recoloured with distinguishable colours, with one legend row per region.

    Parameters
    ----------
    image
        ``(H, W, 3)`` uint8 map as the materials step wrote it (one colour per answer, the backdrop
        ``backdrop_rgb``, unused pixels black).
    keys
        ``(colour in the map, colour to draw, legend text)`` per region.
    backdrop_rgb
        The backdrop's colour in ``image``.
    title
        Above the map.

    Returns
    -------
    bytes
        The PNG: backdrop light grey, object pixels not used dark grey, each region in its drawn colour.
    """
    plt = _plt()
    img = np.asarray(image, dtype=np.uint8)
    out = np.empty_like(img)
    out[:] = MAP_UNUSED_RGB
    out[np.all(img == np.asarray(backdrop_rgb, np.uint8), axis=-1)] = MAP_BACKDROP_RGB
    for src, dst, _ in keys:
        out[np.all(img == np.asarray(src, np.uint8), axis=-1)] = dst
    h, w = img.shape[:2]
    fig, ax = plt.subplots(figsize=(8.4, max(2.4, 3.6 * h / w)), constrained_layout=True)
    ax.imshow(out, interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=9)
    seen: dict[str, tuple[int, int, int]] = {}
    for _, dst, text in keys:
        seen.setdefault(text, dst)
    seen["object pixels not used (too dark or clipped)"] = MAP_UNUSED_RGB
    seen["backdrop"] = MAP_BACKDROP_RGB
    handles = [plt.Rectangle((0, 0), 1, 1, facecolor=np.asarray(c) / 255.0, edgecolor="#888888") for c in seen.values()]
    ax.legend(handles, list(seen), fontsize=8, loc="center left", bbox_to_anchor=(1.0, 0.5),
              title="region: material (verdict)", title_fontsize=8, frameon=False)
    return png_of(fig)


def probe_tone_map(rgb_linear: np.ndarray, key: float = 0.18) -> np.ndarray:
    """8-bit sRGB of an HDR map: the log-mean luminance at ``key``, then Reinhard's global operator.

    The colour of each pixel is kept (its linear RGB scaled by the ratio of compressed to original
    luminance), so bright lamps show their colour instead of clipping to white.

    Parameters
    ----------
    rgb_linear
        ``(H, W, 3)`` linear sRGB, any positive scale.
    key
        The grey the log-mean luminance is mapped to.

    Returns
    -------
    ndarray
        ``(H, W, 3)`` uint8 sRGB.

    References
    ----------
    .. [1] Reinhard, Stark, Shirley, Ferwerda, "Photographic tone reproduction for digital images",
       ACM Transactions on Graphics 21(3), 267-276 (2002), doi:10.1145/566654.566575.

    Examples
    --------
    >>> img = probe_tone_map(np.array([[[1.0, 1.0, 1.0], [100.0, 100.0, 100.0]]]))
    >>> img.dtype.name, bool(img[0, 1, 0] > img[0, 0, 0]), int(img.max()) <= 255
    ('uint8', True, True)
    """
    rgb = np.clip(np.nan_to_num(np.asarray(rgb_linear, dtype=np.float64)), 0.0, None)
    y = rgb @ np.array([0.2126, 0.7152, 0.0722])
    log_mean = float(np.exp(np.mean(np.log(y + 1e-6))))
    scaled = y * (key / max(log_mean, 1e-12))
    compressed = scaled / (1.0 + scaled)
    out = rgb * np.where(y > 0, compressed / np.maximum(y, 1e-12), 0.0)[..., None]
    out = np.clip(out, 0.0, 1.0)
    encoded = np.where(out <= 0.0031308, 12.92 * out, 1.055 * np.power(out, 1 / 2.4) - 0.055)
    return np.round(255 * encoded).astype(np.uint8)


def probe_map_figure(srgb8: np.ndarray, cap_angle_deg: np.ndarray | None = None,
                     cap_limits_deg: tuple[float, float] | None = None) -> bytes:
    """The equirectangular probe map over azimuth and elevation, with the unseen caps outlined.

    Parameters
    ----------
    srgb8
        ``(H, 2H, 3)`` the tone-mapped map (row 0 the zenith, column 0 azimuth 0, from +x toward +y).
    cap_angle_deg
        ``(H, 2H)`` each pixel's angle from the direction toward the camera (degrees), or None.
    cap_limits_deg
        The angles bounding the seen directions: the camera's cap and 180 minus the back cap.
    """
    plt = _plt()
    h, w = srgb8.shape[:2]
    fig, ax = plt.subplots(figsize=(7.0, 3.9), constrained_layout=True)
    extent = (0.0, 360.0, -90.0, 90.0)
    ax.imshow(srgb8, extent=extent, aspect="auto", interpolation="nearest")
    if cap_angle_deg is not None and cap_limits_deg is not None:
        az = (np.arange(w) + 0.5) * 360.0 / w
        el = 90.0 - (np.arange(h) + 0.5) * 180.0 / h
        ax.contour(az, el, cap_angle_deg, levels=sorted(cap_limits_deg), colors="white", linewidths=1.0,
                   linestyles="dashed")
    ax.set_xlabel("azimuth (degrees, from +x toward +y)")
    ax.set_ylabel("elevation (degrees)")
    ax.set_xticks(np.arange(0, 361, 90))
    ax.set_yticks(np.arange(-90, 91, 45))
    return png_of(fig)
