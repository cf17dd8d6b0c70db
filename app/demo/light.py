"""Measured light in ``kogei demo``: a simulated light probe, and the hawk under it and under a daylight sky.

The simulated camera photographs the chart and 7 brackets of a chrome ball in the simulated room of
known light (:mod:`mocks.probe_world`, 480 x 320 frames, so it costs seconds), then both again through a
colour filter; ``build_probe`` merges, finds the ball, unwraps and makes the map spectral from the six
channels (:mod:`app.workflows.light_probe`), and the demo writes ``probe.exr`` (with ``probe.json``) and
compares the map -- and the one-set probe's -- with the room's truth region by region,
as ``tests/integration/test_light_probe_truth.py`` does: the median luminance ratio and the CIE 1931
xy of the mean colour over each region's seen directions, away from region borders.  Then the hawk
(its measured materials on its mesh when the demo's capture produced them, else the preset hawk) is
rendered under the probe (``hawk-probe.png``) and under the analytic daylight sky (``hawk-sky.png``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.workflows.scene_spec import EnvironmentSpec, SceneSpec, parse_environment

__all__ = ["PROBE_FRAME_SIZE", "BORDER_ROWS", "WALL_BORDER_ROWS", "SKY", "probe_vs_truth", "simulated_probe",
           "render_lit_hawk", "demo_light"]

#: The simulated probe's frame size (px): the ball about 30 px in radius, a 64 x 128 map.
PROBE_FRAME_SIZE = (480, 320)
#: Map rows between a compared region and its borders: 2, and 4 for the coloured walls -- at this size the
#: ball's image blurs a wall with its neighbour (another wall, the window) over 2-3 rows of the map, and
#: the lamps, 10 degree discs, keep no pixel 4 rows in.
BORDER_ROWS = 2
WALL_BORDER_ROWS = 4
#: The outdoor sky the hawk is rendered under (``--environment`` syntax).
SKY = "sky:cct=6500,sun_elevation=40,sun_azimuth=-60,type=clear"


def _xy(xyz: np.ndarray) -> np.ndarray:
    return xyz[..., :2] / xyz.sum(axis=-1, keepdims=True)


def probe_vs_truth(env: Any, observed: np.ndarray, world: Any, *, border_rows: int = BORDER_ROWS,
                   wall_border_rows: int = WALL_BORDER_ROWS) -> dict[str, Any]:
    """A recovered probe map against the simulated room's truth, region by region.

    Parameters
    ----------
    env
        The recovered :class:`processing.lighting.environment_map.EnvironmentMap` (units of the chart's white).
    observed
        ``(H, 2H)`` bool: the directions the ball shows.
    world
        The :class:`mocks.probe_world.ProbeWorld` photographed.
    border_rows, wall_border_rows
        Map rows kept away from every region border, and from a wall's (the map's blur mixes neighbours
        there).

    Returns
    -------
    dict
        ``regions``: per region name, ``luminance_ratio`` (median of recovered / true luminance),
        ``xy`` and ``true_xy`` (of the mean colours), ``dxy`` (largest xy coordinate difference) and
        ``pixels``; ``total_luminance_ratio``: the solid-angle total luminance of the seen directions.
    """
    from scipy.ndimage import binary_erosion

    from mocks.probe_world import ROOM_REGIONS, region_labels
    from processing.spectral.display import spectra_to_xyz

    d = env.directions()
    rec = spectra_to_xyz(env.spectral_radiance(d), env.grid)
    truth = spectra_to_xyz(world.environment.spectral_radiance(d), world.grid) / world.chart_white_luminance()
    labels = region_labels(env.height)
    rows = {}
    for k, name in enumerate(ROOM_REGIONS):
        m = binary_erosion(labels == k, iterations=wall_border_rows if name.endswith(" wall") else border_rows) \
            & observed
        if m.sum() < 10:
            continue
        xy, true_xy = _xy(rec[m].mean(axis=0)), _xy(truth[m].mean(axis=0))
        rows[name] = {"luminance_ratio": round(float(np.median(rec[m][:, 1] / truth[m][:, 1])), 4),
                      "xy": [round(float(v), 4) for v in xy], "true_xy": [round(float(v), 4) for v in true_xy],
                      "dxy": round(float(np.abs(xy - true_xy).max()), 4), "pixels": int(m.sum())}
    w = env.solid_angles() * observed
    total = float((rec[..., 1] * w).sum() / (truth[..., 1] * w).sum())
    return {"regions": rows, "total_luminance_ratio": round(total, 4)}


def simulated_probe(folder: Path, out_exr: Path) -> dict[str, Any]:
    """Shoot the simulated room's probe into ``folder``, build it, write ``out_exr``; figures vs the truth.

    Two bracket sets are shot, the second through the magenta notch filter
    (:data:`mocks.probe_world.PROBE_FILTER`, the chart too), and the chart's light is given as measured (the
    room's irradiance on the table, written as the CSV a spectroradiometer there would give): ``out_exr`` is
    that six-channel probe.  The one-set probe (three channels, the light stated as D65) is built too, for
    comparison (``one_set``).  Regions are compared :data:`BORDER_ROWS` map rows from their borders, the
    walls :data:`WALL_BORDER_ROWS`.
    """
    from app.workflows.light_probe import ProbeInputs, build_probe, write_probe
    from mocks.probe_world import PROBE_FILTER, ProbeWorld, write_filtered_shots, write_light_csv, write_probe_shots
    from processing.geometry.camera_calibration import CameraCalibration

    t0 = time.perf_counter()
    w, h = PROBE_FRAME_SIZE
    world = ProbeWorld.probe(20.0, width=w, height=h)
    chart, frames = write_probe_shots(world, folder)
    filter_chart, filter_frames, filter_csv = write_filtered_shots(world, folder / "filtered")
    light_csv = write_light_csv(world, folder / "measured-light.csv")
    t1 = time.perf_counter()
    cal = CameraCalibration((w, h), world.camera_intrinsics(), np.zeros(5), np.eye(4),
                            room_to_camera=world.room_to_camera())
    one = build_probe(ProbeInputs(frames, chart, cal, 20.0, str(folder)))
    result = build_probe(ProbeInputs(frames, chart, cal, 20.0, str(folder), filter_frames=filter_frames,
                                     filter_chart=filter_chart, filter_transmission=filter_csv),
                         light=str(light_csv))
    write_probe(result, out_exr)
    t2 = time.perf_counter()
    figures = probe_vs_truth(result.environment, result.observed, world)
    one_set = probe_vs_truth(one.environment, one.observed, world)
    return {"probe": str(out_exr), "report": str(out_exr.with_suffix(".json")), "frames": len(frames),
            "filter_frames": len(filter_frames), "filter": PROBE_FILTER, "frame_size": [w, h],
            "map": [result.environment.height, result.environment.width],
            "components": result.report["spectral"]["components"],
            "observed_fraction": round(result.report["map"]["observed_fraction"], 4),
            "chart_rmse": round(result.report["spectral"]["chart_rmse"], 4),
            "seconds": {"shots": round(t1 - t0, 2), "probe": round(t2 - t1, 2)}, **figures,
            "one_set": one_set}


def render_lit_hawk(base: SceneSpec, environment: str | Path, path: Path, *, default_hawk_triangles: int) -> float:
    """Render ``base`` with its lights and sky replaced by ``environment`` into ``path``; returns seconds.

    ``environment`` is a map file or an ``--environment sky:...`` text.
    """
    import copy

    from app.workflows.scene_build import build_job
    from render.image_io import write_png
    from render.renderer import render

    spec = copy.deepcopy(base)
    spec.lights, spec.sky_given = [], False
    spec.environment = (EnvironmentSpec(file=environment) if isinstance(environment, Path)
                        else parse_environment(environment))
    t0 = time.perf_counter()
    job = build_job(spec, default_hawk_triangles=default_hawk_triangles)
    write_png(path, render(job.scene, job.camera, job.settings).srgb8)
    return time.perf_counter() - t0


def demo_light(out: Path, base: SceneSpec, source: str, *, default_hawk_triangles: int,
               probe: dict[str, Any] | None = None) -> dict[str, Any]:
    """The simulated probe (``probe.exr``) and the hawk under it and under the sky; printed and returned.

    ``probe``: :func:`simulated_probe`'s answer for ``out`` when the probe was already shot and built (the
    demo does that in its second process, as it needs nothing from the capture); None: here.
    """
    if probe is None:
        probe = simulated_probe(out / "probe-capture", out / "probe.exr")
    s = probe["seconds"]
    print(f"light probe: {probe['frames']} brackets of the simulated room and {probe['filter_frames']} more through "
          f"the {probe['filter']} filter ({probe['frame_size'][0]} x {probe['frame_size'][1]}) merged and unwrapped "
          f"to a {probe['map'][0]} x {probe['map'][1]} map of {probe['components']} basis spectra, "
          f"{100 * probe['observed_fraction']:.0f} % of the directions seen ({s['shots']:.1f} s to shoot, "
          f"{s['probe']:.1f} s to build both probes) -> {probe['probe']}", file=sys.stderr)
    print(f"  recovered vs the room's truth: total luminance of the seen directions {probe['total_luminance_ratio']:.3f}"
          " (target within 5 %, chromaticity within 0.005 in xy); the chart's light given as measured; beside it, "
          "one bracket set with the light stated as D65", file=sys.stderr)
    for name, r in probe["regions"].items():
        one = probe.get("one_set", {}).get("regions", {}).get(name)
        beside = "" if one is None else f"  (one set: {one['luminance_ratio']:.3f}, {one['dxy']:.4f})"
        print(f"  {name:<12} luminance {r['luminance_ratio']:.3f} of the truth, xy ({r['xy'][0]:.4f}, {r['xy'][1]:.4f}) "
              f"vs ({r['true_xy'][0]:.4f}, {r['true_xy'][1]:.4f}), {r['dxy']:.4f} apart{beside}", file=sys.stderr)
    renders = {}
    for name, env in (("probe", out / "probe.exr"), ("sky", SKY)):
        image = f"hawk-{name}.png"
        secs = render_lit_hawk(base, env, out / image, default_hawk_triangles=default_hawk_triangles)
        renders[name] = {"image": image, "environment": "probe.exr" if name == "probe" else SKY,
                         "seconds": round(secs, 2)}
        print(f"{source} under the {'light probe' if name == 'probe' else 'daylight sky (' + SKY + ')'}: "
              f"{base.size[0]} x {base.size[1]} {base.preset}, {secs:.1f} s -> {out / image}", file=sys.stderr)
    added = sum(s.values()) + sum(r["seconds"] for r in renders.values())
    print(f"measured light: {added:.1f} s added to the demo", file=sys.stderr)
    return {**probe, "hawk": source, "renders": renders, "seconds_total": round(added, 2)}
