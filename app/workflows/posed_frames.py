"""Every RAW frame of a processed scan posed on its mesh, projected, and checked against the photo.

:func:`project_session` is what ``kogei project``, ``kogei process`` (after
meshing, when the session has a camera calibration), the batch and the demo
call.  For each RAW frame of a registered pass it computes the camera's pose
relative to the mesh (the chain ``room_to_camera @ Rz(theta) @ inv(T_p)`` of
:mod:`processing.appearance.frame_poses`: the camera calibration, the frame's
table angle, the pass's registered pose), decodes the frame, normalises it with
the pass's colour chart, and writes into ``products/``:

* ``frame-poses.json`` — every frame's intrinsics, pose and lamps in the mesh
  frame (:class:`processing.appearance.frame_poses.FramePose`);
* ``observations.npz`` — for every vertex the frames that see it, with the
  signal, its noise, clipping and the geometry
  (:func:`processing.appearance.observations.read_observations` reads it);
* ``projection-report.json`` — per frame the silhouette IoU of the projected
  mesh against the object's outline in the photo, the mean boundary offset
  (px), the vertices seen; and an overlay image per frame
  (``overlays/<frame>.png``: the photo with the mesh's outline drawn on it).

The signal is linear camera RGB divided per channel by the pass's chart
gains (the neutral patches' camera RGB against their reflectance), i.e. camera
RGB relative to a white diffuser lit like the chart; without a chart frame it is
the raw camera RGB, and the report says so.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from app.errors import UsageError
from app.session_paths import check_destinations, check_not_symlink
from app.workflows.station_calibration import (
    CLIP_LEVEL,
    decode_frame,
    frame_records,
    session_camera_calibration,
    session_lamp_calibration,
)
from processing.common.files import JSONFileError, parse_json

__all__ = ["project_session", "frame_outline", "posed_frame_names", "calibrated_images", "noise_model", "session_mesh", "checked_product", "read_frame_poses", "FRAME_POSES", "OBSERVATIONS", "PROJECTION_REPORT", "OVERLAYS", "MIN_IOU", "MAX_MESH_COORD_MM"]

FRAME_POSES = "products/frame-poses.json"
OBSERVATIONS = "products/observations.npz"
PROJECTION_REPORT = "products/projection-report.json"
OVERLAYS = "products/overlays"
#: A frame whose silhouette IoU is below this is flagged in the report (the geometry does not line up).
MIN_IOU = 0.95


def _pass_poses(root: Path, manifest: dict[str, Any]) -> dict[int, np.ndarray]:
    """Registered pass poses (pass number -> 4 x 4) from the session's process report."""
    from app.session_paths import MAX_JSON_BYTES, read_confined_bytes

    ref = (manifest.get("products") or {}).get("process_report")
    if not isinstance(ref, dict):
        raise UsageError(f"session {root} is not processed yet (no products.process_report); run "
                         f"'kogei process {root}' first")
    try:       # a JSONFileError is a ValueError
        report = parse_json(read_confined_bytes(root, ref.get("file"), "products.process_report.file",
                                                MAX_JSON_BYTES), "products.process_report", "run kogei process again")
    except (OSError, ValueError) as exc:
        raise UsageError(f"session {root}: its process report is unreadable ({exc}); run kogei process again") \
            from None
    entries = report.get("passes") if isinstance(report, dict) else None
    if not isinstance(entries, list):
        raise UsageError(f"session {root}: its process report has no list of passes; run 'kogei process {root}' "
                         "again")
    poses = {}
    for entry in entries:
        if not (isinstance(entry, dict) and entry.get("registered") is True and isinstance(entry.get("pose"), list)):
            continue
        p = entry.get("pass")
        try:
            m = np.asarray(entry["pose"], dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if isinstance(p, int) and not isinstance(p, bool) and p >= 1 and m.shape == (4, 4) and np.all(np.isfinite(m)):
            poses[p] = m
    if not poses:
        raise UsageError(f"session {root}: no registered pass with a valid pose in the process report; run "
                         f"'kogei process {root}' (it registers the passes) again")
    return poses


def _chart_gains(root: Path, manifest: dict[str, Any], note: Callable[[str], None]) -> dict[int, np.ndarray]:
    """Per pass: camera RGB -> relative-to-white gains from the pass's chart frame's neutral patches."""
    from app.session_paths import confined_file
    from app.workflows.chart import measure_chart

    gains = {}
    for cid, rec in (manifest.get("captures") or {}).items():
        if not isinstance(rec, dict) or rec.get("kind") != "chart" or rec.get("status") != "done":
            continue
        p = int(rec.get("pass") or 0)
        if p in gains:
            continue
        try:
            m = measure_chart(confined_file(root, rec.get("file"), f"captures.{cid}.file"), mode="demosaic")
        except UsageError as exc:
            note(f"pass {p}: chart not measured ({exc}); its frames keep raw camera RGB")
            continue
        gains[p] = _neutral_gains(m)
    return gains


def _neutral_gains(m: Any) -> np.ndarray:
    """Per-channel gains mapping the neutral row's camera RGB to its luminance factor Y (least squares).

    The classic 24-patch chart's last row (white to black) is neutral; its
    reference Y comes from the chart's reference L*.
    """
    from processing.camera.chart_layout import reference_lab

    lab = reference_lab("classic24")
    y = np.where(lab[:, 0] > 8.0, ((lab[:, 0] + 16.0) / 116.0) ** 3, lab[:, 0] / 903.3)
    neutral = np.zeros(len(lab), dtype=bool)
    neutral[18:24] = True
    neutral &= m.usable
    rgb = m.mean[neutral]
    return np.array([np.dot(rgb[:, c], y[neutral]) / max(np.dot(rgb[:, c], rgb[:, c]), 1e-12) for c in range(3)])


class _Images(Sequence):
    """The frames' calibrated images, decoded one at a time as :func:`observe` asks for them."""

    def __init__(self, root: Path, frames: list[tuple[str, dict[str, Any]]], gains: dict[int, np.ndarray],
                 mode: str) -> None:
        self.root, self.frames, self.gains, self.mode = root, frames, gains, mode

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, k: Any) -> Any:
        cid, rec = self.frames[k]
        img = decode_frame(self.root, cid, rec, self.mode)
        g = self.gains.get(int(rec.get("pass") or 0))
        rgb = img.rgb if g is None else img.rgb * g.astype(np.float32)
        return rgb


