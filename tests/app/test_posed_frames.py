"""`kogei project` (and `kogei report` on old sessions) on bad input: one-line errors that name the frame,
file or size and say what to do; and a small session posed with the simulation's true camera.

The sessions are small and partly synthetic: RAW frames of the reference sphere from the simulated
station (a camera-only capture), a "processed" state made of a process report registering pass 1 at
the identity and the sphere's exact mesh, and a camera calibration made from the simulation's truth.
The full chain (capture, calibrate, process, project) is `tests/app/test_demo.py`'s.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.capture.devices import build_devices
from app.capture.runner import CaptureHooks, CapturePlan, run_capture
from app.cli import main
from app.session import MANIFEST, Session
from app.workflows.posed_frames import frame_outline, posed_frame_names
from app.workflows.station_calibration import install_station_calibration
from mocks.station import SimulatedStation
from mocks.world import World
from processing.geometry.camera_calibration import CameraCalibration
from tests.app.cli_checks import fails_with_one_line

RADIUS_MM, OFFSET_MM = 20.0, 40.0
FULL = (960, 640)           # the calibrated size; frames are 240 x 160 (binning 4)


def _mesh_ply() -> bytes:
    """The reference sphere's mesh in pass 1's table frame (where the simulation placed it), as PLY bytes."""
    import tempfile

    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(RADIUS_MM, resolution=40)
    m.translate((OFFSET_MM, 0.0, RADIUS_MM))
    m.compute_vertex_normals()
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "mesh.ply"
        o3d.io.write_triangle_mesh(str(path), m)
        return path.read_bytes()


def _true_camera(size: tuple[int, int] = FULL) -> dict:
    """The simulated camera's truth as a camera calibration (calibrated at ``size``)."""
    world = World.calibration_sphere(RADIUS_MM, OFFSET_MM, width=FULL[0], height=FULL[1])
    k = world.camera_intrinsics()
    return CameraCalibration(size, k, np.zeros(5), np.eye(4), room_to_camera=world.room_to_camera()).to_dict()


def _processed(s: Session) -> None:
    """Mark a session processed: pass 1 registered at the identity, the sphere's mesh."""
    report = {"passes": [{"pass": 1, "registered": True, "pose": np.eye(4).tolist()}]}
    rep = s.write_file("products/process-report.json", json.dumps(report).encode())
    mesh = s.write_file("products/mesh.ply", _mesh_ply())
    s.update("products", {"process_report": {"file": rep.path, "sha256": rep.sha256},
                          "mesh": {"file": mesh.path, "sha256": mesh.sha256}})


