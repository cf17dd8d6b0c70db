"""Small helpers shared by every layer above the drivers.

Modules
-------
:mod:`processing.common.files`
    Atomic writes (temporary file, ``fsync``, rename, ``fsync`` of the folder),
    JSON written and read safely, and checksums.
:mod:`processing.common.npz`
    Reading an untrusted ``.npz`` (every member's header checked before anything is allocated).
:mod:`processing.common.png`
    PNG encoding of 8-bit images.
:mod:`processing.common.rotation`
    Rotation matrices (about the axes, about any axis, from Euler angles).
"""

from __future__ import annotations

import importlib
from typing import Any

#: Where each re-exported name lives.  They are imported on first use (PEP 562), so that a program
#: needing only the file helpers -- the simulator's fake ``gphoto2``, started once per photograph --
#: does not import NumPy through the PNG and rotation modules.
_HOMES = {
    "atomic_path": "files", "atomic_write_bytes": "files", "atomic_write_json": "files",
    "atomic_write_text": "files", "fsync_dir": "files", "sha256_file": "files",
    "JSONFileError": "files", "parse_json": "files",
    "read_npz": "npz",
    "png_bytes": "png",
    "rotation_about": "rotation", "rotation_xyz_deg": "rotation", "rotation_z": "rotation",
    "rotation_z_deg": "rotation",
}

__all__ = [
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "fsync_dir",
    "sha256_file",
    "JSONFileError",
    "parse_json",
    "read_npz",
    "png_bytes",
    "rotation_about",
    "rotation_xyz_deg",
    "rotation_z",
    "rotation_z_deg",
]


def __getattr__(name: str) -> Any:
    """The re-exported helper ``name``, imported from its module on first use."""
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'processing.common' has no attribute {name!r}")
    return getattr(importlib.import_module(f"processing.common.{home}"), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
