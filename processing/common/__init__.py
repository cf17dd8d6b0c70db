"""Small helpers shared by every layer above the drivers.

Modules
-------
:mod:`processing.common.files`
    Atomic writes (temporary file, ``fsync``, rename, ``fsync`` of the folder),
    JSON and checksums.
:mod:`processing.common.png`
    PNG encoding of 8-bit images.
:mod:`processing.common.rotation`
    Rotation matrices (about the axes, about any axis, from Euler angles).
"""

from processing.common.files import (
    atomic_path,
    atomic_write_bytes,
    atomic_write_json,
    atomic_write_text,
    fsync_dir,
    sha256_file,
)
from processing.common.png import png_bytes
from processing.common.rotation import rotation_about, rotation_xyz_deg, rotation_z, rotation_z_deg

__all__ = [
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_json",
    "atomic_write_text",
    "fsync_dir",
    "sha256_file",
    "png_bytes",
    "rotation_about",
    "rotation_xyz_deg",
    "rotation_z",
    "rotation_z_deg",
]
