"""Validation against held-out photos: render each held-out frame and measure CIEDE2000 against the photo.

The material fit never sees the held-out frames (:func:`holdout_frames`:
every 4th table angle).  :func:`validate_frames` renders each of them with
its calibrated camera, its lamps and the chart-calibrated exposure
(:func:`render.photo_signal.render_signal`) twice -- with the measured
material of every face region, and with the paper's baseline of one
material for the whole object -- and compares both with the photo in CIELAB
through one camera-RGB -> XYZ matrix
(:func:`processing.appearance.photo_comparison.compare_images`): mean and
95th percentile CIEDE2000 over the object's pixels per frame and overall,
with false-colour error maps (0-10 dE) and photo | render | error triptychs
as PNG bytes; beside a perfect model's score against photos with the sensor's
noise (the noise floor), and, with ``pool_px``, the same comparisons at a
stated spatial scale (linear values averaged in blocks before the colour
conversion).  docs/validation.md describes the rule and the figures, and what
the error is made of on the demo's session.
"""

from __future__ import annotations

import io
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from app.errors import UsageError
from processing.appearance.photo_comparison import ImageComparison, camera_to_xyz_matrix, compare_images, noise_floor
from processing.common.png import png_bytes
from processing.errors import InputError
from render.photo_signal import SIGNAL_GRID, pixel_faces, render_signal

__all__ = ["holdout_frames", "validate_frames", "error_map_png", "triptych_png", "ERROR_RANGE_DE", "HOLDOUT_EVERY",
           "POOL_PX"]

#: Colour range of the error maps: 0 to 10 CIEDE2000.
ERROR_RANGE_DE = 10.0
#: Every this many-th table angle is held out of the fit.
HOLDOUT_EVERY = 4
#: The spatial scale of the pooled comparison (block side, pixels) ``kogei fit-materials`` reports beside the
#: per-pixel one: about the width of a highlight on the station's photos, so the colours are compared where
#: they are resolved and the photo's single-frame sensor noise falls about 4-fold.
POOL_PX = 4
_COLORMAP = "magma"


