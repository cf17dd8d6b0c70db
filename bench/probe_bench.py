"""Cost and error of a light probe at a real camera's size: 7 brackets of 24 megapixels.

The simulated chrome ball in the simulated room (:mod:`mocks.probe_world`) is photographed at
6000 x 4000 (24 MP, RGGB 14-bit DNG) at the 7 exposure times of :data:`mocks.probe_world.BRACKET_TIMES_S`
(2 EV apart, 1/4000 s to 1 s, f/8, ISO 100); the camera signal is computed without the spectral image
(:meth:`mocks.probe_world.ProbeWorld.camera_signal`, which would need 6 GB).  The chart is shot in the
same light at 960 x 640.  Then, each in a fresh process so its peak memory is its own:

* ``merge-demosaic`` / ``merge-bin2x2``: :func:`processing.lighting.hdr_merge.merge_brackets` of the 7
  frames (decoding included);
* ``probe``: the whole :func:`app.workflows.light_probe.build_probe` (chart, merge, sphere finding, unwrap
  to a 512 x 1024 map, spectral), and the map against the room's truth: per region (away from borders),
  the median luminance ratio and the xy distance of the mean colour, and the solid-angle total;
* ``limits`` (no frames): what the simulated camera's three values can tell at all.  The luminance
  range of the spectra that give each region's camera values (:func:`processing.spectral.estimation.
  metamer_set.luminance_range`, over smooth spectra: 8 principal components of the training
  reflectances), and the estimator's own luminance and chromaticity errors on training reflectances
  it did not see (10-fold), by CIELAB chroma under D65;
* ``channels`` (no frames): three camera channels against six (a second bracket set through a colour
  filter, :data:`mocks.probe_world.FILTERS`), per wall and on 29 test colours no estimator was trained on.

Run ``python -m bench.probe_bench`` (all cases; one JSON line) or ``--case NAME --dir DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.common import machine_description, peak_rss_mb, run_case_subprocess

__all__ = ["make_shots", "section", "main"]

WIDTH, HEIGHT = 6000, 4000
MAP_HEIGHT = 512
#: The probe from two bracket sets (the second through :data:`mocks.probe_world.PROBE_FILTER`), with the chart's
#: light stated as D65 and as measured.
TWO_SET_CASES = ("probe-two-sets", "probe-two-sets-measured-light")
#: Basis sizes of the two-set map tried beside the default 6 (``components`` case, the light as measured).
COMPONENT_TRADE = (3, 4, 5)


def _world(width: int, height: int):
    from mocks.probe_world import ProbeWorld

    return ProbeWorld.probe(20.0, width=width, height=height)


def make_shots(folder: Path) -> dict:
    """Write the 24 MP brackets, the chart frame and the camera's calibration into ``folder``."""
    from mocks.camera_sim import (
        RawFrame,
        SensorModel,
        camera_sensitivities,
        expose,
        mosaic,
        white_balance_neutral,
        write_raw,
        xyz_to_camera_matrix,
    )
    from mocks.probe_world import (
        BRACKET_TIMES_S,
        FILTERS,
        PROBE_F_NUMBER,
        PROBE_FILTER,
        filter_transmission,
        write_filter_csv,
        write_light_csv,
        write_probe_shots,
    )
    from processing.geometry.camera_calibration import CameraCalibration

    folder.mkdir(parents=True, exist_ok=True)
    small = _world(960, 640)
    chart, _ = write_probe_shots(small, folder / "chart", times_s=())
    world = _world(WIDTH, HEIGHT)
    transmission = filter_transmission(*FILTERS[PROBE_FILTER], world.grid.wavelengths)
    write_probe_shots(small, folder / "filtered" / "chart", times_s=(), transmission=transmission, seed=1)
    write_filter_csv(folder / "filter.csv")
    write_light_csv(world, folder / "light.csv")      # the chart's light as a spectroradiometer there gives it
    light = world.light_spectrum()
    sens = camera_sensitivities(world.grid)
    sensor = SensorModel()
    frames, render_s = [], 0.0
    for sub, s_filter, seed0 in (("", sens, 0), ("filtered", sens * transmission[:, None], 100)):
        t0 = time.perf_counter()
        signal = world.camera_signal(s_filter)
        render_s += time.perf_counter() - t0
        cfa = mosaic(signal, sensor.cfa_pattern).astype(np.float32)
        del signal
        (folder / sub).mkdir(exist_ok=True)
        for i, t in enumerate(BRACKET_TIMES_S):
            bayer, _ = expose(cfa, sensor, float(t), np.random.default_rng(seed0 + i))
            raw = RawFrame(bayer, sensor.black_level, sensor.white_level, sensor.cfa_pattern, float(t), sensor.iso,
                           np.array(xyz_to_camera_matrix(world.grid)), white_balance_neutral(light, world.grid),
                           np.zeros((1, 1)), f_number=PROBE_F_NUMBER)
            path = write_raw(folder / sub / f"probe-{i + 1}.dng", raw)
            if not sub:
                frames.append(str(path))
    cal = CameraCalibration((WIDTH, HEIGHT), world.camera_intrinsics(), np.zeros(5), np.eye(4),
                            room_to_camera=world.room_to_camera())
    (folder / "camera_calibration.json").write_text(json.dumps(cal.to_dict()))
    return {"frames": frames, "chart": str(chart), "render_s": render_s,
            "file_mb": sum(os.path.getsize(f) for f in frames) / len(frames) / 1e6}