def calibrated_images(root: Path, manifest: dict[str, Any], frames: list[tuple[str, dict[str, Any]]], mode: str,
                      note: Callable[[str], None] | None = None) -> Sequence:
    """The frames' chart-normalised linear camera RGB, decoded one at a time (a lazy sequence).

    Each pass's frames are divided per channel by its chart's neutral gains, as the observations are.
    """
    return _Images(root, frames, _chart_gains(root, manifest, note or (lambda text: None)), mode)


def session_mesh(root: Path, manifest: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(vertices, triangles, vertex_normals)`` of the session's ``products/mesh.ply`` (vertex order kept)."""
    return _mesh(root, manifest)


def read_frame_poses(root: Path, manifest: dict[str, Any]) -> list[Any]:
    """The :class:`~processing.appearance.frame_poses.FramePose` of every posed frame, in the file's order.

    Raises :class:`UsageError` when the session's frames are not posed or the file is damaged.
    """
    from processing.appearance.frame_poses import AppearanceError, FramePose

    doc = _frame_poses_doc(root, manifest)
    if doc is None:
        raise UsageError(f"session {root}: its frames are not posed on the mesh; run kogei project {root}")
    try:
        return [FramePose.from_dict(f) for f in doc.get("frames") or []]
    except (AppearanceError, TypeError, KeyError) as exc:
        raise UsageError(f"session {root}: {FRAME_POSES}: {exc}; run kogei project {root} again") from None


def _frame_poses(root: Path, frames: list[tuple[str, dict[str, Any]]], poses: dict[int, np.ndarray], calib: Any,
                 lamps: Any, mode: str) -> list[Any]:
    """A :class:`FramePose` per frame (the decoded size sets the intrinsics' binning)."""
    from processing.appearance.frame_poses import FramePose
    from processing.geometry.camera_calibration import CameraCalibrationError

    out = []
    for cid, rec in frames:
        img = decode_frame(root, cid, rec, mode)
        h, w = img.rgb.shape[:2]
        try:
            k, dist = calib.for_image_size(w, h)
        except CameraCalibrationError as exc:
            raise UsageError(f"session {root}: {cid}: {exc}") from None
        p = int(rec["pass"])
        out.append(FramePose.from_chain(cid, p, calib.room_to_camera, float(rec["angle_deg"]), poses[p], k, dist,
                                        (w, h), [] if lamps is None else lamps.lamps))
    return out


def project_session(session_dir: str | Path, *, decode: str = "demosaic", max_view_deg: float = 75.0,
                    edge_margin_px: float = 2.0, message: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Pose every RAW frame of a processed, camera-calibrated session on its mesh and project it.

    Parameters
    ----------
    session_dir
        A scan session processed by ``kogei process`` with a camera calibration
        installed (``--camera-calibration``); a lamp calibration is optional
        (without it the observations carry no light directions).
    decode
        ``demosaic`` (full resolution) or ``bin2x2`` (a quarter of the pixels, faster).
    max_view_deg
        Largest angle between a vertex's normal and the view direction that counts as seen.
    edge_margin_px
        Observations this close to a silhouette or depth edge are left out (px).
    message
        Called with progress and warnings.

    Returns
    -------
    dict
        The projection report (also ``products/projection-report.json``).
    """
    from app.session import Session, SessionError

    note = message or (lambda text: None)
    if decode not in ("demosaic", "bin2x2"):
        raise UsageError(f"--decode must be demosaic or bin2x2, got {decode!r}")
    if not (math.isfinite(max_view_deg) and 0 < max_view_deg < 90):
        raise UsageError(f"--max-view-deg must be in (0, 90) degrees, got {max_view_deg!r}")
    if not (math.isfinite(edge_margin_px) and 0 <= edge_margin_px <= 50):
        raise UsageError(f"--edge-margin must be in [0, 50] px, got {edge_margin_px!r}")
    root = Path(session_dir)
    t0 = time.perf_counter()
    try:
        session = Session.open(root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    with session:
        check_destinations(root, (".incoming/observations.npz", FRAME_POSES, OBSERVATIONS, PROJECTION_REPORT, OVERLAYS))
        manifest = session.manifest
        calib = session_camera_calibration(root, manifest)
        if calib is None or calib.room_to_camera is None:
            raise UsageError(f"session {root} has no camera calibration tied to the turntable; run 'kogei calibrate "
                             "--camera BOARD_SESSION --scanner SPHERE_SESSION', then 'kogei process "
                             f"{root} --camera-calibration BOARD_SESSION'")
        lamps = session_lamp_calibration(root, manifest)
        if lamps is None:
            note("no lamp calibration: observations have no light directions (kogei calibrate --lamp ...)")
        poses = _pass_poses(root, manifest)
        frames = frame_records(root, manifest)
        left_out = sorted({int(r.get("pass") or 0) for _, r in frames} - set(poses))
        for p in left_out:
            note(f"pass {p} is not registered: its frames are not posed")
        frames = [(c, r) for c, r in frames if int(r.get("pass") or 0) in poses]
        if not frames:
            raise UsageError(f"session {root} has no RAW frames in a registered pass; nothing to project")
        note(f"posing {len(frames)} frame(s) on the mesh")
        report = _project(session, root, manifest, frames, poses, calib, lamps, decode, max_view_deg,
                          edge_margin_px, note)
        report["seconds"] = round(time.perf_counter() - t0, 3)
        _record(session, root, report)
    return report


def _project(session: Any, root: Path, manifest: dict[str, Any], frames: list[tuple[str, dict[str, Any]]],
             poses: dict[int, np.ndarray], calib: Any, lamps: Any, mode: str, max_view_deg: float,
             edge_margin_px: float, note: Callable[[str], None]) -> dict[str, Any]:
    """Frame poses, observations and silhouette checks written into ``products/``."""
    from processing.appearance.observations import observe, per_vertex_counts, write_observations

    mesh = _mesh(root, manifest)
    gains = _chart_gains(root, manifest, note)
    posed = _frame_poses(root, frames, poses, calib, lamps, mode)
    blob = json.dumps({"schema": "kogei.frame_poses", "version": 1, "decode": mode,
                       "camera_calibration": manifest.get("camera_calibration"),
                       "lamp_calibration": manifest.get("lamp_calibration"),
                       "frames": [f.to_dict() for f in posed]}, indent=1, allow_nan=False) + "\n"
    info = session.write_file(FRAME_POSES, blob.encode())
    session.update("products", {**(session.manifest.get("products") or {}),
                                "frame_poses": {"file": FRAME_POSES, "sha256": info.sha256, "bytes": info.bytes}})
    noise = noise_model(frames, gains)
    images = _Images(root, frames, gains, mode)
    obs = observe(posed, mesh, images, noise=noise, clip_level=_clip_levels(frames, gains),
                  max_view_deg=max_view_deg, edge_margin_px=edge_margin_px)
    tmp = check_not_symlink(root, ".incoming/observations.npz", "observations staging file")
    tmp.parent.mkdir(parents=True, exist_ok=True)
    write_observations(tmp, obs)
    check_not_symlink(root, OBSERVATIONS, "products.observations")
    obs_info = session.adopt_file(tmp, OBSERVATIONS)
    counts = per_vertex_counts(obs)
    checks = _silhouettes(session, root, frames, posed, mesh, mode, note)
    return {
        "session": str(root), "decode": mode, "frames": checks,
        "chart_calibrated_passes": sorted(gains), "lamps": [] if lamps is None else [lp.name for lp in lamps.lamps],
        "observations": {"file": OBSERVATIONS, "sha256": obs_info.sha256, "count": int(len(obs)),
                         "vertices": int(obs.n_vertices), "vertices_seen": int(np.count_nonzero(counts)),
                         "median_per_seen_vertex": float(np.median(counts[counts > 0])) if counts.any() else 0.0},
        "iou_min": min((c["iou"] for c in checks if c.get("iou") is not None), default=None),
        "offset_px_mean": _mean([c.get("offset_px") for c in checks]),
        "settings": {"max_view_deg": max_view_deg, "edge_margin_px": edge_margin_px, "min_iou": MIN_IOU},
    }


#: Largest coordinate (mm) of a session's mesh: an object on a turntable is well inside a metre.  A
#: coordinate beyond it (a damaged or foreign file, a mesh in other units) overflows the areas and
#: distances the materials are fitted with instead of failing.
MAX_MESH_COORD_MM = 1.0e6


def checked_product(root: Path, ref: Any, field: str, rerun: str) -> Path:
    """The session file a ``products`` record names, confined to the session and matching its size and SHA-256.

    Parameters
    ----------
    root
        The session folder.
    ref
        The manifest's record of the product (``file``, and optionally ``bytes`` and ``sha256``).
    field
        The record's place in the manifest, for messages (``products.mesh``).
    rerun
        The command that writes the product again, for messages.

    Returns
    -------
    Path
        The file's path.

    Raises
    ------
    UsageError
        The file is missing, or its size or checksum differs from the manifest's (truncated, edited,
        or replaced after it was written).
    """
    from app.session_paths import confined_file
    from processing.common.files import sha256_file

    rel = ref.get("file") if isinstance(ref, dict) else None
    try:
        path = confined_file(root, rel, f"{field}.file")
    except FileNotFoundError:
        raise UsageError(f"session {root}: {rel} is missing; run {rerun}") from None
    size = path.stat().st_size
    if isinstance(ref.get("bytes"), int) and size != ref["bytes"]:
        raise UsageError(f"session {root}: {rel} has {size} bytes, the manifest says {ref['bytes']} (truncated or "
                         f"replaced); run {rerun}")
    if isinstance(ref.get("sha256"), str) and sha256_file(path) != ref["sha256"]:
        raise UsageError(f"session {root}: {rel} does not match its checksum (edited or replaced); run {rerun}")
    return path


def _mesh(root: Path, manifest: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(vertices, triangles, vertex_normals)`` of ``products/mesh.ply``, vertex order kept.

    The file must match the manifest's checksum and pass the renderer's mesh checks (declared counts,
    finite vertices, faces in range, some area); zero-area triangles are left out.
    """
    import warnings

    from render.errors import MeshError, MeshWarning
    from render.meshio import load_mesh

    rerun = f"kogei process {root} again"
    path = checked_product(root, (manifest.get("products") or {}).get("mesh") or {}, "products.mesh", rerun)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MeshWarning)     # zero-area triangles left out, normals recomputed
            mesh = load_mesh(path)
    except MeshError as exc:
        raise UsageError(f"session {root}: {exc}; run {rerun}") from None
    reach = float(np.abs(mesh.vertices).max())
    if reach > MAX_MESH_COORD_MM:
        raise UsageError(f"session {root}: {path.name} has a vertex {reach:.3g} mm from the origin (more than "
                         f"{MAX_MESH_COORD_MM:.0e} mm: not a mesh of an object on the turntable); run {rerun}")
    return mesh.vertices, mesh.triangles, mesh.vertex_normals


