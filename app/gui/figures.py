"""The window's figures as plain functions of plain data, drawn with Matplotlib's Agg canvas.

Every builder here is a module-level function ``build(fig, **data)`` of
NumPy arrays, numbers and strings, so that a figure can be drawn in another
process (:class:`app.gui.plots.FigureDrawer`): the function travels by its
name and the data by pickling.  Nothing here imports Qt.  A figure is drawn
on a fresh :class:`matplotlib.figure.Figure` with its own
:class:`~matplotlib.backends.backend_agg.FigureCanvasAgg` (never pyplot, so
no state is shared; Matplotlib's "Embedding in a web application server"
example draws the same way).

Examples
--------
>>> rgba = draw_figure(empty_figure, {"title": "Live profile", "hint": "starts with the capture"}, 320, 240)
>>> rgba.shape, rgba.dtype.name
((240, 320, 4), 'uint8')
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["style", "draw_figure", "render_figure", "axes_pixel", "empty_figure", "pick_figure", "profile_figure", "cloud_figure", "frame_figure",
           "histogram_figure", "spectrum_figure", "region_fit_figure", "display_image", "QUALITY_COLOURS", "HISTOGRAM_BINS"]

#: Colour of each patch quality in the camera preview (see :mod:`app.gui.camera_panel`).
QUALITY_COLOURS = {"ok": "#2e9e44", "noisy": "#e0a800", "dark": "#2f6fd0", "clipped": "#d0312d"}
#: Bin edges of the camera histogram (fraction of full scale).
HISTOGRAM_BINS = np.linspace(0.0, 1.0, 129)


def style(ax: Any, title: str = "", xlabel: str = "", ylabel: str = "") -> None:
    """Title and labels at sizes that stay readable in a small panel."""
    if title:
        ax.set_title(title, fontsize=10)
    if xlabel:
        ax.set_xlabel(xlabel, fontsize=9)
    if ylabel:
        ax.set_ylabel(ylabel, fontsize=9)
    ax.tick_params(labelsize=8)


def render_figure(build: Callable[..., Any], data: dict[str, Any], width_px: int, height_px: int,
                  dpi: int = 100) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """``build(fig, **data)`` drawn with Agg: ``(H, W, 4)`` uint8 RGBA and where each 2-D axes landed.

    Each axes is described as ``{"gid", "bbox", "xlim", "ylim"}``: its
    :meth:`~matplotlib.artist.Artist.get_gid`, its box ``(x0, y0, x1, y1)``
    in image pixels (y down, as the bitmap is shown), and its data limits
    after drawing (an equal aspect adjusts them at draw time) -- what a
    window needs to turn a click on the bitmap into data coordinates
    (:func:`axes_pixel`).  3-D axes are left out.
    """
    fig = Figure(figsize=(max(width_px, 50) / dpi, max(height_px, 50) / dpi), dpi=dpi, layout="constrained")
    canvas = FigureCanvasAgg(fig)
    build(fig, **data)
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba()).copy()
    h = rgba.shape[0]
    axes = []
    for ax in fig.axes:
        if ax.name != "rectilinear":
            continue
        box = ax.get_window_extent()
        axes.append({"gid": ax.get_gid(),
                     "bbox": (float(box.x0), float(h - box.y1), float(box.x1), float(h - box.y0)),
                     "xlim": tuple(map(float, ax.get_xlim())), "ylim": tuple(map(float, ax.get_ylim()))})
    return rgba, axes


def draw_figure(build: Callable[..., Any], data: dict[str, Any], width_px: int, height_px: int,
                dpi: int = 100) -> np.ndarray:
    """``build(fig, **data)`` on a new figure of the given size (px), drawn with Agg; ``(H, W, 4)`` uint8 RGBA."""
    return render_figure(build, data, width_px, height_px, dpi)[0]


def axes_pixel(axes: dict[str, Any], x: float, y: float, inverse: bool = False) -> tuple[float, float]:
    """Data ``(x, y)`` of an axes of :func:`render_figure` to image pixels, or pixels to data (``inverse``).

    Linear scales only.

    >>> ax = {"bbox": (10.0, 20.0, 110.0, 220.0), "xlim": (0.0, 50.0), "ylim": (-1.0, 1.0)}
    >>> axes_pixel(ax, 25.0, 1.0)
    (60.0, 20.0)
    >>> axes_pixel(ax, 60.0, 20.0, inverse=True)
    (25.0, 1.0)
    """
    x0, y0, x1, y1 = axes["bbox"]
    (a0, a1), (b0, b1) = axes["xlim"], axes["ylim"]
    if inverse:
        return a0 + (x - x0) / (x1 - x0) * (a1 - a0), b1 - (y - y0) / (y1 - y0) * (b1 - b0)
    return x0 + (x - a0) / (a1 - a0) * (x1 - x0), y0 + (b1 - y) / (b1 - b0) * (y1 - y0)


def display_image(image: np.ndarray, max_side: int = 1024) -> np.ndarray:
    """``image`` subsampled by a whole step so that its longer side is at most ``max_side`` px.

    A panel is never wider than the screen, and Matplotlib resamples every
    pixel it is given, so a 24-megapixel preview is cut down before it is
    sent to be drawn.

    >>> display_image(np.zeros((3000, 2000, 3), np.uint8)).shape
    (1000, 667, 3)
    """
    step = max(1, int(np.ceil(max(image.shape[:2]) / max_side)))
    return np.ascontiguousarray(image[::step, ::step])


def empty_figure(fig: Figure, title: str, hint: str, xlabel: str = "", ylabel: str = "") -> None:
    """An empty plot with its title and a grey hint of what will appear."""
    ax = fig.add_subplot(111)
    style(ax, title, xlabel, ylabel)
    ax.text(0.5, 0.5, hint, ha="center", va="center", transform=ax.transAxes, color="#777")
    if not (xlabel or ylabel):
        ax.set_xticks([])
        ax.set_yticks([])


def profile_figure(fig: Figure, p: int, idx: int, angle: float, x: np.ndarray, z: np.ndarray) -> None:
    """One laser profile: range against position along the line (mm), range growing down the plot."""
    ax = fig.add_subplot(111)
    ok = np.isfinite(x) & np.isfinite(z)
    ax.plot(x[ok], z[ok], ".", ms=3, color="#1f5fa8")
    style(ax, f"Live profile: pass {p}, step {idx} at {angle:.1f}° ({int(ok.sum())} of {x.size} points)",
          "x along the laser line (mm)", "range z (mm)")
    ax.invert_yaxis()                  # the range grows away from the sensor: down the plot
    ax.grid(alpha=0.3)


def cloud_figure(fig: Figure, p: int, angles: np.ndarray, x: np.ndarray, z: np.ndarray, cal: Any) -> None:
    """The pass so far: 3-D points through the calibration ``cal``, or the range image without one.

    ``x`` and ``z`` are ``(profiles, points)`` (mm, NaN where no return),
    ``angles`` the table angle of each profile (degrees).
    """
    finite = np.isfinite(z)
    if cal is not None and finite.any():
        from processing.geometry.scan_points import profiles_to_points

        lo, hi = float(np.nanmin(z)), float(np.nanmax(z))
        pad = 0.02 * max(hi - lo, 1.0)
        sp = profiles_to_points(x, z, angles, cal, range_mm=(max(lo - pad, 0.0), hi + pad))
        pts = sp.points
        if len(pts) > 3000:
            pts = pts[np.linspace(0, len(pts) - 1, 3000).astype(int)]
        ax = fig.add_subplot(111, projection="3d")
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=1, c=pts[:, 2], cmap="viridis")
        ax.set_title(f"Point cloud, pass {p}: {len(sp.points)} points after {len(angles)} profiles", fontsize=10)
        ax.set_xlabel("x (mm)", fontsize=8)
        ax.set_ylabel("y (mm)", fontsize=8)
        ax.set_zlabel("z (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.set_box_aspect(None, zoom=0.75)     # the axis labels inside the figure (the layout leaves 3-D axes be)
        if len(pts):
            span = np.ptp(pts, axis=0).max() / 2 or 1.0
            mid = (pts.max(axis=0) + pts.min(axis=0)) / 2
            ax.set_xlim(mid[0] - span, mid[0] + span)
            ax.set_ylim(mid[1] - span, mid[1] + span)
            ax.set_zlim(mid[2] - span, mid[2] + span)
        return
    import matplotlib

    ax = fig.add_subplot(111)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="black")
    top = float(angles[-1]) if len(angles) > 1 else 1.0
    im = ax.imshow(np.ma.masked_invalid(z), aspect="auto", cmap=cmap, interpolation="nearest",
                   extent=(0, z.shape[1], top, float(angles[0])))
    fig.colorbar(im, ax=ax, label="range (mm)")
    style(ax, f"Pass {p} as a range image: {100 * finite.mean():.0f}% returns, black none\n"
              "(choose a calibration on the Processing tab for 3-D points)",
          "point along the laser line", "table angle (°)")


def frame_figure(fig: Figure, image: np.ndarray, size: tuple[int, int], title: str,
                 outline: np.ndarray | None = None, quads: np.ndarray | None = None,
                 qualities: list[str] | None = None, mesh_outlines: list[np.ndarray] | None = None,
                 marks: np.ndarray | None = None) -> None:
    """A camera frame with the chart's outline and each patch coloured by its quality.

    The image axes' gid is ``"frame"`` (a click on it maps to preview pixels);
    ``marks`` (K, 2) are corners clicked so far, numbered in order.

    ``image`` may be a subsampled copy (:func:`display_image`) of a preview
    of ``size`` = (width, height) px; ``outline`` (4, 2), ``quads``
    (N, 4, 2) and ``mesh_outlines`` (the scanned mesh's outline projected
    with the calibrated camera, polylines (M, 2)) are in that preview's pixels.
    """
    ax = fig.add_subplot(111)
    ax.set_gid("frame")
    w, h = size
    ax.imshow(image, interpolation="nearest", extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    for k, line in enumerate(mesh_outlines or []):
        closed = np.vstack([line, line[:1]])
        ax.plot(closed[:, 0], closed[:, 1], "-", color="#00e5ff", lw=1.0,
                label="mesh outline (calibrated camera)" if k == 0 else None)
    if mesh_outlines:
        ax.legend(loc="lower right", fontsize=7, framealpha=0.7)
    if outline is not None:
        closed = np.vstack([outline, outline[:1]])
        ax.plot(closed[:, 0], closed[:, 1], "-", color="#ffdd00", lw=1.5)
    for n, (q, quality) in enumerate(zip(quads if quads is not None else [], qualities or []), start=1):
        qq = np.vstack([q, q[:1]])
        colour = QUALITY_COLOURS.get(quality, "#ffffff")
        ax.plot(qq[:, 0], qq[:, 1], "-", color=colour, lw=1.2)
        if len(quads) <= 30:
            c = q.mean(axis=0)
            ax.text(c[0], c[1], str(n), color="white", fontsize=7, ha="center", va="center",
                    bbox={"facecolor": colour, "alpha": 0.7, "pad": 1, "lw": 0})
    if marks is not None and len(marks):
        m = np.asarray(marks, dtype=float)
        ax.plot(m[:, 0], m[:, 1], "+-", color="#ff00ff", ms=12, mew=2, lw=1)
        for k, (x, y) in enumerate(m, start=1):
            ax.annotate(str(k), (x, y), xytext=(4, 4), textcoords="offset points", color="#ff00ff",
                        fontsize=9, fontweight="bold")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    style(ax, title)
    ax.set_xticks([])
    ax.set_yticks([])


def histogram_figure(fig: Figure, counts: np.ndarray, clipped: float) -> None:
    """Per-channel histograms ``counts`` (3, 128) over :data:`HISTOGRAM_BINS`, log scale, full scale marked."""
    ax = fig.add_subplot(111)
    for c, colour in enumerate(("#d0312d", "#2e9e44", "#2f6fd0")):
        ax.stairs(np.maximum(counts[c], 0.8), HISTOGRAM_BINS, color=colour, label="RGB"[c])
    ax.set_yscale("log")
    ax.axvline(1.0, color="k", ls="--", lw=1)
    style(ax, f"Linear signal ({100 * clipped:.2f}% clipped)", "fraction of full scale", "pixels")
    ax.legend(fontsize=8, loc="upper right")


def spectrum_figure(fig: Figure, wavelengths: np.ndarray, mean: np.ndarray, uncertainty: np.ndarray,
                    model: np.ndarray, model_name: str, pixels: int, title: str) -> None:
    """Estimated reflectance with its 1-sd band against the identified material's (scaled) model spectrum."""
    ax = fig.add_subplot(111)
    wl, m, u = wavelengths, mean, uncertainty
    ax.fill_between(wl, m - u, m + u, color="#1f5fa8", alpha=0.2, label="uncertainty (1 sd)")
    ax.plot(wl, m, color="#1f5fa8", lw=2, label=f"estimated ({pixels} px)")
    ax.plot(wl, model, color="#d0312d", lw=1.5, ls="--", label=f"{model_name} model (scaled)")
    style(ax, title, "wavelength (nm)", "reflectance factor")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")