def _frames(folder: Path) -> list[Path]:
    return sorted(folder.glob("probe-*.dng"), key=lambda p: int(p.stem.split("-")[1]))


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process so far: the work, whatever else shares the cores."""
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def case_merge(folder: Path, mode: str) -> dict:
    from processing.lighting.hdr_merge import merge_brackets

    frames = _frames(folder)
    c0, t0 = _cpu_s(), time.perf_counter()
    hdr = merge_brackets(frames, mode=mode)
    seconds, cpu = time.perf_counter() - t0, _cpu_s() - c0
    return {"case": f"merge-{mode}", "seconds": seconds, "cpu_s": cpu, "shape": list(hdr.shape),
            "peak_rss_mb": peak_rss_mb(), "saturated_everywhere": float(hdr.saturated.mean()),
            "load_average": os.getloadavg()[0]}


def _region_errors(env, observed, world) -> dict:
    from scipy.ndimage import binary_erosion

    from mocks.probe_world import ROOM_REGIONS, region_labels
    from processing.spectral.display import spectra_to_xyz

    d = env.directions()
    rec = spectra_to_xyz(env.spectral_radiance(d), env.grid)
    truth = spectra_to_xyz(world.environment.spectral_radiance(d), world.grid) / world.chart_white_luminance()
    labels = region_labels(env.height)

    def xy(v):
        return v[..., :2] / v.sum(axis=-1, keepdims=True)

    rows = {}
    for k, name in enumerate(ROOM_REGIONS):
        m = binary_erosion(labels == k, iterations=2) & observed
        if m.sum() < 10:
            continue
        rows[name] = {"luminance_ratio": float(np.median(rec[m][:, 1] / truth[m][:, 1])),
                      "dxy": float(np.abs(xy(rec[m].mean(axis=0)) - xy(truth[m].mean(axis=0))).max()),
                      "pixels": int(m.sum())}
    w = env.solid_angles() * observed
    return {"regions": rows, "total_luminance_ratio": float((rec[..., 1] * w).sum() / (truth[..., 1] * w).sum())}


def case_probe(folder: Path, filtered: bool = False, measured_light: bool = False, components: int | None = None) -> dict:
    """The whole probe: one bracket set (wiener), or two with the filtered set (twolight, ``components`` basis
    spectra, default 6); the chart's light stated as D65 or given as measured (``light.csv``)."""
    from app.workflows.light_probe import build_probe, probe_inputs

    extra = {"filter_frames": str(folder / "filtered"), "filter_chart": str(folder / "filtered" / "chart" / "chart.dng"),
             "filter_transmission": str(folder / "filter.csv")} if filtered else {}
    inputs = probe_inputs([str(p) for p in _frames(folder)], chart=str(folder / "chart" / "chart.dng"),
                          camera_calibration=str(folder / "camera_calibration.json"), sphere_radius_mm=20.0, **extra)
    light = str(folder / "light.csv") if measured_light else "D65"
    c0, t0 = _cpu_s(), time.perf_counter()
    result = build_probe(inputs, height=MAP_HEIGHT, light=light, components=components)
    seconds, cpu = time.perf_counter() - t0, _cpu_s() - c0
    errors = _region_errors(result.environment, result.observed, _world(96, 64))
    spectral = result.report["spectral"]
    return {"case": "probe", "seconds": seconds, "cpu_s": cpu, "load_average": os.getloadavg()[0], "steps_s": result.report["seconds"], "peak_rss_mb": peak_rss_mb(),
            "radius_px": result.report["sphere"]["radius_px"], "observed": result.report["map"]["observed_fraction"],
            "chart_rmse": spectral["chart_rmse"], "light": "measured" if measured_light else "D65",
            "method": spectral["method"], **{k: spectral[k] for k in ("components", "projection_dxy_p99",
                                                                      "projection_spectral_median") if k in spectral},
            **errors}