def _mean(values: list[Any]) -> float | None:
    vals = [float(v) for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def _clip_levels(frames: list[tuple[str, dict[str, Any]]], gains: dict[int, np.ndarray]) -> np.ndarray:
    """Per frame, the signal at which it clips: :data:`CLIP_LEVEL` of the white level times the pass's chart gain.

    The signal is raw camera RGB (1.0 = the white level) times per-channel gains; one level per frame
    serves all channels, so the smallest gain sets it (a channel is never taken for unclipped when it is not).
    """
    return np.array([CLIP_LEVEL * float(np.min(gains[p])) if (p := int(rec.get("pass") or 0)) in gains else CLIP_LEVEL
                     for _, rec in frames])


def noise_model(frames: list[tuple[str, dict[str, Any]]], gains: dict[int, np.ndarray]) -> np.ndarray:
    """``(a, b)`` of ``sigma^2 = a + b * signal`` per frame, in the units of the signal observed.

    A nominal sensor, since the files do not carry the gain: a 14-bit sensor's typical read noise
    (2 DN) and a full well of 30 000 electrons at the white level, in raw units (1.0 = saturation).
    A frame whose pass has chart gains ``g`` (signal = g x raw) gets ``a g^2`` and ``b g`` with the
    mean of the three channels' gains (the model has one ``(a, b)`` for all channels).
    """
    a = (2.0 / 16383.0) ** 2
    b = 1.0 / 30000.0
    out = np.tile([a, b], (len(frames), 1))
    for k, (_, rec) in enumerate(frames):
        g = gains.get(int(rec.get("pass") or 0))
        if g is not None:
            m = float(np.mean(g))
            out[k] = (a * m * m, b * m)
    return out


def _silhouettes(session: Any, root: Path, frames: list[tuple[str, dict[str, Any]]], posed: list[Any], mesh: Any,
                 mode: str, note: Callable[[str], None]) -> list[dict[str, Any]]:
    """Per frame: silhouette IoU and boundary offset of the projected mesh vs the object, and an overlay PNG."""
    from processing.appearance.frame_poses import AppearanceError
    from processing.appearance.projection import raycasting_scene
    from processing.appearance.silhouette import mesh_mask, object_mask, outline_px, silhouette_check

    scene = raycasting_scene(*mesh[:2])
    out = []
    for (cid, rec), pose in zip(frames, posed):
        img = decode_frame(root, cid, rec, mode)
        entry: dict[str, Any] = {"frame": cid, "pass": int(rec["pass"]), "table_angle_deg": float(rec["angle_deg"]),
                                 "file": rec.get("file")}
        hit = mesh_mask(None, pose, scene=scene)
        try:
            entry.update(silhouette_check(hit, object_mask(img.rgb, name=cid)))
        except AppearanceError as exc:
            entry.update(iou=None, offset_px=None, problem=str(exc))
            note(f"{cid}: silhouette not checked ({exc})")
        if entry.get("iou") is not None and entry["iou"] < MIN_IOU:
            note(f"{cid}: the mesh's outline covers the photo's object with IoU {entry['iou']:.3f} < {MIN_IOU}: "
                 "check the camera calibration and the registration")
        entry["overlay"] = _overlay(session, cid, img, outline_px(hit))
        out.append(entry)
    return out


def _overlay(session: Any, cid: str, img: Any, outlines: list[np.ndarray]) -> str:
    """The frame's display preview with the mesh's outline drawn in cyan, written as a PNG product."""
    import cv2

    from processing.camera.raw_decode import preview_srgb8
    from processing.common.png import png_bytes

    rgb = np.ascontiguousarray(preview_srgb8(img))
    scale = 2 if max(rgb.shape[:2]) < 800 else 1
    if scale > 1:
        rgb = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    pts = [np.round((o + 0.5) * scale - 0.5).astype(np.int32).reshape(-1, 1, 2) for o in outlines]
    cv2.polylines(rgb, pts, True, (0, 255, 255), 2, cv2.LINE_AA)
    rel = f"{OVERLAYS}/{cid.replace('/', '_')}.png"
    session.write_file(rel, png_bytes(rgb, compress_level=3))     # one per frame: a third of the time
    return rel


def _record(session: Any, root: Path, report: dict[str, Any]) -> None:
    """Write the projection report and reference it and the observations from the manifest's products."""
    blob = (json.dumps(report, indent=1, allow_nan=False) + "\n").encode()
    info = session.write_file(PROJECTION_REPORT, blob)
    products = dict(session.manifest.get("products") or {})
    products["observations"] = {"file": OBSERVATIONS, "sha256": report["observations"]["sha256"]}
    products["projection_report"] = {"file": PROJECTION_REPORT, "sha256": info.sha256, "bytes": info.bytes}
    session.update("products", products)
    iou = report.get("iou_min")
    session.event("projected", f"{len(report['frames'])} frames, {report['observations']['count']} observations"
                               + ("" if iou is None else f", silhouette IoU >= {iou:.3f}"))


def _frame_poses_doc(root: Path, manifest: dict[str, Any]) -> dict[str, Any] | None:
    """``products/frame-poses.json`` (checksum checked), or None when the session's frames are not posed."""
    import hashlib

    from app.session_paths import MAX_JSON_BYTES, read_confined_bytes

    ref = (manifest.get("products") or {}).get("frame_poses")
    if not isinstance(ref, dict):
        return None
    blob = read_confined_bytes(root, ref.get("file"), "products.frame_poses.file", MAX_JSON_BYTES)
    if isinstance(ref.get("sha256"), str) and hashlib.sha256(blob).hexdigest() != ref["sha256"]:
        raise UsageError(f"session {root}: {ref.get('file')} does not match its checksum; run kogei project again")
    try:
        doc = parse_json(blob, root / str(ref.get("file")), f"run kogei project {root} again")
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    return doc if isinstance(doc, dict) else None


def posed_frame_names(session_dir: str | Path) -> list[str]:
    """Capture ids of the session's frames that are posed on the mesh (empty when none is)."""
    from app.session import Session

    root = Path(session_dir)
    doc = _frame_poses_doc(root, Session.read(root))
    return [] if doc is None else [str(f.get("name")) for f in doc.get("frames") or [] if isinstance(f, dict)]


def frame_outline(session_dir: str | Path, frame: str) -> dict[str, Any]:
    """The mesh's outline on one posed frame, for an overlay.

    Parameters
    ----------
    session_dir
        A projected session (``kogei project``).
    frame
        The frame's capture id (``p01/frame/03``) or its file name in the session.

    Returns
    -------
    dict
        ``outlines``: list of ``(N, 2)`` polylines in the frame's decoded pixels
        (``image_size``, sensor photosites when decoded with ``demosaic``);
        ``image_size``; ``iou`` and ``offset_px`` from the projection report (or None).
    """
    from app.session import Session
    from processing.appearance.frame_poses import AppearanceError, FramePose
    from processing.appearance.silhouette import mesh_mask, outline_px

    root = Path(session_dir)
    manifest = Session.read(root)
    doc = _frame_poses_doc(root, manifest)
    if doc is None:
        raise UsageError(f"session {root}: its frames are not posed on the mesh; run kogei project {root}")
    captures = manifest.get("captures") or {}
    cid = frame if frame in captures else next((k for k, r in captures.items() if isinstance(r, dict)
                                                and r.get("file") and Path(str(r["file"])).name == Path(frame).name),
                                               frame)
    entry = next((f for f in doc.get("frames") or [] if isinstance(f, dict) and f.get("name") == cid), None)
    if entry is None:
        raise UsageError(f"session {root}: frame {frame} is not posed (only the frames of registered passes are)")
    try:
        pose = FramePose.from_dict(entry)
    except AppearanceError as exc:
        raise UsageError(f"session {root}: {FRAME_POSES}: {exc}") from None
    hit = mesh_mask(_mesh(root, manifest), pose)
    check = {}
    rep = (manifest.get("products") or {}).get("projection_report")
    if isinstance(rep, dict):
        from app.session_paths import MAX_JSON_BYTES, read_confined_bytes

        try:
            doc_rep = parse_json(read_confined_bytes(root, rep.get("file"), "products.projection_report.file",
                                                     MAX_JSON_BYTES), root / str(rep.get("file")),
                                 f"run kogei project {root} again")
        except JSONFileError as exc:
            raise UsageError(str(exc)) from None
        frames = doc_rep.get("frames") if isinstance(doc_rep, dict) else None
        check = next((f for f in frames or [] if isinstance(f, dict) and f.get("frame") == cid), {})
    return {"frame": cid, "outlines": outline_px(hit), "image_size": pose.image_size,
            "iou": check.get("iou"), "offset_px": check.get("offset_px")}
