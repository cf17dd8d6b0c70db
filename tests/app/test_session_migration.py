"""Sessions written by an older kogei (manifest version 1) open, migrate, and simply have no camera poses."""

from __future__ import annotations

import json

from app.session import MANIFEST, SCHEMA_VERSION, Session


def _v1_session(root):
    """A version-1 manifest as kogei wrote it before camera and lamp calibration existed."""
    root.mkdir()
    manifest = {
        "schema": "kogei.session", "version": 1, "created_utc": "2026-11-01T00:00:00Z",
        "updated_utc": "2026-11-01T00:00:00Z", "status": "complete", "object": {}, "devices": {},
        "settings": {}, "calibration": None,
        "plan": {"kind": "scan", "steps": 8, "passes": 1, "camera_angles_deg": [0, 90, 180, 270], "chart": True,
                 "lasers": [1], "camera": True, "chart_frames": 1},
        "passes": {}, "state": {}, "captures": {}, "history": [{"utc": "2026-11-01T00:00:00Z", "event": "created",
                                                                  "detail": ""}],
    }
    (root / MANIFEST).write_text(json.dumps(manifest))
    return root


def test_a_version_1_session_reads_as_the_current_version_without_camera_poses(tmp_path):
    m = Session.read(_v1_session(tmp_path / "old"))
    assert SCHEMA_VERSION == 2
    assert m["version"] == 2
    assert m["camera_calibration"] is None and m["lamp_calibration"] is None
    assert m["history"][-1]["event"] == "migrated" and "1 -> 2" in m["history"][-1]["detail"]
    # reading changes nothing on disk
    assert json.loads((tmp_path / "old" / MANIFEST).read_text())["version"] == 1


def test_opening_a_version_1_session_writes_the_migration_once(tmp_path):
    root = _v1_session(tmp_path / "old")
    with Session.open(root):
        pass
    on_disk = json.loads((root / MANIFEST).read_text())
    assert on_disk["version"] == 2 and on_disk["camera_calibration"] is None
    with Session.open(root):
        pass
    again = json.loads((root / MANIFEST).read_text())
    assert [h["event"] for h in again["history"]].count("migrated") == 1