#: CIELAB chroma classes (under D65) of the held-out reflectance errors.
CHROMA_CLASSES = ((0.0, 20.0), (20.0, 40.0), (40.0, 60.0), (60.0, 200.0))


def case_limits() -> dict:
    """The camera's metamer range per room region, and held-out estimator errors by chroma."""
    import colour

    from app.workflows.spectral import estimator_setup
    from mocks.camera_sim import camera_sensitivities
    from mocks.probe_world import ROOM_REGIONS
    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.estimation.estimator import fit_estimator
    from processing.spectral.estimation.metamer_set import luminance_range
    from processing.spectral.spectra import light_spectrum

    world = _world(96, 64)
    setup = estimator_setup()
    g, sens = world.grid, camera_sensitivities(world.grid)
    e = world.light_spectrum()
    smooth = np.linalg.svd(setup.training, full_matrices=False)[2][:8]
    rho = world.environment.basis * np.pi / e                 # each region as a "reflectance" in the chart's light
    values = (rho * e) @ sens * g.step
    lo, hi = luminance_range(values, sens, e, g, basis=smooth)
    y = spectra_to_xyz(rho * e, g)[:, 1]
    regions = {name: [float(a), float(b)] for name, a, b in zip(ROOM_REGIONS, lo / y, hi / y)}

    d65 = light_spectrum("D65", g)
    train = setup.training
    chart_rgb = (setup.reflectances * d65) @ sens * g.step
    order = np.random.default_rng(0).permutation(len(train))
    ratio, dxy = np.empty(len(train)), np.empty(len(train))
    for fold in np.array_split(order, 10):
        fit = fit_estimator("wiener", np.delete(train, fold, axis=0), setup.sensitivities, d65, g, noise=0.01,
                            chart_rgb=chart_rgb, chart_reflectance=setup.reflectances)
        est = fit.estimate_weights((train[fold] * d65) @ sens * g.step) @ fit.basis.T
        x1, x0 = spectra_to_xyz(est * d65, g), spectra_to_xyz(train[fold] * d65, g)
        ratio[fold] = x1[:, 1] / x0[:, 1]
        dxy[fold] = np.abs(x1[:, :2] / x1.sum(-1, keepdims=True) - x0[:, :2] / x0.sum(-1, keepdims=True)).max(-1)
    white = spectra_to_xyz(d65, g)
    lab = colour.XYZ_to_Lab(spectra_to_xyz(train * d65, g) / white[1], colour.XYZ_to_xy(white))
    chroma = np.hypot(lab[:, 1], lab[:, 2])
    classes = []
    for c0, c1 in CHROMA_CLASSES:
        m = (chroma >= c0) & (chroma < c1)
        err = np.abs(ratio[m] - 1.0)
        classes.append({"chroma": [c0, c1], "n": int(m.sum()), "median": float(np.median(err)),
                        "p90": float(np.quantile(err, 0.9)), "within_5pct": float(np.mean(err <= 0.05)),
                        "dxy_median": float(np.median(dxy[m])), "within_0005": float(np.mean(dxy[m] <= 0.005))})
    from mocks.probe_world import WALL_PATCHES

    lab_walls = colour.XYZ_to_Lab(spectra_to_xyz(setup.reflectances[list(WALL_PATCHES)] * d65, g) / white[1],
                                  colour.XYZ_to_xy(white))
    wall_chroma = {name: float(np.hypot(a, b)) for name, (_, a, b)
                   in zip(("red wall", "green wall", "blue wall", "yellow wall"), lab_walls)}
    return {"metamer_range": regions, "held_out": classes, "training_n": int(len(train)),
            "wall_chroma": wall_chroma}


