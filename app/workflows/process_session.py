"""``kogei process``: a captured session's profiles -> one registered, watertight mesh, with a report.

docs/processing.md, "Pipeline".  The stages, each a plain library call:

1. per complete pass: profiles + table angles + the session's scanner
   calibration -> points, normals and confidences in that pass's table frame
   (:func:`processing.geometry.scan_points.profiles_to_points`); an incomplete pass is
   skipped and reported (resume the capture to include it);
2. registration of the passes into pass 1's frame: global search, ICP, pose
   graph, every pair verified (:func:`processing.geometry.registration.register_passes`);
   a pass that cannot be registered is left out and reported, never merged
   with a wrong pose;
3. the merged, confidence-weighted cloud -> a watertight mesh with its holes
   filled and reported (:mod:`processing.geometry.surface`);
4. ``products/mesh.ply`` (binary PLY with vertex normals) and
   ``products/process-report.json`` are written atomically into the session
   and referenced, with checksums, from its manifest (``products``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from app.session_paths import UnsafeSessionPath, check_not_symlink, confined_file

__all__ = ["process_session", "incomplete_warnings", "PRESETS", "MIN_PASS_POINTS", "MIN_STEPS_HINT", "TURN_STEPS_HINT"]

PRESETS = ("draft", "standard", "reference")
#: Table steps per revolution below which a left-out pass is blamed on too sparse profiles (the simulated
#: hawk's passes register from 60 steps, 6 deg apart; at 36 two of three were left out).
MIN_STEPS_HINT = 60
#: Steps per revolution suggested when a nearly symmetric pair's turn about its axis was too uncertain to
#: verify: ``kogei capture``'s default.  The turn is held by the profiles that cross the distinguishing
#: feature; on the simulated vase (a 1 mm boss) 11 of 21 pairs registered at 72 steps, 20 of 21 at 200
#: (docs/processing.md, "Nearly symmetric shapes: the turn's uncertainty").
TURN_STEPS_HINT = 200
#: A pass with fewer usable points than this is skipped (it cannot be registered reliably).
MIN_PASS_POINTS = 500
REPORT = "products/process-report.json"
MESH = "products/mesh.ply"


def _observed_range(z_mm: np.ndarray) -> tuple[float, float]:
    """The pass's range of valid readings, widened 2% (the sensor's working range as used)."""
    finite = z_mm[np.isfinite(z_mm)]
    lo, hi = float(finite.min()), float(finite.max())
    pad = 0.02 * max(hi - lo, 1.0)
    return max(lo - pad, 0.0), hi + pad


#: Most passes a session's plan may name (``kogei capture`` plans far fewer).
MAX_PASSES = 1000


def _check_types(root: Path, manifest: dict[str, Any]) -> None:
    """A one-line error naming a manifest field the geometry reads that is not a record."""
    for key in ("plan", "captures", "passes"):
        if not isinstance(manifest.get(key), dict):
            raise UsageError(f"session {root}: session.json {key} is a {type(manifest.get(key)).__name__}, not a "
                             "record; the manifest is damaged")
    for key in ("captures", "passes"):
        bad = [k for k, v in manifest[key].items() if not isinstance(v, dict)]
        if bad:
            raise UsageError(f"session {root}: session.json {key} {bad[0]!r} is not a record; the manifest is damaged")


def _pass_count(root: Path, plan: dict[str, Any]) -> int:
    """``plan.passes`` checked to be a whole number 1..:data:`MAX_PASSES` (else a one-line error)."""
    n = plan.get("passes")
    if not (isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= MAX_PASSES):
        raise UsageError(f"session {root}: session.json plan.passes is {n!r}, not a whole number 1..{MAX_PASSES}; "
                         "the manifest is damaged")
    return n


def _pass_clouds(root: Path, manifest: dict[str, Any], cal: Any, note: Callable[[str], None]) -> list[dict[str, Any]]:
    from app.capture.runner import ProfilesFileError, load_pass_profiles
    from app.session import SessionError
    from processing.geometry.scan_points import profiles_to_points

    plan = manifest["plan"]
    out = []
    for p in range(1, _pass_count(root, plan) + 1):
        entry: dict[str, Any] = {"pass": p}
        if f"p{p:02d}/profiles" not in manifest["captures"]:
            held = sum(1 for k, r in manifest["captures"].items()
                       if r.get("kind") == "profile" and r.get("pass") == p)
            entry["skipped"] = (f"incomplete: {held} of {plan['steps']} profiles captured; resume the capture "
                                "to include this pass")
            note(f"pass {p}: {entry['skipped']}")
            out.append(entry)
            continue
        try:
            rec = manifest["captures"][f"p{p:02d}/profiles"]
            confined_file(root, rec.get("file") if isinstance(rec, dict) else None, f"captures.p{p:02d}/profiles.file")
            prof = load_pass_profiles(root, p)
        except UnsafeSessionPath:
            raise
        except (SessionError, OSError) as exc:
            # a damaged file's message says what to do; a missing or altered one is gathered again on resume
            entry["skipped"] = str(exc) if isinstance(exc, ProfilesFileError) else \
                f"{exc}; resume the capture to gather the pass's profiles again"
            note(f"pass {p}: {entry['skipped']}")
            out.append(entry)
            continue
        if not np.isfinite(prof["z_mm"]).any():
            entry["skipped"] = "no valid point in any profile (laser off? object out of the sensor's range?)"
            note(f"pass {p}: {entry['skipped']}")
            out.append(entry)
            continue
        t = time.perf_counter()
        sp = profiles_to_points(prof["x_mm"], prof["z_mm"], prof["angles_deg"], cal,
                                range_mm=_observed_range(prof["z_mm"]))
        keep = sp.confidence > 0
        entry.update({"points_total": int(sp.n_total), "invalid": int(sp.n_invalid),
                      "cropped_table": int(sp.n_cropped_table), "cropped_radius": int(sp.n_cropped_radius),
                      "points": int(keep.sum()), "seconds": round(time.perf_counter() - t, 3)})
        if keep.sum() < MIN_PASS_POINTS:
            entry["skipped"] = f"only {int(keep.sum())} usable points (fewer than {MIN_PASS_POINTS})"
            note(f"pass {p}: {entry['skipped']}")
        else:
            entry["cloud"] = (sp.points[keep], sp.normals[keep], sp.confidence[keep])
            angle_uncertain = manifest["passes"].get(str(p), {}).get("angle_uncertain_deg")
            if angle_uncertain:
                entry["angle_uncertain_deg"] = angle_uncertain
                note(f"pass {p}: its profiles after an interrupted move may be turned by up to "
                     f"{angle_uncertain:g} deg against those before it (a session captured before passes were "
                     "taken again in one table frame); registration places the pass as one whole and cannot "
                     "undo that: capture the pass again if the mesh shows a seam")
        out.append(entry)
    return out


def process_session(session_dir: str | Path, *, preset: str = "standard", calibration: str | Path | None = None,
                    camera_calibration: str | Path | None = None, lamp_calibration: str | Path | None = None,
                    project: bool = True, message: Callable[[str], None] | None = None,
                    picks: dict[tuple[int, int], tuple[Any, Any]] | None = None) -> dict[str, Any]:
    """Process a captured session into ``products/mesh.ply`` and ``products/process-report.json``.

    Parameters
    ----------
    session_dir
        A session captured with a ``scan`` plan.
    preset
        ``draft``, ``standard`` or ``reference`` (registration and surface
        settings; docs/BENCHMARKS.md gives each one's time and error).
    calibration
        A calibrated session folder or a calibration JSON file to install
        into the session first; default: the session's own.
    camera_calibration, lamp_calibration
        A calibrated board / mirror-sphere session (or its JSON file) to
        install first (:mod:`app.workflows.station_calibration`).
    project
        After meshing, pose and project every RAW frame when the session has
        a camera calibration (:func:`app.workflows.posed_frames.project_session`);
        its report is under ``"projection"``.
    message
        Called with progress and warnings.
    picks
        Manual registration of pass pairs: ``{(a, b): (points_on_a, points_on_b)}``
        with pass numbers ``a < b`` (1-based) and three or more corresponding
        points (mm, each pass's table frame) picked on each
        (:func:`processing.geometry.registration.register_passes`).

    Returns
    -------
    dict
        The report (also written to ``products/process-report.json``).
    """
    from app.session import Session
    from app.workflows.calibration import install_calibration, load_calibration_source, session_calibration

    note = message or (lambda text: None)
    if preset not in PRESETS:
        raise UsageError(f"--preset must be one of {', '.join(PRESETS)}, got {preset!r}")
    root = Path(session_dir)
    t_all = time.perf_counter()
    session = Session.open(root)
    with session:
        manifest = session.manifest
        _check_types(root, manifest)
        if manifest["plan"].get("kind") != "scan":
            raise UsageError(f"session {root} is a {manifest['plan'].get('kind')!r} capture; only scan sessions "
                             "have profiles to mesh")
        if calibration is not None:
            install_calibration(session, {**load_calibration_source(calibration),
                                          "installed_from": str(Path(calibration).resolve())})
        _install_station(session, camera_calibration, lamp_calibration)
        cal = session_calibration(root, manifest)
        timings: dict[str, float] = {}
        t = time.perf_counter()
        passes = _pass_clouds(root, manifest, cal, note)
        timings["points"] = time.perf_counter() - t
        usable = [e for e in passes if "cloud" in e]
        if not usable:
            raise UsageError(f"session {root}: no pass has usable points ({'; '.join(e.get('skipped', '') for e in passes)})")
        note(f"registering {len(usable)} pass(es) ({', '.join(str(e['points']) for e in usable)} points)")
        t = time.perf_counter()
        colours = _pass_colours(root, manifest, usable, note)
        timings["colours"] = time.perf_counter() - t
        t = time.perf_counter()
        reg = _register(root, usable, preset, picks, colours)
        timings["registration"] = time.perf_counter() - t
        _note_poses(usable, reg, note)
        points, normals, confidence = _merged(usable, reg)
        note(f"meshing {len(points)} points")
        t = time.perf_counter()
        surf = _surface(root, points, normals, confidence, preset)
        timings["surface"] = time.perf_counter() - t
        mesh_info = _adopt_mesh(session, root, surf)
        timings["total"] = time.perf_counter() - t_all
        report = _report(root, preset, manifest, passes, reg, surf, mesh_info, timings)
        report["warnings"] = incomplete_warnings(report, manifest.get("plan") or {})
        report["complete"] = not report["warnings"]
        for text in report["warnings"]:
            note(f"INCOMPLETE: {text}")
        _record_products(session, manifest, preset, report, passes, surf, mesh_info)
        posed = bool(session.manifest.get("camera_calibration"))
    if project and posed:
        from app.workflows.posed_frames import project_session

        report["projection"] = project_session(root, message=note)
    elif project:
        note("no camera calibration: the RAW frames are not posed on the mesh (kogei calibrate --camera ..., then "
             "kogei process --camera-calibration BOARD_SESSION)")
    return report


def _install_station(session: Any, camera: str | Path | None, lamps: str | Path | None) -> None:
    """Install a camera and/or lamp calibration (from a calibrated session or its JSON) into ``session``."""
    from app.workflows.station_calibration import (
        install_station_calibration,
        load_station_source,
        parse_station_calibration,
    )

    for key, source in (("camera_calibration", camera), ("lamp_calibration", lamps)):
        if source is None:
            continue
        data = load_station_source(source, key)
        parse_station_calibration(key, data, f"--{key.replace('_', '-')} {source}")
        install_station_calibration(session, key, {**data, "installed_from": str(Path(source).resolve())})


def _pass_colours(root: Path, manifest: dict[str, Any], usable: list[dict[str, Any]],
                  note: Callable[[str], None]) -> list[Any] | None:
    """Each usable pass's points coloured from its own RAW frames, or None without a camera calibration.

    A pass's cloud is in its table frame, so its frames are posed with the
    pass pose the identity (the camera calibration and each frame's table
    angle) and every point takes the colour of the frame that sees it most
    frontally (:func:`processing.geometry.registration.photo_consistency.colour_points`);
    the registration uses the colours only where the shape leaves a turn
    about an axis of revolution free.  Frames are decoded at full size and
    normalised by the pass's chart, as the projection does.
    """
    from app.workflows.posed_frames import calibrated_images
    from app.workflows.station_calibration import frame_records, session_camera_calibration, session_lamp_calibration
    from processing.appearance.frame_poses import FramePose
    from processing.geometry.camera_calibration import CameraCalibrationError
    from processing.geometry.registration.photo_consistency import colour_points

    calib = session_camera_calibration(root, manifest)
    if calib is None or calib.room_to_camera is None:
        return None
    lamps = session_lamp_calibration(root, manifest)
    frames = frame_records(root, manifest, passes={int(e["pass"]) for e in usable})
    if not frames:
        return None
    note(f"colouring {len(usable)} pass(es) from {len(frames)} posed frame(s)")
    images = calibrated_images(root, manifest, frames, "demosaic", note)
    out: list[Any] = []
    for e in usable:
        posed, imgs = [], []
        for k, (cid, rec) in enumerate(frames):
            if int(rec["pass"]) != int(e["pass"]):
                continue
            img = images[k]
            h, w = img.shape[:2]
            try:
                k_mat, dist = calib.for_image_size(w, h)
            except CameraCalibrationError as exc:
                raise UsageError(f"session {root}: {cid}: {exc}") from None
            posed.append(FramePose.from_chain(cid, int(e["pass"]), calib.room_to_camera, float(rec["angle_deg"]),
                                              np.eye(4), k_mat, dist, (w, h), [] if lamps is None else lamps.lamps))
            imgs.append(img)
        cloud = e["cloud"]
        out.append(colour_points(cloud[0], cloud[1], posed, imgs) if posed else None)
        if posed:
            seen = float(np.mean(np.isfinite(out[-1].colours).all(axis=1)))
            e["coloured"] = round(seen, 4)
    return out


def _register(root: Path, usable: list[dict[str, Any]], preset: str,
              picks: dict[tuple[int, int], tuple[Any, Any]] | None, colours: list[Any] | None = None) -> Any:
    """Register the usable passes into pass 1's frame (picks name passes by number; colours per pass or None)."""
    from processing.geometry.registration import RegistrationError, register_passes

    names = [f"pass {e['pass']}" for e in usable]
    try:
        index_of = {e["pass"]: k for k, e in enumerate(usable)}
        unknown = [pair for pair in (picks or {}) if pair[0] not in index_of or pair[1] not in index_of]
        if unknown:
            raise UsageError(f"session {root}: picks name passes without usable points: {unknown}")
        return register_passes([e["cloud"][0] for e in usable], [e["cloud"][1] for e in usable],
                               preset=preset, names=names, colours=colours,
                               picks={(index_of[a], index_of[b]): v for (a, b), v in (picks or {}).items()})
    except RegistrationError as exc:
        raise UsageError(f"session {root}: registration: {exc}") from None


def _note_poses(usable: list[dict[str, Any]], reg: Any, note: Callable[[str], None]) -> None:
    """Record each pass's pose (or why it has none) in its entry."""
    for e, pose in zip(usable, reg.poses):
        e["registered"] = bool(pose.registered)
        e["pose"] = None if pose.transform is None else np.asarray(pose.transform).tolist()
        if not pose.registered:
            e["skipped"] = f"not registered: {pose.reason}"
            note(f"pass {e['pass']}: {e['skipped']} (left out of the mesh; use the manual 3-point registration)")


def _merged(usable: list[dict[str, Any]], reg: Any) -> tuple[Any, Any, Any]:
    """Points, normals and confidences of the registered passes in pass 1's frame."""
    from processing.geometry.registration import merge_passes

    points, normals, index = merge_passes([e["cloud"][0] for e in usable], reg, [e["cloud"][1] for e in usable])
    confidence = np.concatenate([e["cloud"][2] for e, pose in zip(usable, reg.poses) if pose.registered])
    return points, normals, confidence


def _surface(root: Path, points: Any, normals: Any, confidence: Any, preset: str) -> Any:
    """The merged cloud meshed into a watertight surface."""
    from processing.geometry.surface import SurfaceError, reconstruct_surface

    try:
        # the merged cloud is in pass 1's table frame: its cropped underside is closed on the table top
        return reconstruct_surface(points, normals, confidence, preset=preset, table_z_mm=0.0)
    except SurfaceError as exc:
        raise UsageError(f"session {root}: surface: {exc}") from None


def _adopt_mesh(session: Any, root: Path, surf: Any) -> Any:
    """Write the mesh as binary PLY and adopt it into the session as ``products/mesh.ply``."""
    from processing.geometry.mesh_ply import write_mesh_ply

    tmp = check_not_symlink(root, ".incoming/mesh.ply", "mesh staging file")
    check_not_symlink(root, MESH, "products.mesh")
    try:
        tmp.parent.mkdir(parents=True, exist_ok=True)
        write_mesh_ply(tmp, surf.vertices, surf.triangles, surf.vertex_normals)
    except OSError as exc:                          # a full disk or a read-only folder: one line, resumable
        from app.session import disk_error

        raise disk_error(root, f"write the mesh {MESH}", exc) from None
    return session.adopt_file(tmp, MESH)


def incomplete_warnings(report: dict[str, Any], plan: dict[str, Any]) -> list[str]:
    """Why a processed session is a partial result, each with what to capture or do; empty when complete.

    A pass left out of the mesh (skipped or not registered) or a mesh that is not watertight makes the
    result partial: ``kogei process`` then exits 1 and the report and the manifest say so.

    Examples
    --------
    >>> rep = {"passes": [{"pass": 1, "registered": True}, {"pass": 2, "skipped": "not registered: far"}],
    ...        "mesh": {"watertight": True}}
    >>> incomplete_warnings(rep, {"steps": 36})[0][:60]
    '1 of 2 passes left out of the mesh (pass 2: not registered: '
    """
    warnings: list[str] = []
    left_out = [p for p in report["passes"] if not p.get("registered")]
    if left_out:
        n = len(report["passes"])
        steps = plan.get("steps")
        advice = (f"capture again with at least {MIN_STEPS_HINT} steps per revolution (this session has {steps}); "
                  if isinstance(steps, int) and steps < MIN_STEPS_HINT else "")
        if not advice and isinstance(steps, int) and steps < TURN_STEPS_HINT and _turn_uncertain(report):
            advice = (f"capture again with at least {TURN_STEPS_HINT} steps per revolution (this session has "
                      f"{steps}): a nearly symmetric object's turn about its axis is held by the profiles that cross "
                      "its distinguishing feature; ")
        if _turn_uncertain(report, by="colour"):
            advice += ("photograph the object with more pixels across its decoration (the camera nearer or a longer "
                       "lens): its colours decided a turn about the symmetry axis, and a photo places a colour border "
                       "only to within its pixel; ")
        warnings.append(
            f"{len(left_out)} of {n} passes left out of the mesh ("
            + "; ".join(f"pass {p['pass']}: {str(p.get('skipped', 'not registered')).split(' (')[0]}"
                        for p in left_out)
            + f"); {advice}resume an incomplete pass with kogei capture --resume, re-place the object so each "
              "placement overlaps another by about a third, or register by hand (kogei gui, Processing tab, "
              "'Manual 3-point registration'; docs/processing.md)")
    if not report["mesh"]["watertight"]:
        warnings.append("the mesh is not watertight: parts of the object were seen in no registered pass; "
                        "capture more placements (--passes) that show the missing sides, or register the "
                        "left-out passes")
    return warnings


def _turn_uncertain(report: dict[str, Any], by: str | None = None) -> bool:
    """Whether a pair of the report's registration was refused because its turn about a symmetry axis was uncertain.

    Such a pair alone is refused with a stated bound on its turn (``turn_uncertainty_deg``; None for the others).
    With ``by`` ("shape" or "colour"), only a pair whose turn that evidence decided (``decided_by``) counts.
    """
    pairs = (report.get("registration") or {}).get("pairs") or []
    return any(isinstance(p, dict) and not p.get("verified") and isinstance(p.get("turn_uncertainty_deg"), (int, float))
               and (by is None or p.get("decided_by") == by) for p in pairs)


def _report(root: Path, preset: str, manifest: dict[str, Any], passes: list[dict[str, Any]], reg: Any, surf: Any,
            mesh_info: Any, timings: dict[str, float]) -> dict[str, Any]:
    """The process report (``products/process-report.json``)."""
    return {
        "session": str(root),
        "preset": preset,
        "calibration": manifest.get("calibration"),
        "passes": [{k: v for k, v in e.items() if k != "cloud"} for e in passes],
        "registration": {
            "all_registered": reg.all_registered,
            "pairs": [pr.as_dict() for pr in reg.pairs],
            "consistency": None if reg.consistency is None else {
                "max_rotation_deg": reg.consistency.max_rotation_deg,
                "max_displacement_mm": reg.consistency.max_displacement_mm,
            },
            "seconds": reg.seconds,
        },
        "surface": surf.summary(),
        "mesh": {"file": MESH, "sha256": mesh_info.sha256, "vertices": int(len(surf.vertices)),
                 "triangles": int(len(surf.triangles)), "watertight": bool(surf.watertight)},
        "timings_s": {k: round(v, 3) for k, v in timings.items()},
    }


def _record_products(session: Any, manifest: dict[str, Any], preset: str, report: dict[str, Any],
                     passes: list[dict[str, Any]], surf: Any, mesh_info: Any) -> None:
    """Write the report into the session and reference it and the mesh from the manifest's products."""
    blob = (json.dumps(report, indent=1, default=_json_default, allow_nan=False) + "\n").encode()
    rep_info = session.write_file(REPORT, blob)
    products = dict(manifest.get("products") or {})
    products["mesh"] = {"file": MESH, "sha256": mesh_info.sha256, "bytes": mesh_info.bytes, "preset": preset,
                        "complete": report["complete"], "warnings": report["warnings"]}
    products["process_report"] = {"file": REPORT, "sha256": rep_info.sha256, "bytes": rep_info.bytes}
    session.update("products", products)
    session.event("processed", f"{preset}: mesh {len(surf.triangles)} triangles, "
                               f"{sum(1 for e in passes if e.get('registered'))} of {len(passes)} passes"
                               + ("" if report["complete"] else "; INCOMPLETE: " + "; ".join(report["warnings"])))


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON data")