def region_fit_figure(fig: Figure, half_angle_deg: np.ndarray, observed: np.ndarray, predicted: np.ndarray | None,
                      title: str) -> None:
    """A region's observations (R, G, B signal) against the half-vector angle, with the fitted model's values."""
    ax = fig.add_subplot(111)
    order = np.argsort(half_angle_deg)
    for c, colour in enumerate(("#c0392b", "#2e9e44", "#1f5fa8")):
        ax.scatter(half_angle_deg, observed[:, c], s=4, color=colour, alpha=0.35, lw=0,
                   label="observed R, G, B" if c == 1 else None)
        if predicted is not None:
            ax.plot(half_angle_deg[order], predicted[order, c], ".", ms=1.5, color=colour, alpha=0.9,
                    label="fitted model" if c == 1 else None)
    style(ax, title, "angle between the normal and the half vector (deg)", "signal (white diffuser = 1)")
    ax.set_yscale("symlog", linthresh=1e-3)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper right")


def pick_figure(fig: Figure, a: np.ndarray, b: np.ndarray, picks_a: np.ndarray, picks_b: np.ndarray, i: int, j: int,
                label_a: str, label_b: str) -> None:
    """Two passes' points (mm) side by side in the projection on coordinates ``i``, ``j``, picks numbered.

    The axes are tagged ``"a"`` and ``"b"`` (their gid) so that a click on
    the drawing can be mapped back to a pass and its data coordinates.
    """
    names = "xyz"
    for k, (side, pts, picks, label) in enumerate((("a", a, picks_a, label_a), ("b", b, picks_b, label_b))):
        ax = fig.add_subplot(1, 2, k + 1)
        ax.set_gid(side)
        if len(pts):
            ax.scatter(pts[:, i], pts[:, j], s=2, c=pts[:, 3 - i - j], cmap="viridis")
            for n, p in enumerate(picks, start=1):
                ax.plot(p[i], p[j], "o", mfc="none", mec="#d0312d", ms=10, mew=2)
                ax.annotate(str(n), (p[i], p[j]), xytext=(6, 6), textcoords="offset points", color="#d0312d",
                            fontsize=11, fontweight="bold")
            ax.set_aspect("equal", adjustable="datalim")
        style(ax, f"{label}: {len(picks)} picks", f"{names[i]} (mm)", f"{names[j]} (mm)")
