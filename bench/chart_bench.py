"""Cost of the colour-pipeline front end on a 24-megapixel RAW: decoding and chart detection.

A 6000 x 4000 RGGB DNG (14 bit) of a ColorChecker Classic lying tilted and turned on the grey
backdrop is simulated once: the layout of :mod:`processing.camera.chart_layout` is drawn in model units,
warped into the image by the card's homography (:mod:`mocks.chart_scene` placement, nearest
neighbour), and each photosite gets its patch's camera signal through the Nikon D5100
sensitivities and the noisy sensor of :mod:`mocks.camera_sim` (the full spectral image would
need 3 GB).  Then, each in a fresh process so the peak memory is that case's alone:

* ``decode-bin2x2`` / ``decode-demosaic``: :func:`processing.camera.raw_decode.decode_raw`, median of 3;
* ``detect``: :func:`processing.camera.chart_detection.detect_chart` on the full-size sRGB preview of
  the binned image (3000 x 2000) and of the demosaiced one (6000 x 4000), median of 3 each, the
  preview's own cost reported apart; the patch centres are scored against the centroids of the
  simulation's labelled photosites.

Run ``python -m bench.chart_bench`` (all cases; one JSON line) or ``--case NAME --dng PATH``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import machine_description, peak_rss_mb, run_case_subprocess

__all__ = ["make_dng", "section", "main"]

WIDTH, HEIGHT = 6000, 4000
PLACEMENT = {"center": (0.45, 0.55), "size": 0.35, "rotation_deg": 12.0, "tilt_deg": (15.0, -10.0)}


def make_dng(path: Path) -> dict:
    """Write the 24-megapixel chart DNG; return the true outer corners and patch centres (sensor pixels)."""
    import cv2

    from mocks.camera_sim import (
        RawFrame,
        SensorModel,
        channel_signal,
        expose,
        white_balance_neutral,
        write_raw,
        xyz_to_camera_matrix,
    )
    from mocks.chart_scene import (
        FRAME_REFLECTANCE,
        ChartPlacement,
        chart_corners,
        chart_homography,
        chart_patch_reflectances,
    )
    from mocks.world import BACKDROP_REFLECTANCE
    from processing.camera.chart_layout import chart_layout
    from processing.spectral.display import xyz_scale
    from processing.spectral.spectra import SpectralGrid, light_spectrum

    layout = chart_layout("classic24")
    grid = SpectralGrid(400, 700, 10)
    e = light_spectrum("D65", grid)
    e = e * xyz_scale(e, grid)
    corners = chart_corners(layout, WIDTH, HEIGHT, ChartPlacement(**PLACEMENT))
    # labels in model space (40 px per unit, pixel centres at (i + 0.5) / 40 units), then warped
    ppu = 40.0
    mw, mh = int(layout.width * ppu), int(layout.height * ppu)
    u = (np.arange(mw) + 0.5) / ppu
    v = (np.arange(mh) + 0.5) / ppu
    col = np.full(mw, -1)
    row = np.full(mh, -1)
    for c, (a, b) in enumerate(layout.col_edges):
        col[(u >= a) & (u < b)] = c
    for r, (a, b) in enumerate(layout.row_edges):
        row[(v >= a) & (v < b)] = r
    model = np.where((row[:, None] >= 0) & (col[None, :] >= 0), row[:, None] * layout.cols + col[None, :],
                     layout.size).astype(np.uint8)
    to_model_px = np.array([[ppu, 0, -0.5], [0, ppu, -0.5], [0, 0, 1]])
    h = chart_homography(layout, corners) @ np.linalg.inv(to_model_px)
    labels = cv2.warpPerspective(model, h, (WIDTH, HEIGHT), flags=cv2.INTER_NEAREST,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=layout.size + 1)
    # ground truth of the patch centres: centroids of the labelled photosites (as in the tests)
    flat = labels.ravel()
    n = np.bincount(flat, minlength=layout.size + 2)[:layout.size]
    xs = np.bincount(flat, weights=np.tile(np.arange(WIDTH, dtype=np.float64), HEIGHT),
                     minlength=layout.size + 2)[:layout.size]
    ys = np.bincount(flat, weights=np.repeat(np.arange(HEIGHT, dtype=np.float64), WIDTH),
                     minlength=layout.size + 2)[:layout.size]
    centres = np.column_stack([xs / n, ys / n])
    refl = np.vstack([chart_patch_reflectances("classic24", grid), np.full((1, grid.size), FRAME_REFLECTANCE),
                      np.full((1, grid.size), BACKDROP_REFLECTANCE)])
    table = channel_signal(refl * e / math.pi, grid)                   # (26, 3) camera signal
    cfa = np.empty((HEIGHT, WIDTH), np.uint8)
    cfa[0::2, 0::2], cfa[0::2, 1::2], cfa[1::2, 0::2], cfa[1::2, 1::2] = 0, 1, 1, 2
    signal = table[labels, cfa]
    del labels, cfa
    sensor = SensorModel()
    bayer, _ = expose(signal, sensor, 0.01, np.random.default_rng(5))
    del signal
    frame = RawFrame(bayer, sensor.black_level, sensor.white_level, "RGGB", 0.01, sensor.iso,
                     np.array(xyz_to_camera_matrix(grid)), white_balance_neutral(e, grid), np.zeros((2, 2)))
    write_raw(path, frame)
    return {"corners": corners.tolist(), "centres": centres.tolist()}


def _median(fn, repeats: int = 3) -> tuple[float, list[float], object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times, out


def case_decode(dng: Path, mode: str) -> dict:
    from processing.camera.raw_decode import decode_raw

    med, times, img = _median(lambda: decode_raw(dng, mode=mode))
    return {"case": f"decode-{mode}", "median_s": med, "times_s": times, "shape": list(img.rgb.shape),
            "peak_rss_mb": peak_rss_mb()}


def case_detect(dng: Path, centres: list) -> dict:
    from processing.camera.chart_detection import detect_chart
    from processing.camera.raw_decode import decode_raw, preview_srgb8

    truth = np.asarray(centres)
    out = {"case": "detect"}
    for mode in ("bin2x2", "demosaic"):
        img = decode_raw(dng, mode=mode)
        prev_med, _, prev = _median(lambda img=img: preview_srgb8(img))
        det_med, det_times, det = _median(lambda img=img, prev=prev: detect_chart(prev, "classic24", scale=img.scale))
        err = np.linalg.norm(det.centres - truth, axis=1)
        out[mode] = {"preview_size": [prev.shape[1], prev.shape[0]], "preview_s": prev_med, "detect_s": det_med,
                     "detect_times_s": det_times, "confidence": det.confidence,
                     "centre_error_max_px": float(err.max()), "centre_error_mean_px": float(err.mean())}
        del img, prev
    out["peak_rss_mb"] = peak_rss_mb()
    return out


def run_all() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        dng = Path(tmp) / "chart24mp.dng"
        t0 = time.perf_counter()
        truth = make_dng(dng)
        made = time.perf_counter() - t0
        centres = json.dumps(truth["centres"])
        load_before = os.getloadavg()[0]
        results = {
            "machine": machine_description(),
            "size": [WIDTH, HEIGHT],
            "file_mb": dng.stat().st_size / 2**20,
            "simulate_s": made,
            "decode-bin2x2": run_case_subprocess("bench.chart_bench", "decode-bin2x2", "--dng", str(dng)),
            "decode-demosaic": run_case_subprocess("bench.chart_bench", "decode-demosaic", "--dng", str(dng)),
            "detect": run_case_subprocess("bench.chart_bench", "detect", "--dng", str(dng), "--centres", centres),
        }
        results["load_average"] = [load_before, os.getloadavg()[0]]
    return results


def section(results: dict | None = None) -> list[str]:
    """The Markdown section of docs/BENCHMARKS.md (runs the benchmark when no results are given)."""
    r = results or run_all()
    b, d, det = r["decode-bin2x2"], r["decode-demosaic"], r["detect"]
    lines = [
        "## RAW decoding and chart detection",
        "",
        f"A simulated {r['size'][0]} x {r['size'][1]} (24 MP) RGGB 14-bit DNG ({r['file_mb']:.0f} MB) of a",
        "ColorChecker Classic tilted and turned on the backdrop (`bench/chart_bench.py`).  Each case runs in a",
        "fresh process; medians of 3 runs.  Decoding includes LibRaw's read and unpack.  Detection is",
        "`detect_chart` on the full-size sRGB preview (`cv2.mcc` on the preview shrunk to 1600 px, then the",
        "patch-centroid refinement at full size); the preview's own cost is listed apart.  Centre errors are",
        "against the centroids of the simulation's labelled photosites, in sensor pixels.  Target: detection <= 1 s.",
        "",
        f"Machine: {r['machine']}."
        + (f"  Load average (1 min) at the start and end of the run: {r['load_average'][0]:.1f}, "
           f"{r['load_average'][1]:.1f} -- other work shared the cores." if "load_average" in r else ""),
        "",
        "| step | output | median (s) | runs (s) | peak RSS (MB) |",
        "|---|---|---:|---|---:|",
    ]
    for c in (b, d):
        lines.append(f"| {c['case']} | {c['shape'][1]} x {c['shape'][0]} x 3 float32 | **{c['median_s']:.2f}** | "
                     f"{', '.join(f'{t:.2f}' for t in c['times_s'])} | {c['peak_rss_mb']:.0f} |")
    lines += [
        "",
        "| preview of | preview size | preview (s) | detect (s) | detect runs (s) | confidence | "
        "centre error max / mean (px) |",
        "|---|---|---:|---:|---|---:|---|",
    ]
    for mode in ("bin2x2", "demosaic"):
        m = det[mode]
        lines.append(
            f"| {mode} | {m['preview_size'][0]} x {m['preview_size'][1]} | {m['preview_s']:.2f} | "
            f"**{m['detect_s']:.2f}** | {', '.join(f'{t:.2f}' for t in m['detect_times_s'])} | "
            f"{m['confidence']:.2f} | {m['centre_error_max_px']:.2f} / {m['centre_error_mean_px']:.2f} |"
        )
    lines += [
        "",
        f"Ratios of medians: demosaic / bin2x2 decode {d['median_s'] / b['median_s']:.1f}; detection on the binned "
        f"preview / binned decode {det['bin2x2']['detect_s'] / b['median_s']:.1f}; detection on the full preview / "
        f"on the binned one {det['demosaic']['detect_s'] / det['bin2x2']['detect_s']:.1f}.  "
        f"Detection case peak RSS (both modes decoded in turn): {det['peak_rss_mb']:.0f} MB.",
        "",
    ]
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=["all", "decode-bin2x2", "decode-demosaic", "detect"], default="all")
    ap.add_argument("--dng", type=Path)
    ap.add_argument("--centres", help="JSON list of the true patch centres (detect case)")
    ap.add_argument("--markdown", action="store_true", help="print the Markdown section after the JSON line")
    args = ap.parse_args(argv)
    if args.case == "all":
        results = run_all()
        print(json.dumps(results))
        if args.markdown:
            print("\n".join(section(results)))
        return
    if args.dng is None:
        sys.exit("--dng PATH is needed with --case")
    if args.case == "detect":
        print(json.dumps(case_detect(args.dng, json.loads(args.centres))))
    else:
        print(json.dumps(case_decode(args.dng, args.case.split("-", 1)[1])))


if __name__ == "__main__":
    main()
