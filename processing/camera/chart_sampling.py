"""Sampling the linear RAW inside each chart patch, and the checks that reject an unusable chart.

:func:`sample_patches` gives per patch the trimmed mean, standard deviation,
clipped fraction, live-pixel count and a noise-corrected non-uniformity of the
linear camera RGB inside the central part of the patch; :func:`check_patches`
rejects clipped, non-uniform and mis-ordered (rotated or mirrored) chart
shots before colour calibration (cf. ISO 17321-1:2012, section 4.5).
Patches are named as printed on the chart, 1-based with their names
(``"patch 19 (white 9.5)"``); arrays are indexed from 0.
docs/colour-pipeline.md, "Sampling and checks", gives the statistics and the
thresholds.

References
----------
ISO 17321-1:2012, Graphic technology and photography -- Colour
characterisation of digital still cameras (DSCs) -- Part 1, section 4.5 (no DOI).

Tippett, L. H. C. (1925). On the extreme individuals and the range of samples
taken from a normal population. Biometrika 17(3-4), 364-387.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from processing.camera.chart_detection import ChartDetection
from processing.camera.chart_layout import chart_layout, chart_type_hint, reference_lab
from processing.camera.raw_decode import RawImage
from processing.errors import InputError

__all__ = [
    "ChartCheck",
    "ChartRejectedError",
    "ChartSamplingError",
    "PatchSamples",
    "check_patches",
    "sample_patches",
]


class ChartSamplingError(InputError):
    """The patches cannot be sampled (too small, off the image, bad settings)."""


class ChartRejectedError(InputError):
    """The chart shot is unusable (clipped, uneven or mis-ordered); the message names the patches."""


@dataclass
class PatchSamples:
    """Per-patch statistics of the linear camera RGB (units of saturation).

    Parameters
    ----------
    chart, mean, std, clipped, count, nonuniformity, exposure_time, iso, f_number
        The attributes below, in this order.

    Attributes
    ----------
    chart
        Chart type.
    mean
        ``(N, 3)`` trimmed mean R, G, B.
    std
        ``(N, 3)`` standard deviation over the patch's live pixels.
    clipped
        ``(N,)`` fraction of pixels saturated.
    count
        ``(N,)`` live (not dead) pixels sampled.
    nonuniformity
        ``(N,)`` largest noise-corrected ``(max - min) / mean`` of the four quadrant means.
    exposure_time, iso, f_number
        From the RAW file (seconds, ISO speed, f-number; 0 when unknown).
    """

    chart: str
    mean: NDArray[np.float64]
    std: NDArray[np.float64]
    clipped: NDArray[np.float64]
    count: NDArray[np.int64]
    nonuniformity: NDArray[np.float64]
    exposure_time: float = 0.0
    iso: float = 0.0
    f_number: float = 0.0


@dataclass
class ChartCheck:
    """Result of :func:`check_patches`.

    Parameters
    ----------
    usable, warnings
        The attributes below, in this order.

    Attributes
    ----------
    usable
        ``(N,)`` bool: the patch may be used for calibration.
    warnings
        One message per excluded patch.
    """

    usable: NDArray[np.bool_]
    warnings: list[str] = field(default_factory=list)


def _trim_mean(values: NDArray[np.float64], trim: float) -> NDArray[np.float64]:
    """Mean per column with the ``trim`` fraction cut from each end (scipy's ``trim_mean``).

    The same partition and slice as :func:`scipy.stats.trim_mean`, so the same values bit for bit,
    without importing :mod:`scipy.stats` (about a second of every colour step's start-up).
    """
    a = np.asarray(values, dtype=np.float64)
    n = a.shape[0]
    low = int(trim * n)
    high = n - low
    if low > high:
        raise ValueError("Proportion too big.")
    return np.partition(a, (low, high - 1), axis=0)[low:high].mean(axis=0)


def sample_patches(raw_image: RawImage, detection: ChartDetection, *, inset: float = 0.6,
                   trim: float = 0.1) -> PatchSamples:
    """Statistics of the linear RGB inside each patch.

    The pixels sampled are those whose centre lies in the central ``inset``
    of the patch side, in the patch's own model coordinates (so perspective
    is exact).  The non-uniformity is ``(max - min - 4.7 s / sqrt(n)) / mean``
    of the four quadrant means of the channel that varies most (``s`` the
    pixel standard deviation, ``n`` the independent samples of the smallest
    quadrant): the part of the range sensor noise explains is removed, so it
    measures glare and shadows rather than noise.

    Parameters
    ----------
    raw_image
        The decoded RAW (any mode; coordinates are mapped by its scale).
    detection
        Patch positions in sensor pixels.
    inset
        Fraction of the patch side sampled, centred (0 < inset <= 1).
    trim
        Fraction cut from each end per channel for the mean (0 <= trim < 0.5).

    Returns
    -------
    PatchSamples
        One row per patch in reading order, with the frame's exposure metadata.

    Raises
    ------
    ChartSamplingError
        Bad ``inset``/``trim``, a chart from another image size, or a patch
        with fewer than 4 live pixels inside the image.

    Examples
    --------
    >>> from pathlib import Path
    >>> from processing.camera.chart_detection import chart_from_corners
    >>> img = RawImage(np.full((60, 90, 3), 0.5, np.float32), np.zeros((60, 90), bool), np.zeros((60, 90), bool),
    ...                (0, 0, 0, 0), 1.0, "RGGB", 0.01, 100, 0, "", "", Path("x"), "demosaic", 1)
    >>> det = chart_from_corners([[2, 2], [85.75, 2], [85.75, 58.25], [2, 58.25]])
    >>> s = sample_patches(img, det)
    >>> s.mean[0].tolist(), float(s.clipped[0]), bool(s.count[0] > 50)
    ([0.5, 0.5, 0.5], 0.0, True)
    """
    _check_sampling(raw_image, detection, inset, trim)
    layout = detection.layout
    inv = np.linalg.inv(detection.homography)
    quads_img = raw_image.from_sensor(detection.quads)
    n = layout.size
    mean = np.zeros((n, 3))
    std = np.zeros((n, 3))
    clipped = np.zeros(n)
    count = np.zeros(n, np.int64)
    nonuni = np.zeros(n)
    rects = layout.quads()
    for k in range(n):
        (y0, y1, x0, x1), sel, s, t = _patch_pixels(raw_image, inv, rects[k], quads_img[k], inset)
        if sel.sum() < 4:
            raise ChartSamplingError(
                f"{layout.label(k)} covers only {int(sel.sum())} pixels inside the image; move the camera closer "
                "or use demosaic mode"
            )
        rgb = raw_image.rgb[y0:y1, x0:x1].reshape(-1, 3)[sel].astype(np.float64)
        sat = raw_image.saturated[y0:y1, x0:x1].reshape(-1)[sel]
        live = ~raw_image.dead[y0:y1, x0:x1].reshape(-1)[sel]
        clipped[k] = float(sat.mean())
        count[k] = int(live.sum())
        if count[k] < 4:
            raise ChartSamplingError(f"{layout.label(k)} has only {count[k]} live pixels (dead photosites)")
        vals = rgb[live]
        mean[k] = _trim_mean(vals, trim)
        std[k] = vals.std(axis=0, ddof=1)
        quadrant = ((s[sel] > 0).astype(int) * 2 + (t[sel] > 0))[live]
        nonuni[k] = _nonuniformity(vals, quadrant, mean[k], std[k], raw_image.mode)
    return PatchSamples(detection.chart, mean, std, clipped, count, nonuni, raw_image.exposure_time,
                        raw_image.iso, raw_image.f_number)


def _check_sampling(raw_image: RawImage, detection: ChartDetection, inset: float, trim: float) -> None:
    """Refuse settings out of range and a detection made on an image of another size."""
    if not (0 < inset <= 1):
        raise ChartSamplingError(f"inset must be in (0, 1] (fraction of the patch side sampled), got {inset!r}")
    if not (0 <= trim < 0.5):
        raise ChartSamplingError(f"trim must be in [0, 0.5) (fraction cut from each end), got {trim!r}")
    h, w = raw_image.shape
    sensor_size = (w * raw_image.scale, h * raw_image.scale)
    if detection.image_size is not None and any(abs(a - b) > raw_image.scale
                                                for a, b in zip(detection.image_size, sensor_size)):
        raise ChartSamplingError(
            f"the chart was located in a {detection.image_size[0]} x {detection.image_size[1]} image but "
            f"{raw_image.path} is {sensor_size[0]} x {sensor_size[1]} photosites; detect the chart on this image"
        )


def _patch_pixels(
    raw_image: RawImage, inv: NDArray[np.float64], rect: NDArray[np.float64], q: NDArray[np.float64], inset: float
) -> tuple[tuple[int, int, int, int], NDArray[np.bool_], NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """The window ``(y0, y1, x0, x1)`` around patch ``q``, its pixels inside the inset, their patch coordinates.

    The coordinates ``s``, ``t`` run from -0.5 to 0.5 across the patch (None for an empty window).
    """
    h, w = raw_image.shape
    (mx0, my0), (mx1, my1) = rect[0], rect[2]
    x0, y0 = np.floor(q.min(axis=0)).astype(int)
    x1, y1 = np.ceil(q.max(axis=0)).astype(int) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    sel = np.zeros((0,), bool)
    s = t = None
    if x1 > x0 and y1 > y0:
        ys, xs = np.mgrid[y0:y1, x0:x1]
        sx, sy = raw_image.to_sensor(np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.float64)).T
        # the inverse homography written out: (N, 3) @ (3, 3) matmuls are slow on large windows
        den = inv[2, 0] * sx + inv[2, 1] * sy + inv[2, 2]
        u = (inv[0, 0] * sx + inv[0, 1] * sy + inv[0, 2]) / den
        v = (inv[1, 0] * sx + inv[1, 1] * sy + inv[1, 2]) / den
        s = (u - mx0) / (mx1 - mx0) - 0.5
        t = (v - my0) / (my1 - my0) - 0.5
        sel = (np.abs(s) < inset / 2) & (np.abs(t) < inset / 2)
    return (y0, y1, x0, x1), sel, s, t


def _nonuniformity(vals: NDArray[np.float64], quadrant: NDArray[np.int64], mean: NDArray[np.float64],
                   std: NDArray[np.float64], mode: str) -> float:
    """Largest noise-corrected spread of the quadrant means relative to the mean (0 with fewer than 2 quadrants)."""
    groups = [vals[quadrant == i] for i in range(4) if np.count_nonzero(quadrant == i) >= 2]
    if len(groups) <= 1:
        return 0.0
    qmeans = np.array([g.mean(axis=0) for g in groups])
    # demosaiced pixels share photosites: a quadrant holds about a quarter as many independent
    # samples of a channel as it has pixels (R and B sites are a quarter of the mosaic)
    smallest = min(len(g) for g in groups) / (4.0 if mode == "demosaic" else 1.0)
    # the range of 4 normal means exceeds 4.7 standard errors with probability 0.5 % (the range's
    # distribution: Tippett, Biometrika 17, 1925; 4.70 in a simulation of 4e6 draws), so noise
    # alone rarely flags a patch
    noise = 4.7 * std / np.sqrt(max(smallest, 1.0))
    spread = np.maximum(qmeans.max(axis=0) - qmeans.min(axis=0) - noise, 0.0)
    return float(np.max(spread / np.where(mean > 0, mean, np.inf)))


def _hue(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Hue angle in degrees of opponent coordinates ``a``, ``b``."""
    return np.degrees(np.arctan2(b, a))


def _opponent(rgb: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Opponent axes ``R - G`` and ``(R + G) / 2 - B`` of ``(n, 3)`` colours."""
    return rgb[:, 0] - rgb[:, 1], 0.5 * (rgb[:, 0] + rgb[:, 1]) - rgb[:, 2]


def check_patches(
    samples: PatchSamples,
    reference: ArrayLike | None = None,
    *,
    max_clipped: float = 0.005,
    max_nonuniformity: float = 0.05,
    min_usable: float = 0.75,
    neutral_concordance: float = 0.9,
    hue_tolerance_deg: float = 45.0,
    hue_agreement: float = 0.7,
) -> ChartCheck:
    """Reject clipped, non-uniform and mis-ordered chart shots; say which patches are usable.

    A patch is unusable when clipped, non-uniform or without signal in a
    channel.  The chart is mis-ordered when its camera-independent orderings
    fail: the neutral patches must darken in the order of the reference's
    L*, and each strongly chromatic patch must have about the reference hue
    after balancing on the neutrals (opponent axes ``R - G`` and
    ``(R + G)/2 - B``, which keep the hue order of any RGB camera to within
    tens of degrees).  A chart rotated or mirrored against its corners fails
    both.

    Parameters
    ----------
    samples
        From :func:`sample_patches`.
    reference
        ``(N, 3)`` CIE L*a*b* of the chart's patches; None uses the chart
        type's reference (:func:`processing.camera.chart_layout.reference_lab`).
    max_clipped
        Largest clipped fraction of a usable patch.
    max_nonuniformity
        Largest quadrant spread of a usable patch (0.05 = 5 %).
    min_usable
        Smallest fraction of usable patches for the chart to be accepted.
    neutral_concordance
        Smallest fraction of neutral pairs (L* apart by >= 8) whose camera
        signals are in the reference's order.
    hue_tolerance_deg, hue_agreement
        A chromatic patch (C*ab >= 25) agrees when its balanced camera hue is
        within the tolerance of the reference hue; this fraction must agree.

    Returns
    -------
    ChartCheck
        Which patches are usable, and one warning per excluded patch.

    Raises
    ------
    ChartRejectedError
        Too few usable patches (the message names each bad patch and what to
        do), or the chart is mis-ordered (rotated or mirrored).

    Examples
    --------
    >>> from processing.camera.chart_layout import reference_srgb8
    >>> rgb = (reference_srgb8("classic24") / 255.0) ** 2.2 + 0.01     # a camera that sees sRGB
    >>> n = len(rgb)
    >>> shot = PatchSamples("classic24", rgb, np.zeros((n, 3)), np.zeros(n), np.full(n, 100), np.zeros(n))
    >>> bool(check_patches(shot).usable.all())
    True
    >>> upside_down = PatchSamples("classic24", rgb[::-1], shot.std, shot.clipped, shot.count, shot.nonuniformity)
    >>> try:
    ...     check_patches(upside_down)
    ... except ChartRejectedError as exc:
    ...     print("out of order" in str(exc))
    True
    """
    layout = chart_layout(samples.chart)
    ref = reference_lab(samples.chart) if reference is None else np.asarray(reference, dtype=np.float64)
    n = layout.size
    if ref.shape != (n, 3) or not np.all(np.isfinite(ref)):
        raise ChartRejectedError(f"reference must be ({n}, 3) finite L*a*b* for {samples.chart}, got {ref.shape}")
    mean = np.asarray(samples.mean, dtype=np.float64)
    if mean.shape != (n, 3) or not np.all(np.isfinite(mean)):
        raise ChartRejectedError(f"samples.mean must be ({n}, 3) finite values for {samples.chart}")
    usable = np.ones(n, bool)
    problems: list[str] = []
    faults: dict[str, list[tuple[str, float]]] = {kind: [] for kind in _ADVICE}
    for k in range(n):
        if samples.clipped[k] > max_clipped:
            kind, pct = "clipped", 100 * float(samples.clipped[k])
        elif samples.nonuniformity[k] > max_nonuniformity:
            kind, pct = "not uniform", 100 * float(samples.nonuniformity[k])
        elif np.any(mean[k] <= 0):
            kind, pct = "without signal", 0.0
        else:
            continue
        usable[k] = False
        faults[kind].append((layout.label(k), pct))
        problems.append(_one_patch(kind, layout.label(k), pct) + _ADVICE[kind])
    if usable.mean() < min_usable:
        raise ChartRejectedError(_rejection(samples.chart, int(usable.sum()), n, faults))
    _check_order(layout, ref, mean, usable, neutral_concordance, hue_tolerance_deg, hue_agreement)
    return ChartCheck(usable, problems)


#: What to do about each kind of unusable patch (the text after the patches' description).
_ADVICE = {
    "clipped": ": lower the exposure",
    "not uniform": "; light the chart evenly and tilt it away from specular reflection",
    "without signal": ": raise the exposure",
}

#: How a group of unusable patches is described.
_KIND_TEXT = {"clipped": "clipped", "not uniform": "not uniform (glare or a shadow)",
              "without signal": "with no signal in some channel"}

#: Patches named one by one (the worst first) in a rejection message; the rest are counted.
_NAMED = 3


def _one_patch(kind: str, label: str, pct: float) -> str:
    """What is wrong with one patch, e.g. ``"patch 19 (white 9.5) is 100% clipped"``."""
    if kind == "clipped":
        return f"{label} is {pct:.0f}% clipped"
    if kind == "not uniform":
        return f"{label} is not uniform ({pct:.0f}% difference across it: glare or a shadow)"
    return f"{label} has no signal in some channel"


def _rejection(chart: str, usable: int, n: int, faults: dict[str, list[tuple[str, float]]]) -> str:
    """One short line: why the chart is unusable, a few patches named per kind, and what to do.

    Examples
    --------
    >>> faults = {"clipped": [("patch 19 (white 9.5)", 100.0)], "without signal": [],
    ...           "not uniform": [(f"patch {k}", 40.0) for k in range(1, 11)]}
    >>> print(_rejection("sg140", 129, 140, faults))  # doctest: +NORMALIZE_WHITESPACE
    the sg140 chart is unusable (129 of 140 patches usable): patch 19 (white 9.5) is 100% clipped: lower the
    exposure; patch 1 40%, patch 2 40%, patch 3 40% and 7 more not uniform (glare or a shadow);
    light the chart evenly and tilt it away from specular reflection; if it is evenly lit, it may not be an
    sg140 chart (other types: classic24, vinyl18), or its corners are misplaced or in the wrong order
    """
    parts = []
    for kind, found in faults.items():
        if len(found) == 1:
            parts.append(_one_patch(kind, *found[0]) + _ADVICE[kind])
        elif found:
            worst = sorted(found, key=lambda f: -f[1])[:_NAMED]
            named = ", ".join(label if kind == "without signal" else f"{label} {pct:.0f}%" for label, pct in worst)
            more = f" and {len(found) - _NAMED} more" if len(found) > _NAMED else ""
            parts.append(f"{named}{more} {_KIND_TEXT[kind]}{_ADVICE[kind]}")
    hint = ""
    if len(faults["not uniform"]) > sum(map(len, faults.values())) / 2:
        hint = f"; if it is evenly lit, it may not be {chart_type_hint(chart)}, or its corners are misplaced or in the wrong order"
    return f"the {chart} chart is unusable ({usable} of {n} patches usable): " + "; ".join(parts) + hint


def _check_order(layout, ref: NDArray[np.float64], mean: NDArray[np.float64], usable: NDArray[np.bool_],
                 neutral_concordance: float, hue_tolerance_deg: float, hue_agreement: float) -> None:
    """Raise :class:`ChartRejectedError` when the neutrals or the chromatic hues are out of the reference order."""
    chroma = np.hypot(ref[:, 1], ref[:, 2])
    neutral = np.flatnonzero((chroma < 5) & usable & np.all(mean > 0, axis=1))
    hint = (f"the chart is rotated or mirrored against the corners given: list them starting at the chart's "
            f"top-left as printed (the corner next to {layout.label(0)}), clockwise; or it is not "
            f"{chart_type_hint(layout.name)}")
    if len(neutral) >= 2:
        lum = mean[neutral].sum(axis=1)
        li = ref[neutral, 0]
        i, j = np.triu_indices(len(neutral), 1)
        far = np.abs(li[i] - li[j]) >= 8
        if far.any():
            agree = np.sign(lum[i] - lum[j])[far] == np.sign(li[i] - li[j])[far]
            if agree.mean() < neutral_concordance:
                names = ", ".join(str(k + 1) for k in neutral)
                raise ChartRejectedError(
                    f"the {layout.name} chart's patches are out of order: the neutral patches ({names}) do not "
                    f"darken as they should ({100 * agree.mean():.0f}% of pairs in order); {hint}"
                )
    chromatic = np.flatnonzero((chroma >= 25) & usable & np.all(mean > 0, axis=1))
    if len(neutral) == 0 or len(chromatic) < 3:
        return
    white = mean[neutral].sum(axis=0)
    balanced = mean[chromatic] / (white / white[1])
    a, b = _opponent(balanced)
    import colour

    ref_rgb = np.asarray(colour.XYZ_to_sRGB(colour.Lab_to_XYZ(ref[chromatic]), apply_cctf_encoding=False))
    ra, rb = _opponent(ref_rgb)
    diff = np.abs((_hue(a, b) - _hue(ra, rb) + 180.0) % 360.0 - 180.0)
    ok = diff <= hue_tolerance_deg
    if ok.mean() < hue_agreement:
        worst = chromatic[np.argsort(-diff)[:3]]
        listed = ", ".join(f"{layout.label(k)} off by {diff[list(chromatic).index(k)]:.0f} deg" for k in worst)
        raise ChartRejectedError(
            f"the {layout.name} chart's patches are out of order: only {int(ok.sum())} of {len(chromatic)} "
            f"chromatic patches have their expected hue ({listed}); {hint}"
        )