def holdout_frames(frame_names: Sequence[str], angles_deg: Sequence[float], every: int = HOLDOUT_EVERY) -> set[str]:
    """Names of the frames held out of the material fit: every ``every``-th distinct table angle.

    The distinct table angles (modulo 360, to 0.01 degree) are ranked in
    ascending order; the angles of rank ``every // 2``, ``every // 2 +
    every``, ... are held out (so each held-out angle has fitted angles on both
    sides), and with them every frame taken at such an angle (in any pass).

    Parameters
    ----------
    frame_names
        Frame names.
    angles_deg
        Table angle of each frame (degrees).
    every
        Hold out one angle in ``every`` (>= 2).

    Returns
    -------
    set of str

    Examples
    --------
    >>> sorted(holdout_frames([f"f{i}" for i in range(8)], [45 * i for i in range(8)]))
    ['f2', 'f6']
    """
    names = list(frame_names)
    angles = np.round(np.mod(np.asarray(angles_deg, dtype=np.float64), 360.0), 2)
    if len(names) != len(angles) or not np.all(np.isfinite(angles)):
        raise UsageError(f"holdout_frames: give one finite table angle per frame ({len(names)} frames, "
                         f"{len(angles)} angles)")
    if isinstance(every, bool) or int(every) != every or every < 2:
        raise UsageError(f"holdout_frames: every must be a whole number >= 2, got {every!r}")
    distinct = np.unique(angles)
    held = distinct[np.arange(len(distinct)) % int(every) == int(every) // 2]
    return {n for n, a in zip(names, angles, strict=True) if a in set(held.tolist())}


def _false_colour(error_map: NDArray[np.float32]) -> NDArray[np.uint8]:
    import matplotlib

    cmap = matplotlib.colormaps[_COLORMAP]
    x = np.clip(np.nan_to_num(error_map, nan=0.0) / ERROR_RANGE_DE, 0.0, 1.0)
    rgb = (cmap(x)[..., :3] * 255.0 + 0.5).astype(np.uint8)
    rgb[~np.isfinite(error_map)] = 40
    return rgb


def error_map_png(error_map: ArrayLike, title: str = "") -> bytes:
    """False-colour PNG of a CIEDE2000 map with a colour bar from 0 to :data:`ERROR_RANGE_DE`.

    Parameters
    ----------
    error_map
        ``(H, W)`` CIEDE2000, NaN where not compared (drawn dark grey).
    title
        Title above the map.

    Returns
    -------
    bytes
        PNG file.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    emap = np.asarray(error_map, dtype=np.float32)
    h, w = emap.shape
    fig = Figure(figsize=(max(3.0, w / 80 + 1.2), max(2.0, h / 80 + 0.6)), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    import matplotlib

    cmap = matplotlib.colormaps[_COLORMAP].with_extremes(bad=(40 / 255,) * 3)
    im = ax.imshow(np.ma.masked_invalid(emap), cmap=cmap, vmin=0.0, vmax=ERROR_RANGE_DE, interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)
    fig.colorbar(im, ax=ax, label="CIEDE2000")
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


def triptych_png(photo: ArrayLike, rendered: ArrayLike, error_map: ArrayLike, camera_to_xyz: ArrayLike) -> bytes:
    """Photo | rendering | false-colour error side by side (sRGB through ``camera_to_xyz``), as PNG bytes.

    Parameters
    ----------
    photo, rendered
        ``(H, W, 3)`` chart-normalised camera RGB.
    error_map
        ``(H, W)`` CIEDE2000 (NaN: not compared).
    camera_to_xyz
        ``(3, 3)`` camera RGB -> XYZ.

    Returns
    -------
    bytes
        PNG file, ``(H, 3 W + 8)``.
    """
    from processing.spectral.display import xyz_to_srgb8

    m = np.asarray(camera_to_xyz, dtype=np.float64)
    white = m @ np.ones(3)

    def srgb(img: ArrayLike) -> NDArray[np.uint8]:
        rgb = np.clip(np.nan_to_num(np.asarray(img, dtype=np.float64)), 0.0, None)
        return xyz_to_srgb8(rgb @ m.T / white[1], white / white[1])

    left, mid = srgb(photo), srgb(rendered)
    gap = np.full((left.shape[0], 4, 3), 255, np.uint8)
    return png_bytes(np.concatenate([left, gap, mid, gap, _false_colour(np.asarray(error_map, np.float32))], axis=1))


def _pooled(de: list[NDArray[np.float64]]) -> dict[str, float | int]:
    allde = np.concatenate(de) if de else np.zeros(0)
    if allde.size == 0:
        return {"mean_de2000": None, "p95_de2000": None, "median_de2000": None, "n_pixels": 0}
    return {"mean_de2000": float(allde.mean()), "p95_de2000": float(np.percentile(allde, 95)),
            "median_de2000": float(np.median(allde)), "n_pixels": int(allde.size)}


def _by_region(region: NDArray[np.int64], de_m: NDArray[np.float32], de_b: NDArray[np.float32]
               ) -> dict[str, dict[str, Any]]:
    """Per face region: the CIEDE2000 values of the measured and baseline renderings (lists, for pooling)."""
    ok = np.isfinite(de_m) & (region >= 0)
    return {str(r): {"measured": de_m[ok & (region == r)].astype(np.float64),
                     "baseline": de_b[ok & (region == r)].astype(np.float64)} for r in np.unique(region[ok]).tolist()}


def _region_figures(per_frame: list[dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    keys = sorted({k for regions in per_frame for k in regions}, key=int)
    return {k: {kind: _pooled([regions[k][kind] for regions in per_frame if k in regions])
                for kind in ("measured", "baseline")} for k in keys}


def _compare_frame(frame: Any, photo: NDArray[Any], mesh: tuple, specs: Sequence[str | None], baseline_spec: str,
                   spectra: dict[str, Any], matrix: NDArray[np.float64], options: dict[str, Any]
                   ) -> tuple[dict[str, Any], ImageComparison | None, ImageComparison | None]:
    vertices, triangles, normals, face_material = mesh
    kw = dict(sensitivities=spectra["sensitivities"], scale=options["scale"], grid=spectra["grid"],
              irradiance_ref_mm=options["irradiance_ref_mm"], spread_px=options["spread_px"])
    t0 = time.perf_counter()
    measured, mask = render_signal(vertices, triangles, normals, face_material, specs, frame, spectra["light"], **kw)
    base, _ = render_signal(vertices, triangles, normals, np.zeros(len(triangles), np.int64), [baseline_spec], frame,
                            spectra["light"], **kw)
    photo = np.asarray(photo)
    if photo.shape != measured.shape:
        raise UsageError(f"held-out photo {frame.name!r}: shape {photo.shape}, the frame's camera gives "
                         f"{measured.shape}; give the frame's chart-normalised image")
    usable = mask.copy()
    if options["clip_level"] is not None:
        usable &= ~np.any(photo >= np.asarray(options["clip_level"]), axis=-1)
    margin = options["edge_margin_px"]
    left = ndimage.binary_erosion(usable, iterations=margin) if margin else usable
    if not left.any():
        return {"name": frame.name, "skipped": "no measured, unclipped object pixel in this frame",
                "seconds": time.perf_counter() - t0}, None, None
    res_m = compare_images(photo, measured, usable, matrix, edge_margin_px=margin)
    res_b = compare_images(photo, base, usable, matrix, edge_margin_px=margin)
    floor_kw = dict(edge_margin_px=margin, cfa=options["cfa"], frames=options["frames_averaged"])
    floor = None if options["noise"] is None else noise_floor(measured, usable, matrix, options["noise"], **floor_kw)
    faces = pixel_faces(vertices, triangles, frame)
    region = np.where(faces >= 0, np.asarray(face_material)[np.maximum(faces, 0)], -1)
    entry = {"name": frame.name, "measured": res_m.to_dict(), "baseline": res_b.to_dict(),
             **({} if floor is None else {"noise_floor": floor.to_dict(), "_floor_map": _values(floor)}),
             "regions": _by_region(region, res_m.error_map, res_b.error_map),
             "clipped_pixels": int(np.sum(mask & ~usable)), "seconds": 0.0}
    pool = options["pool_px"]
    if pool > 1:
        pm = compare_images(photo, measured, usable, matrix, edge_margin_px=margin, pool_px=pool)
        pb = compare_images(photo, base, usable, matrix, edge_margin_px=margin, pool_px=pool)
        entry["pooled"] = {"block_px": pool, "measured": pm.to_dict(), "baseline": pb.to_dict(),
                           "_maps": (_blocks(pm, pool), _blocks(pb, pool))}
        if options["noise"] is not None:
            pf = noise_floor(measured, usable, matrix, options["noise"], pool_px=pool, **floor_kw)
            entry["pooled"]["noise_floor"] = pf.to_dict()
            entry["pooled"]["_floor_map"] = _blocks(pf, pool)
        if options["images"]:
            entry["pooled_error_map_png"] = error_map_png(pm.error_map, f"{frame.name}: measured materials, "
                                                                        f"{pool} x {pool} px blocks")
    if options["images"]:
        entry["error_map_png"] = error_map_png(res_m.error_map, f"{frame.name}: measured materials")
        entry["baseline_error_map_png"] = error_map_png(res_b.error_map, f"{frame.name}: one material")
        entry["triptych_png"] = triptych_png(photo, measured, res_m.error_map, matrix)
    entry["seconds"] = time.perf_counter() - t0
    return entry, res_m, res_b


def _values(res: ImageComparison) -> NDArray[np.float64]:
    """The compared pixels' CIEDE2000 values."""
    return res.error_map[np.isfinite(res.error_map)].astype(np.float64)


def _blocks(res: ImageComparison, block_px: int) -> NDArray[np.float64]:
    """One CIEDE2000 value per compared block (the map repeats it on the block's pixels)."""
    return res.error_map[::block_px, ::block_px][np.isfinite(res.error_map[::block_px, ::block_px])].astype(np.float64)


def validate_frames(frames: Sequence[Any], photos: Sequence[ArrayLike], vertices: ArrayLike, triangles: ArrayLike,
                    normals: ArrayLike | None, face_material: ArrayLike, specs: Sequence[str | None],
                    baseline_spec: str, light_spectrum: Any, sensitivities: Any, scale: float, *,
                    irradiance_ref_mm: float | None = None, grid: Any = SIGNAL_GRID, edge_margin_px: int = 2,
                    clip_level: float | ArrayLike | None = None, images: bool = True,
                    noise: ArrayLike | None = None, cfa: str | None = None, frames_averaged: int = 1,
                    pool_px: int = 1, spread_px: float = 0.0) -> dict[str, Any]:
    """Render held-out frames with the measured materials and with one baseline material; CIEDE2000 to the photos.

    Parameters
    ----------
    frames
        The held-out :class:`processing.appearance.frame_poses.FramePose` list.
    photos
        Their chart-normalised ``(H, W, 3)`` images, same order; read one at
        a time (a lazy sequence is fine).
    vertices, triangles, normals, face_material, specs
        The object's mesh with per-face materials (:func:`render.photo_signal.render_signal`).
    baseline_spec
        The one material of the baseline (e.g. ``"nami-shibuichi"``), on every face.
    light_spectrum, sensitivities, scale, irradiance_ref_mm, grid
        The lamp, the camera and the chart-calibrated exposure (as ``render_signal``).
    edge_margin_px
        Mask erosion before comparing; with a ``spread_px`` it is at least
        ``ceil(3 * spread_px)`` (the photo mixes the backdrop into its outline's outer pixels, the
        rendering does not draw the backdrop).
    clip_level
        Photo signal at which the sensor saturates (scalar or per channel);
        pixels at or above it are left out.  None: keep all.
    images
        Add the PNGs (error maps, triptych) per frame.
    noise
        ``(K, 2)`` per frame (or one ``(2,)``) the photos' noise model ``(a, b)`` (variance
        ``a + b * signal``): each frame and the pool then also get ``"noise_floor"``, the figures of
        the measured rendering against itself plus that noise
        (:func:`processing.appearance.photo_comparison.noise_floor`) -- what a perfect model scores.
    cfa
        The photos' Bayer pattern (e.g. ``"RGGB"``) when they were demosaicked bilinearly: the noise
        floor then draws its noise on the mosaic and demosaicks it as the photos were; None:
        independent noise per pixel (an upper bound for demosaicked photos).
    frames_averaged
        Each photo is the linear mean of this many frames with independent noise (a burst shot at
        the held-out angle): the noise floor's variance is divided by it.
    spread_px
        The camera's point spread (Gaussian standard deviation, pixels; :func:`fit_point_spread`): the
        renderings are blurred by it within the object as the photos were by the lens
        (:func:`render.photo_signal.render_signal`); 0: a pinhole.
    pool_px
        > 1: also compare at that spatial scale, both images' linear values averaged over
        ``pool_px x pool_px`` blocks wholly inside the compared pixels before the colour conversion
        (:func:`processing.appearance.photo_comparison.compare_images`); each frame and the pool
        then get ``"pooled"`` with ``block_px``, ``"measured"``, ``"baseline"`` and (with ``noise``)
        ``"noise_floor"``, and each frame its ``pooled_error_map_png``.  The per-pixel figures stay.

    Returns
    -------
    dict
        ``{"frames": [{"name", "measured": {mean_de2000, p95_de2000, median_de2000, n_pixels}, "baseline": {...},
        "regions": {"<index>": {"measured": {...}, "baseline": {...}}}, "clipped_pixels", "seconds",
        "error_map_png", "baseline_error_map_png", "triptych_png"}, ...], "overall": {"measured": {...},
        "baseline": {...}, "regions": {...}, "n_frames", "n_skipped"}, "baseline_spec", "camera_to_xyz"}``; a frame with
        no measured, unclipped object pixel has only ``"name"``, ``"skipped"`` (why) and ``"seconds"``; overall
        figures pool the pixels of all frames; "regions" splits them by the face region seen in each pixel.
    """
    from processing.camera.response import camera_sensitivities
    from processing.spectral.spectra import light_spectrum as named_light

    if len(frames) != len(photos):
        raise UsageError(f"validate_frames: {len(frames)} frames but {len(photos)} photos; give one photo per frame")
    try:
        light = named_light(light_spectrum, grid) if isinstance(light_spectrum, (str, int, float)) \
            else np.asarray(light_spectrum, dtype=np.float64)
        sens = camera_sensitivities(grid, *(() if sensitivities is None else (sensitivities,))) \
            if sensitivities is None or isinstance(sensitivities, str) else np.asarray(sensitivities, np.float64)
        matrix = camera_to_xyz_matrix(sens, light, grid)
        spectra = {"light": light, "sensitivities": sens, "grid": grid}
        if not (np.isfinite(spread_px) and 0 <= spread_px <= 10):
            raise UsageError(f"validate_frames spread_px: give the camera's point spread in [0, 10] px, got {spread_px!r}")
        margin = max(int(edge_margin_px), int(np.ceil(3 * spread_px)))
        options = {"scale": scale, "irradiance_ref_mm": irradiance_ref_mm, "edge_margin_px": margin,
                   "spread_px": float(spread_px),
                   "clip_level": clip_level, "images": images, "noise": None, "cfa": cfa,
                   "frames_averaged": frames_averaged, "pool_px": _whole(pool_px, "pool_px")}
        _whole(frames_averaged, "frames_averaged")
        ab = None if noise is None else np.broadcast_to(np.asarray(noise, dtype=np.float64), (len(frames), 2))
        mesh = (vertices, triangles, normals, face_material)
        out, de_m, de_b, regions = [], [], [], []
        floors, pooled = [], []
        for i, frame in enumerate(frames):
            options["noise"] = None if ab is None else ab[i]
            entry, res_m, res_b = _compare_frame(frame, photos[i], mesh, specs, baseline_spec, spectra, matrix, options)
            if res_m is None:
                out.append(entry)
                continue
            regions.append(entry["regions"])
            entry["regions"] = _region_figures([entry["regions"]])
            out.append(entry)
            de_m.append(_values(res_m))
            de_b.append(_values(res_b))
            if "noise_floor" in entry:
                floors.append(entry.pop("_floor_map"))
            if "pooled" in entry:
                pooled.append(entry["pooled"])
                entry["pooled"] = {k: x for k, x in entry["pooled"].items() if not k.startswith("_")}
    except InputError as exc:
        raise UsageError(f"held-out validation: {exc}") from None
    overall = {"measured": _pooled(de_m), "baseline": _pooled(de_b), "n_frames": len(de_m),
               **({"noise_floor": _pooled(floors)} if floors else {}), "n_skipped": len(out) - len(de_m),
               "regions": _region_figures(regions)}
    if options["pool_px"] > 1:
        overall["pooled"] = {"block_px": options["pool_px"],
                             "measured": _pooled([p["_maps"][0] for p in pooled]),
                             "baseline": _pooled([p["_maps"][1] for p in pooled]),
                             **({"noise_floor": _pooled([p["_floor_map"] for p in pooled])} if floors else {})}
    return {"frames": out, "overall": overall, "frames_averaged": frames_averaged, "noise_cfa": cfa,
            "spread_px": float(spread_px), "edge_margin_px": margin,
            "baseline_spec": baseline_spec, "camera_to_xyz": matrix.tolist()}


def _whole(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise UsageError(f"validate_frames: {name} must be a whole number >= 1, got {value!r}")
    return int(value)