def case_channels(draws: int = 20) -> dict:
    """Three camera channels against six (a second bracket set through a colour filter), wall by wall.

    The room's walls and, as colours no estimator was trained on, the CIE 1995 test colour samples and
    NIST CQS 9.0's fifteen (29 reflectances), in the room's light through the model camera with 1 %
    noise per channel (``draws`` draws); each estimator fitted on the training reflectances for that
    light (and the light through the filter).  Per row the xy error (mean over the draws) and, for the
    walls, the luminance ratio.
    """
    import colour
    from colour.quality.datasets import SDS_TCS, SDS_VS

    from app.workflows.spectral import estimator_setup
    from mocks.probe_world import FILTERS, ROOM_REGIONS, filter_transmission
    from processing.spectral.display import spectra_to_xyz
    from processing.spectral.estimation.estimator import fit_estimator
    from processing.spectral.estimation.two_light import fit_two_light

    world = _world(96, 64)
    setup = estimator_setup()
    g, sens = world.grid, setup.sensitivities
    e = world.light_spectrum()
    walls = [i for i, name in enumerate(ROOM_REGIONS) if name.endswith(" wall")]
    rho_walls = (world.environment.basis * np.pi / e)[walls]
    shape = colour.SpectralShape(g.start, g.stop, g.step)
    test = np.array([sd.copy().align(shape, extrapolator_kwargs={"method": "Constant"}).values
                     for sd in [*SDS_TCS["CIE 1995"].values(), *SDS_VS["NIST CQS 9.0"].values()]])
    wl = g.wavelengths

    def xy_y(spectra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        xyz = spectra_to_xyz(spectra * e, g)
        return xyz[:, :2] / xyz.sum(axis=1, keepdims=True), xyz[:, 1]

    rng = np.random.default_rng(0)

    def errors(fit, filt, rho):
        rgb = (rho * e) @ sens * g.step
        if filt is not None:
            rgb = np.concatenate([rgb, (rho * e * filt) @ sens * g.step], axis=1)
        t_xy, t_y = xy_y(rho)
        dxy, ratio = [], []
        for _ in range(draws):
            est = fit.estimate_weights(rgb * (1.0 + 0.01 * rng.standard_normal(rgb.shape))) @ fit.basis.T
            x, y = xy_y(est)
            dxy.append(np.linalg.norm(x - t_xy, axis=1))
            ratio.append(y / t_y)
        return np.mean(dxy, axis=0), np.median(ratio, axis=0)

    rows = []
    for name, spec in [("none", None), *FILTERS.items()]:
        filt = None if spec is None else filter_transmission(*spec, wl)
        for method in ("wiener", "rootpoly"):
            if filt is None:
                fit = fit_estimator(method, setup.training, sens, e, g, noise=0.01)
            else:
                fit = fit_two_light(setup.training, sens, np.stack([e, e * filt]), g, estimator=method, noise=0.01)
            w_xy, w_ratio = errors(fit, filt, rho_walls)
            t_xy, _ = errors(fit, filt, test)
            rows.append({"filter": name, "estimator": method, "channels": 3 if filt is None else 6,
                         "linear": fit.expansion == "linear", "walls_dxy": w_xy.round(5).tolist(),
                         "walls_luminance_ratio": w_ratio.round(4).tolist(),
                         "test_dxy_median": float(np.median(t_xy)), "test_dxy_max": float(t_xy.max()),
                         "test_n": int(len(test))})
    return {"walls": [ROOM_REGIONS[i] for i in walls], "rows": rows}


def run_all() -> dict:
    with tempfile.TemporaryDirectory(prefix="kogei-probe-bench-") as tmp:
        made = run_case_subprocess("bench.probe_bench", "make", "--dir", tmp, timeout=3600)
        out = {"machine": machine_description(), "size": [WIDTH, HEIGHT], **made,
               "load_average": [os.getloadavg()[0]]}
        for case in ("merge-demosaic", "merge-bin2x2", "probe", *TWO_SET_CASES, "components", "limits", "channels"):
            out[case] = run_case_subprocess("bench.probe_bench", case, "--dir", tmp, timeout=3600)
        out["load_average"].append(os.getloadavg()[0])
    return out


def section(results: dict | None = None) -> list[str]:
    """The Markdown section of docs/BENCHMARKS.md (runs the benchmark when no results are given)."""
    r = results or run_all()
    p = r["probe"]
    lines = [
        "## Light probe",
        "",
        f"7 brackets (1/4000 s to 1 s, 2 EV apart, f/8, ISO 100) of a chrome ball in the simulated room, "
        f"{r['size'][0]} x {r['size'][1]} (24 MP) RGGB 14-bit DNGs of {r['file_mb']:.0f} MB (`bench/probe_bench.py`);",
        "each case in a fresh process.  The merge includes decoding.  The probe is the whole chain (chart, merge,",
        f"sphere, unwrap to {MAP_HEIGHT} x {2 * MAP_HEIGHT}, spectral); its map is compared with the room's truth",
        "region by region (2 map rows from any border; the caps toward and away from the camera are not seen).",
        "Targets: merge <= 20 s and <= 3 GB; luminance within 5 %, chromaticity (CIE 1931 xy) within 0.005.",
        "",
        f"Machine: {r['machine']}.  Load average (1 min) at the start and end: {r['load_average'][0]:.1f}, "
        f"{r['load_average'][1]:.1f}.",
        "",
        "CPU time (user + system of the process) is the work itself; wall time grows with what else runs.",
        "",
        "| case | output | wall time (s) | CPU time (s) | peak RSS (MB) |",
        "|---|---|---:|---:|---:|",
    ]
    for name in ("merge-demosaic", "merge-bin2x2"):
        c = r[name]
        lines.append(f"| {name} | {c['shape'][1]} x {c['shape'][0]} x 3 float32 | **{c['seconds']:.1f}** | "
                     f"{c['cpu_s']:.1f} | {c['peak_rss_mb']:.0f} |")
    st = p["steps_s"]
    lines.append(f"| probe (chart {st['chart']:.1f} s, merge {st['merge']:.1f} s, sphere + unwrap {st['unwrap']:.1f} s) "
                 f"| {MAP_HEIGHT} x {2 * MAP_HEIGHT} map | **{p['seconds']:.1f}** | {p['cpu_s']:.1f} | "
                 f"{p['peak_rss_mb']:.0f} |")
    lines += [
        "",
        f"Ball radius {p['radius_px']:.0f} px; {100 * p['observed']:.0f} % of the directions seen; chart RMS "
        f"reflectance error {p['chart_rmse']:.3f}; solid-angle total luminance ratio of the seen directions "
        f"**{p['total_luminance_ratio']:.3f}**.",
        "",
        "| region | luminance ratio (median) | xy distance of the mean | map pixels |",
        "|---|---:|---:|---:|",
    ]
    for name, row in p["regions"].items():
        lines.append(f"| {name} | {row['luminance_ratio']:.3f} | {row['dxy']:.4f} | {row['pixels']} |")
    lines.append("")
    lines += two_set_lines(r)
    return lines + limits_lines(r["limits"]) + (channels_lines(r["channels"], p["regions"].get("red wall", {}).get("dxy"))
                                             if "channels" in r else [])


def two_set_lines(r: dict) -> list[str]:
    """The probe from two bracket sets (the second through the magenta notch filter), with the chart's light
    stated as D65 and as measured."""
    cases = [c for c in TWO_SET_CASES if c in r]
    if not cases:
        return []
    names = list(r[cases[0]]["regions"])
    lines = [
        "The same probe from two bracket sets, the second shot through the magenta notch filter (the chart too): "
        "six camera values per direction, the two-light root polynomial, a map of "
        f"{r[cases[0]]['components']} non-negative basis spectra; the chart's light stated as D65, and given as "
        "measured (the room's irradiance on the table, as a spectroradiometer there would give it).  Per region: "
        "luminance ratio / xy distance.",
        "",
        "| chart's light | wall time (s) | CPU time (s) | peak RSS (MB) | basis: xy p99 | "
        + " | ".join(names) + " |",
        "|---|---:|---:|---:|---:|" + "---:|" * len(names),
    ]
    rows = [r[c] for c in cases] + [x for x in r.get("components", {}).get("rows", [])]
    for p in rows:
        cells = [f"{x['luminance_ratio']:.3f} / {x['dxy']:.4f}" for x in p["regions"].values()]
        ok = all(abs(x["luminance_ratio"] - 1) <= 0.05 and x["dxy"] <= 0.005 for x in p["regions"].values())
        label = p["light"] + ("" if p["components"] == r[cases[0]]["components"] else f", {p['components']} basis spectra")
        lines.append(f"| {label}{' (all within target)' if ok else ''} | {p['seconds']:.1f} | {p['cpu_s']:.1f} | "
                     f"{p['peak_rss_mb']:.0f} | {p['projection_dxy_p99']:.4f} | " + " | ".join(cells) + " |")
    lines += ["", "'basis: xy p99': what the map's basis loses against the estimated spectra (99th percentile over "
              "the map's pixels of the xy distance); the rows with fewer basis spectra are the trade against the "
              "render's cost, which grows with them.", ""]
    return lines


def limits_lines(lim: dict) -> list[str]:
    """The "what the camera can tell" part of the section."""
    wc = lim["wall_chroma"]
    lines = [
        "What the camera's three values can tell.  The walls are strongly coloured (CIELAB chroma under D65: "
        + ", ".join(f"{name} {c:.0f}" for name, c in wc.items()) + ").  Over smooth spectra (8 principal "
        "components of the training reflectances, non-negative) the camera values of each region are given by "
        "spectra whose luminance spans the range below (Finlayson & Morovic's metamer set, two linear "
        "programmes per region): no estimator can be sure of a luminance from the values alone; its "
        "accuracy comes from its prior.  How good that prior is for coloured surfaces, on the "
        f"{lim['training_n']} training reflectances, each estimated by a Wiener estimator fitted without it "
        "(10-fold, D65, the same camera and chart):",
        "",
        "| region | luminance of the camera's metamers / truth |",
        "|---|---|",
    ]
    for name, (lo, hi) in lim["metamer_range"].items():
        lines.append(f"| {name} | {lo:.2f} to {hi:.2f} |")
    lines += ["", "| chroma (CIELAB, D65) | reflectances | luminance error median / p90 | within 5 % | "
              "xy error median | within 0.005 |", "|---|---:|---:|---:|---:|---:|"]
    for c in lim["held_out"]:
        c0, c1 = c["chroma"]
        label = f"{c0:.0f}-{c1:.0f}" if c1 < 200 else f">= {c0:.0f}"
        lines.append(f"| {label} | {c['n']} | {100 * c['median']:.1f} % / {100 * c['p90']:.1f} % | "
                     f"{100 * c['within_5pct']:.0f} % | {c['dxy_median']:.4f} | {100 * c['within_0005']:.0f} % |")
    lines += ["", "The targets hold for the neutral and weakly coloured regions (floor, ceiling, window, lamps: within "
              "1 % and 0.005) and for the green and yellow walls; the red and blue walls miss them.  Among the "
              "reflectances the estimator did not see, a quarter of those with chroma above 40 miss 5 % in "
              "luminance and most miss 0.005 in xy: the red and blue walls are such surfaces.  The limit is the "
              "camera's three channels with the estimator's prior, not the merge or the unwrap; reaching the "
              "targets on strongly coloured light needs more than three channels (measured below).", ""]
    return lines


def channels_lines(ch: dict, chain_red_dxy: float | None = None) -> list[str]:
    """The "three channels against six" part of the section (``chain_red_dxy``: the red wall's xy error through
    the probe's whole chain, for comparison)."""
    lines = [
        "Three channels against six: a second bracket set through a colour filter (idealised smooth filter "
        "curves, not measured products).  A filter over the lens is a second light for the estimator (the "
        "light times the filter's transmission), as two lights are for an object (`twolight`).  The room's "
        "walls, and 29 colours no estimator was trained on (CIE 1995 test colour samples 1-14, NIST CQS 9.0 "
        "VS1-15), in the room's light through the model camera with 1 % noise per channel (mean of 20 draws), "
        "each estimator fitted on the training reflectances; `linear` estimators could keep the map as "
        "coefficients of a fixed basis (3 or 6), the root polynomial could not:",
        "",
        "| filter | estimator | xy error " + " / ".join(w.replace(" wall", "") for w in ch["walls"])
        + " wall | luminance ratio of the walls | test colours: xy error median / max |",
        "|---|---|---|---|---|",
    ]
    for r in ch["rows"]:
        ok = all(d <= 0.005 for d in r["walls_dxy"]) and all(abs(x - 1) <= 0.05 for x in r["walls_luminance_ratio"])
        dxy = " / ".join(f"{d:.4f}" for d in r["walls_dxy"])
        lines.append(f"| {r['filter']} | {r['estimator']}{' (linear)' if r['linear'] else ''} | "
                     f"{'**' + dxy + '**' if ok else dxy} | "
                     + " / ".join(f"{x:.3f}" for x in r["walls_luminance_ratio"])
                     + f" | {r['test_dxy_median']:.4f} / {r['test_dxy_max']:.4f} |")
    def worst(r: dict) -> float:
        return max(r["walls_dxy"])

    both = [r for r in ch["rows"] if worst(r) <= 0.005 and all(abs(x - 1) <= 0.05 for x in r["walls_luminance_ratio"])]
    three = next(r for r in ch["rows"] if r["channels"] == 3 and r["linear"])
    linear6 = min((r for r in ch["rows"] if r["channels"] == 6 and r["linear"]), key=worst)
    lines += ["", "Bold: every wall within 0.005 in xy and 5 % in luminance: "
              + (", ".join(f"{r['filter']} with {r['estimator']} (largest wall error {worst(r):.4f})" for r in both)
                 or "no row") + f".  The probe's three channels (wiener): largest wall error {worst(three):.4f}; the "
              f"best linear six-channel row: {linear6['filter']}, {worst(linear6):.4f}.  A filter chosen by the walls "
              "would be fitted to what is scored; by the test colours the best three rows are "
              + ", ".join(f"{r['filter']} with {r['estimator']} ({r['test_dxy_median']:.4f} median, "
                          f"{worst(r):.4f} on the walls)"
                          for r in sorted(ch["rows"], key=lambda r: r["test_dxy_median"])[:3])
              + ".  These figures leave out the "
              "chain's own errors (merge, demosaic, the chart's calibration)"
              + ("" if chain_red_dxy is None else f": through the chain the red wall reads {chain_red_dxy:.4f} in the "
                 f"table above, against {three['walls_dxy'][0]:.4f} here") + ".  `kogei probe --filter-frames` reads such a second set "
              "(the magenta notch): the whole chain's figures are in the table above.", ""]
    return lines


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="all", choices=["all", "make", "merge-demosaic", "merge-bin2x2", "probe",
                                                       *TWO_SET_CASES, "components", "limits", "channels"])
    ap.add_argument("--dir", default=None, help="the folder of the shots (cases other than all)")
    args = ap.parse_args(argv)
    if args.case == "all":
        out = run_all()
    elif args.case == "limits":
        out = case_limits()
    elif args.case == "channels":
        out = case_channels()
    elif args.dir is None:
        sys.exit("--dir is needed for a single case")
    elif args.case == "make":
        out = make_shots(Path(args.dir))
    elif args.case == "probe":
        out = case_probe(Path(args.dir))
    elif args.case in TWO_SET_CASES:
        out = case_probe(Path(args.dir), filtered=True, measured_light=args.case.endswith("measured-light"))
    elif args.case == "components":
        out = {"rows": [case_probe(Path(args.dir), filtered=True, measured_light=True, components=k)
                        for k in COMPONENT_TRADE]}
    else:
        out = case_merge(Path(args.dir), args.case.split("-", 1)[1])
    print(json.dumps(out))


if __name__ == "__main__":
    main()
