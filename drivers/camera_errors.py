"""Errors of the camera drivers (:mod:`drivers.camera_gphoto2`, :mod:`drivers.camera_hotfolder`).

Every error says which executable or folder was involved and what to do
next; the attributes carry the same facts for programs (the capture session
records them in its manifest).  They derive from :class:`CameraError`, so a
caller can catch all camera failures at once.

Examples
--------
>>> err = CameraNotFoundError("gphoto2 found no camera", executable="gphoto2")
>>> isinstance(err, CameraError), err.executable
(True, 'gphoto2')
"""

from __future__ import annotations

__all__ = [
    "CameraError",
    "CameraConfigError",
    "CameraNotFoundError",
    "CameraBusyError",
    "CameraTimeoutError",
    "CameraCommandError",
    "CameraOutputMissingError",
    "CameraBadFrameError",
    "CameraFileExistsError",
    "CameraTransferError",
]


class CameraError(RuntimeError):
    """Base class of camera failures.

    Parameters
    ----------
    message
        What happened and what to do.
    executable
        The command line tool involved (gphoto2 driver), if any.
    folder
        The folder involved (hot folder or destination), if any.
    stderr
        An excerpt of the tool's error output, if any.
    """

    def __init__(self, message: str, *, executable: str | None = None, folder: str | None = None,
                 stderr: str | None = None) -> None:
        super().__init__(message)
        self.executable = executable
        self.folder = folder
        self.stderr = stderr


class CameraConfigError(CameraError, ValueError):
    """The driver is configured wrongly: executable missing, folder missing, bad name or pattern."""


class CameraNotFoundError(CameraError):
    """gphoto2 found no camera (``*** Error: No camera found. ***``)."""


class CameraBusyError(CameraError):
    """The camera is claimed by another program or still busy (``Could not claim the USB device``, -110)."""


class CameraTimeoutError(CameraError):
    """The capture did not finish (gphoto2) or no stable new file appeared (hot folder) in time."""


class CameraCommandError(CameraError):
    """gphoto2 exited with a non-zero status for another reason.

    ``returncode`` holds the exit status.
    """

    def __init__(self, message: str, *, returncode: int, **kwargs: str | None) -> None:
        super().__init__(message, **kwargs)
        self.returncode = returncode


class CameraOutputMissingError(CameraError):
    """The capture reported success but no RAW file was downloaded."""


class CameraBadFrameError(CameraOutputMissingError):
    """A downloaded frame is not the RAW format its file name claims (junk, a text file, a JPEG)."""


class CameraFileExistsError(CameraError, FileExistsError):
    """The destination file of a capture already exists; it is never overwritten."""


class CameraTransferError(CameraError, OSError):
    """Moving the RAW file into the destination failed; the source file is kept."""