@pytest.fixture(scope="module")
def sessions(tmp_path_factory):
    base = tmp_path_factory.mktemp("posed")
    raw = base / "raw"
    world = World.calibration_sphere(RADIUS_MM, OFFSET_MM, width=FULL[0] // 4, height=FULL[1] // 4, chart_first=False)
    plan = CapturePlan("camera-calibration", steps=3, passes=1)
    with SimulatedStation(world, root=base / "station", seed=4) as st:
        config = {"turntable": {"port": str(st.turntable_path)},
                  "camera": {"kind": "gphoto2", "executable": str(st.gphoto2_path)}}
        s = Session.create(raw, plan=plan.to_dict())
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()

    def make(name: str, *, processed: bool = True, camera: dict | None = None) -> Path:
        root = base / name
        shutil.copytree(raw, root)
        with Session.open(root) as s:
            if processed:
                _processed(s)
            if camera is not None:
                install_station_calibration(s, "camera_calibration", camera)
        return root

    make("unprocessed", processed=False, camera=_true_camera())
    make("no-camera")
    edited = make("edited", camera=_true_camera())
    data = json.loads((edited / "camera_calibration.json").read_text())
    data["K"][0][0] *= 1.01
    (edited / "camera_calibration.json").write_text(json.dumps(data))
    untied = make("untied")
    with Session.open(untied) as s:
        # install_station_calibration refuses an untied camera: write it as another tool might have
        info = s.write_file("camera_calibration.json", json.dumps({**_true_camera(), "room_to_camera": None}).encode())
        s.update("camera_calibration", {"path": info.path, "sha256": info.sha256})
    no_angle = make("no-angle", camera=_true_camera())
    manifest = json.loads((no_angle / MANIFEST).read_text())
    del manifest["captures"]["p01/frame/01"]["angle_deg"]
    (no_angle / MANIFEST).write_text(json.dumps(manifest))
    make("binning", camera=_true_camera((1000, 640)))
    make("good", camera=_true_camera())
    return base



def test_an_unprocessed_session(sessions, capsys):
    root = sessions / "unprocessed"
    _fails(["project", str(root)], capsys, sessions, "not processed", f"kogei process {root}")


@pytest.mark.parametrize("name", ["no-camera", "untied"])
def test_a_session_without_a_tied_camera_calibration(name, sessions, capsys):
    _fails(["project", str(sessions / name)], capsys, sessions, "no camera calibration",
           "kogei calibrate --camera", "--camera-calibration")


def test_an_edited_camera_calibration(sessions, capsys):
    _fails(["project", str(sessions / "edited")], capsys, sessions, "camera_calibration.json", "checksum",
           "--camera-calibration")


def test_a_frame_without_its_table_angle(sessions, capsys):
    _fails(["project", str(sessions / "no-angle")], capsys, sessions, "p01/frame/01", "table angle")


def test_frames_not_binned_from_the_calibrated_size(sessions, capsys):
    _fails(["project", str(sessions / "binning")], capsys, sessions, "240 x 160", "1000 x 640", "p01/frame/00")


def test_bad_settings(sessions, capsys):
    _fails(["project", str(sessions / "good"), "--max-view-deg", "95"], capsys, sessions, "--max-view-deg")
    _fails(["project", str(sessions / "good"), "--edge-margin", "nan"], capsys, sessions, "--edge-margin")
    _fails(["project", str(sessions / "nowhere")], capsys, sessions, "nowhere")


def test_outlines_before_projection_are_refused(sessions):
    from app.errors import UsageError

    assert posed_frame_names(sessions / "good") == []
    with pytest.raises(UsageError, match="kogei project"):
        frame_outline(sessions / "good", "p01/frame/00")


def test_the_true_camera_poses_the_frames_on_the_mesh(sessions, capsys):
    """With the simulation's camera and the sphere's exact mesh, the projected outline is the photo's."""
    root = sessions / "posed"
    shutil.copytree(sessions / "good", root)
    assert main(["project", str(root), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [f["frame"] for f in report["frames"]] == ["p01/frame/00", "p01/frame/01", "p01/frame/02"]
    # measured: IoU 0.995, mean boundary offset 0.07 px (240 x 160 frames)
    assert report["iou_min"] > 0.98 and report["offset_px_mean"] < 0.3
    doc = json.loads((root / "products" / "frame-poses.json").read_text())
    k = np.asarray(doc["frames"][0]["K"])
    # the truth at binning 4: fx = (960 / 2) / tan(12.5 deg) / 4, cx = (479.5 + 0.5) / 4 - 0.5
    assert k[0, 0] == pytest.approx(480.0 / np.tan(np.radians(12.5)) / 4, rel=1e-9)
    assert k[0, 2] == pytest.approx(119.5) and k[1, 2] == pytest.approx(79.5)
    # the chain room_to_camera @ Rz(theta) @ inv(T_1), T_1 = identity, against the simulation's camera
    from processing.common.rotation import rotation_z_deg

    truth = World.calibration_sphere(RADIUS_MM, OFFSET_MM).room_to_camera()
    for frame in doc["frames"]:
        rz = np.eye(4)
        rz[:3, :3] = rotation_z_deg(frame["table_angle_deg"])
        np.testing.assert_allclose(frame["mesh_to_camera"], truth @ rz, atol=1e-9)
    assert len({f["table_angle_deg"] for f in doc["frames"]}) == 3
    assert posed_frame_names(root) == ["p01/frame/00", "p01/frame/01", "p01/frame/02"]
    outline = frame_outline(root, "p01/frame/01")
    assert tuple(outline["image_size"]) == (240, 160) and len(outline["outlines"]) >= 1
    assert outline["iou"] == pytest.approx(report["frames"][1]["iou"])
    # a frame may be named by its file too
    file = json.loads((root / MANIFEST).read_text())["captures"]["p01/frame/01"]["file"]
    assert frame_outline(root, Path(file).name)["frame"] == "p01/frame/01"
    from app.errors import UsageError

    with pytest.raises(UsageError, match="p09/frame/00 is not posed"):
        frame_outline(root, "p09/frame/00")
    poses = root / "products" / "frame-poses.json"
    poses.write_text(poses.read_text().replace('"version": 1', '"version": 1 '))
    with pytest.raises(UsageError, match="frame-poses.json does not match its checksum; run kogei project again"):
        frame_outline(root, "p01/frame/01")


def test_a_damaged_raw_frame_is_named(sessions, capsys):
    root = sessions / "damaged"
    shutil.copytree(sessions / "good", root)
    rec = json.loads((root / MANIFEST).read_text())["captures"]["p01/frame/02"]
    with open(root / rec["file"], "ab") as f:
        f.write(b"\0")
    _fails(["project", str(root)], capsys, sessions, rec["file"], "p01/frame/02", "checksum", "kogei capture")


def test_a_version_1_session_processed_today_has_no_camera_poses_and_reports(tmp_path, capsys):
    """A session written by kogei before camera calibration existed: processed, reported, no poses."""
    from app.workflows.calibration import calibrate_session

    root = tmp_path / "old"
    plan = CapturePlan("scan", steps=36, passes=1, camera=True, chart=False, camera_angles_deg=(0.0, 180.0))
    world = World.calibration_sphere(25.0, 60.0, width=FULL[0] // 4, height=FULL[1] // 4, chart_first=False)
    with SimulatedStation(world, root=tmp_path / "station", seed=6, n_points=400) as st:
        config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)},
                  "camera": {"kind": "gphoto2", "executable": str(st.gphoto2_path)}}
        s = Session.create(root, plan=plan.to_dict())
        try:
            run_capture(s, plan, build_devices(config, s.root), CaptureHooks(before_pass=lambda p, n: st.place(p)))
        finally:
            s.close()
    calibrate_session(root, 25.0)               # the sphere is its own calibration scan
    manifest = json.loads((root / MANIFEST).read_text())
    assert any(r.get("kind") == "frame" for r in manifest["captures"].values())      # RAW frames to pose
    manifest["version"] = 1
    for key in ("camera_calibration", "lamp_calibration"):
        manifest.pop(key, None)
    for key in ("board", "sphere_radius_mm"):
        manifest["plan"].pop(key, None)
    (root / MANIFEST).write_text(json.dumps(manifest))

    from app.cli.process import EXIT_PARTIAL

    code = main(["process", str(root), "--preset", "draft"])
    err = capsys.readouterr().err
    assert code in (0, EXIT_PARTIAL), err                # one pass of a sphere may mesh open: reported, not failed
    assert "no camera calibration" in err
    manifest = Session.read(root)
    assert manifest["version"] == 2 and manifest["camera_calibration"] is None
    assert "frame_poses" not in manifest["products"] and "observations" not in manifest["products"]
    assert posed_frame_names(root) == []
    out = tmp_path / "report.html"
    assert main(["report", str(root), "--out", str(out)]) == 0, capsys.readouterr().err
    html = out.read_text()
    assert "Camera and lamp" in html and "no camera calibration" in html


def test_a_missing_raw_frame_is_named(sessions, capsys):
    root = sessions / "frame-missing"
    shutil.copytree(sessions / "good", root)
    rec = json.loads((root / MANIFEST).read_text())["captures"]["p01/frame/01"]
    (root / rec["file"]).unlink()
    _fails(["project", str(root)], capsys, sessions, rec["file"], "p01/frame/01", "missing", "kogei capture")


def test_a_missing_mesh_is_named(sessions, capsys):
    root = sessions / "mesh-missing"
    shutil.copytree(sessions / "good", root)
    (root / "products" / "mesh.ply").unlink()
    _fails(["project", str(root)], capsys, sessions, "products/mesh.ply", "missing", "kogei process")


@pytest.mark.parametrize("report", [[], "text", {"passes": "all"}, {"passes": [{"pass": "one", "registered": True,
                                                                              "pose": np.eye(4).tolist()}]},
                                    {"passes": [{"pass": 1, "registered": True, "pose": [[1, 0], [0, 1]]}]}])
def test_an_odd_process_report(report, sessions, capsys):
    """The process report is a session file like any other (untrusted): odd content is an error, not a traceback."""
    root = sessions / f"report-{len(list(sessions.glob('report-*')))}"
    shutil.copytree(sessions / "good", root)
    with Session.open(root) as s:
        info = s.write_file("products/process-report.json", json.dumps(report).encode())
        s.update("products", {**s.manifest["products"], "process_report": {"file": info.path, "sha256": info.sha256}})
    _fails(["project", str(root)], capsys, sessions, "process report", "kogei process")


@pytest.mark.parametrize("value", ["one", None, 2.5])
def test_an_odd_frame_pass(value, sessions, capsys):
    root = sessions / f"pass-{len(list(sessions.glob('pass-*')))}"
    shutil.copytree(sessions / "good", root)
    manifest = json.loads((root / MANIFEST).read_text())
    manifest["captures"]["p01/frame/01"]["pass"] = value
    (root / MANIFEST).write_text(json.dumps(manifest))
    _fails(["project", str(root)], capsys, sessions, "p01/frame/01", "pass", "session.json")


def test_an_edited_lamp_calibration(sessions, capsys):
    from processing.geometry.lamp_calibration import Lamp, LampCalibration

    root = sessions / "lamp-edited"
    shutil.copytree(sessions / "good", root)
    lamp = Lamp("key", "distant", direction=np.array([0.0, 0.0, 1.0]), covariance=np.eye(3) * 1e-6)
    with Session.open(root) as s:
        install_station_calibration(s, "lamp_calibration", LampCalibration([lamp], 20.0).to_dict())
    path = root / "lamp_calibration.json"
    path.write_text(path.read_text().replace('"key"', '"kez"'))
    _fails(["project", str(root)], capsys, sessions, "lamp_calibration.json", "checksum", "--lamp-calibration")


def test_the_noise_model_follows_the_chart_gain():
    """A signal scaled by g has its variance scaled by g^2: a -> a g^2 (read noise), b -> b g (shot noise)."""
    import numpy as np

    from app.workflows.posed_frames import noise_model

    frames = [("p01/frame/00", {"pass": 1}), ("p02/frame/00", {"pass": 2})]
    raw = noise_model(frames, {})
    scaled = noise_model(frames, {1: np.array([1.5, 2.0, 2.5])})
    signal = 0.3
    var_raw = raw[0, 0] + raw[0, 1] * signal          # variance of a raw value of 0.3
    var_scaled = scaled[0, 0] + scaled[0, 1] * (2.0 * signal)   # the same value times the mean gain 2
    assert var_scaled == pytest.approx(4.0 * var_raw, rel=1e-12)
    assert scaled[1].tolist() == raw[1].tolist()      # pass 2 has no chart: raw units


def _fails(argv: list[str], capsys, base: Path, *needles: str) -> str:
    return fails_with_one_line(argv, capsys, base, *needles, manifests_may_change=True)


def test_a_pass_is_coloured_from_its_own_posed_frames(sessions):
    # What `kogei process` gives the registration when the session has a camera calibration: the
    # pass's points (here the sphere's exact surface in pass 1's table frame, outward normals) coloured
    # from its frames posed with the pass pose the identity.  Against the simulation's camera: every
    # point that some frame shows facing its camera at more than cos 0.3 and more than 5 px inside the
    # sphere's true outline and the image's edge is coloured (the limits are cos 0.2 and 3 px, where the
    # lens mixes the colour with the background's; the margins keep the boundaries out), none that no
    # frame shows (within 2 px of the image) facing it at more than cos 0.1, and each coloured point's
    # camera is the true centre of one of the frames.
    from scipy.ndimage import distance_transform_edt

    from app.workflows.process_session import _pass_colours
    from processing.common.rotation import rotation_z_deg

    root = sessions / "good"
    manifest = json.loads((root / MANIFEST).read_text())
    k = np.arange(3000) + 0.5
    z = 1.0 - 2.0 * k / 3000
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    nrm = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], 1)
    pts = nrm * RADIUS_MM + [OFFSET_MM, 0.0, RADIUS_MM]
    entry = {"pass": 1, "cloud": (pts, nrm, np.ones(len(pts)))}
    (pc,) = _pass_colours(root, manifest, [entry], lambda text: None)
    world = World.calibration_sphere(RADIUS_MM, OFFSET_MM, width=FULL[0] // 4, height=FULL[1] // 4)
    k_mat, room_to_camera = world.camera_intrinsics(), world.room_to_camera()
    centres, shown = [], []
    for rec in manifest["captures"].values():
        if rec.get("kind") != "frame":
            continue
        rz = np.eye(4)
        rz[:3, :3] = rotation_z_deg(rec["angle_deg"])
        to_cam = room_to_camera @ rz
        centres.append(np.linalg.inv(to_cam)[:3, 3])
        x = pts @ to_cam[:3, :3].T + to_cam[:3, 3]
        uv = (x @ k_mat.T)[:, :2] / x[:, 2:]
        view = centres[-1] - pts
        cos = np.sum(view * nrm, axis=1) / np.linalg.norm(view, axis=1)
        rays = np.stack(np.meshgrid(np.arange(world.width) + 0.5, np.arange(world.height) + 0.5, [1.0]), -1)
        rays = rays.reshape(world.height, world.width, 3) @ np.linalg.inv(k_mat).T @ to_cam[:3, :3]
        rays /= np.linalg.norm(rays, axis=2, keepdims=True)
        off = np.array([OFFSET_MM, 0.0, RADIUS_MM]) - centres[-1]
        on_sphere = np.linalg.norm(off - (rays @ off)[..., None] * rays, axis=2) < RADIUS_MM
        clear_px = distance_transform_edt(np.pad(on_sphere, 1))[1:-1, 1:-1]   # to the outline or the edge
        ij = np.clip(np.floor(uv).astype(int), 0, [world.width - 1, world.height - 1])
        well_in = np.all((uv >= 0.0) & (uv <= [world.width - 1.0, world.height - 1.0]), axis=1)
        well_in &= clear_px[ij[:, 1], ij[:, 0]] > 5.0
        near = np.all((uv >= -2.0) & (uv <= [world.width + 1.0, world.height + 1.0]), axis=1)
        shown.append((np.where(well_in, cos, -1.0), np.where(near, cos, -1.0)))
    best_in = np.max([a for a, _ in shown], axis=0)
    best_near = np.max([b for _, b in shown], axis=0)
    seen = np.isfinite(pc.colours).all(axis=1)
    assert seen[best_in > 0.3].all() and not seen[best_near < 0.1].any()
    assert pc.lamp_dirs is None          # this session has no lamp calibration: only the view is checked
    nearest = np.min(np.linalg.norm(pc.camera_mm[seen][:, None, :] - np.array(centres)[None], axis=2), axis=1)
    assert nearest.max() < 1e-6
    assert entry["coloured"] == pytest.approx(seen.mean(), abs=1e-4)
