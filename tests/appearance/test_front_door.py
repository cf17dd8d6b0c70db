"""The package's front door is light: importing it loads neither Open3D nor OpenCV; lazy names resolve."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_front_door_imports_nothing_heavy():
    code = ("import sys, processing.appearance as a; print('open3d' in sys.modules, 'cv2' in sys.modules); "
            "print(a.visible_vertices.__module__, a.FramePose.__module__)")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert out.stdout.split("\n")[:2] == ["False False",
                                          "processing.appearance.visibility processing.appearance.frame_poses"]
