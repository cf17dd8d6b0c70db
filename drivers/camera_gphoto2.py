"""Tethered RAW capture through the gphoto2 command line.

gphoto2 (libgphoto2's command-line front end, http://gphoto.org/doc/manual/)
fires the camera and downloads the new file with::

    gphoto2 [--set-config-value shutterspeed=T] --capture-image-and-download --filename PATTERN

(``T`` sets the frame's exposure first, for exposure brackets) where ``PATTERN`` may use gphoto2's codes (``%f`` the camera's file name
without extension, ``%C`` its extension, ``%n`` a running number, ``%%``).
:class:`Gphoto2Camera` runs it without a shell in a fresh private folder
inside the destination (so the download lands on the destination's
filesystem and nothing else is mistaken for it), with a timeout, finds the
RAW file among what was downloaded (a RAW+JPEG camera setting gives two
files), and renames it atomically to ``dest_dir/<name><ext>``.

Failures are mapped from gphoto2's messages to specific errors
(:mod:`drivers.camera_errors`):

==================================================  =========================
gphoto2 says                                        error
==================================================  =========================
``*** Error: No camera found. ***``                 CameraNotFoundError
``Could not claim the USB device``, ``-110``,       CameraBusyError
``I/O in progress``, ``Device or resource busy``
(no exit within ``timeout_s``)                      CameraTimeoutError
any other non-zero exit                             CameraCommandError
exit 0 but no RAW file downloaded                   CameraOutputMissingError
==================================================  =========================

Examples
--------
>>> parse_saved_files("New file is in location /capt0000.nef on the camera\\nSaving file as DSC_0001.nef\\n")
['DSC_0001.nef']
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

from drivers.camera_errors import (
    CameraBusyError,
    CameraCommandError,
    CameraConfigError,
    CameraNotFoundError,
    CameraOutputMissingError,
    CameraTimeoutError,
)
from drivers.camera_hotfolder import RAW_EXTENSIONS, check_capture_name, move_file_atomic, tiff_complete
from drivers.process import run_bounded

__all__ = [
    "Gphoto2Camera",
    "classify_gphoto2_error",
    "parse_saved_files",
    "DEFAULT_PATTERN",
]

#: Default ``--filename`` pattern: the camera's own name and extension.
DEFAULT_PATTERN = "%f.%C"

_NO_CAMERA = re.compile(r"no camera found|could not detect any camera", re.IGNORECASE)
_BUSY = re.compile(
    r"could not claim the usb device|\(-110\)|error -110|i/o in progress|device or resource busy|camera is busy",
    re.IGNORECASE,
)
_SAVED = re.compile(r"^Saving file as (.+?)\s*$", re.MULTILINE)
_EXCERPT = 600


def parse_saved_files(output: str) -> list[str]:
    """File names gphoto2 reported as saved (``Saving file as NAME`` lines), in order.

    Examples
    --------
    >>> parse_saved_files("Saving file as a.nef\\nSaving file as a.jpg\\n")
    ['a.nef', 'a.jpg']
    """
    return _SAVED.findall(output)


def classify_gphoto2_error(text: str) -> str | None:
    """``"no_camera"``, ``"busy"`` or None for gphoto2's error output ``text``.

    Examples
    --------
    >>> classify_gphoto2_error("*** Error: No camera found. ***")
    'no_camera'
    >>> classify_gphoto2_error("*** Error (-53: 'Could not claim the USB device') ***")
    'busy'
    """
    if _NO_CAMERA.search(text):
        return "no_camera"
    if _BUSY.search(text):
        return "busy"
    return None


def _excerpt(text: str) -> str:
    text = text.strip()
    return text if len(text) <= _EXCERPT else "..." + text[-_EXCERPT:]


class Gphoto2Camera:
    """A camera tethered over USB and driven by the ``gphoto2`` program.

    Parameters
    ----------
    dest_dir
        Folder the RAW frames are moved into (created if missing).
    executable
        The gphoto2 program: a name looked up on ``PATH`` or a path.
    filename_pattern
        gphoto2 ``--filename`` pattern for the download (file name only,
        no folders); the frame is renamed afterwards anyway.
    timeout_s
        Seconds allowed for one capture and download (> 0); long exposures
        need more.
    extensions
        File endings taken as RAW (case-insensitive).
    extra_args
        More gphoto2 arguments placed before the capture command (e.g.
        ``("--port", "usb:001,004")`` to pick one of several cameras).

    Examples
    --------
    >>> import tempfile
    >>> cam = Gphoto2Camera(tempfile.mkdtemp(), executable="gphoto2", timeout_s=5)
    >>> cam.command()[1:]
    ['--capture-image-and-download', '--filename', '%f.%C']
    """

    def __init__(
        self,
        dest_dir: str | os.PathLike[str],
        executable: str | os.PathLike[str] = "gphoto2",
        filename_pattern: str = DEFAULT_PATTERN,
        timeout_s: float = 60.0,
        extensions: Iterable[str] = RAW_EXTENSIONS,
        extra_args: Sequence[str] = (),
    ) -> None:
        self.dest_dir = Path(dest_dir)
        self.executable = os.fspath(executable)
        if not self.executable:
            raise CameraConfigError("executable is empty; give 'gphoto2' or the path of the gphoto2 program")
        if not isinstance(filename_pattern, str) or not filename_pattern or "/" in filename_pattern \
                or "\\" in filename_pattern:
            raise CameraConfigError(
                f"filename_pattern {filename_pattern!r} must be a non-empty file name pattern without folders, "
                f"e.g. {DEFAULT_PATTERN!r}",
                executable=self.executable,
            )
        self.filename_pattern = filename_pattern
        if not (isinstance(timeout_s, (int, float)) and not isinstance(timeout_s, bool) and 0 < timeout_s < 1e9):
            raise CameraConfigError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}",
                                    executable=self.executable)
        self.timeout_s = float(timeout_s)
        exts = tuple(e.lower() if e.startswith(".") else "." + e.lower() for e in extensions)
        if not exts:
            raise CameraConfigError("extensions is empty; give at least one RAW ending such as '.nef'")
        self.extensions = exts
        self.extra_args = tuple(str(a) for a in extra_args)

    def command(self, shutter: str | None = None) -> list[str]:
        """The argument vector of one capture (no shell is involved).

        ``shutter`` (a camera shutter-speed setting such as ``"1/250"`` or ``"2"``) is set with gphoto2's
        ``--set-config-value shutterspeed=...`` in the same invocation, before the capture.
        """
        setting = [] if shutter is None else ["--set-config-value", f"shutterspeed={shutter}"]
        return [self.executable, *self.extra_args, *setting, "--capture-image-and-download", "--filename",
                self.filename_pattern]

    def _resolve_executable(self) -> str:
        if os.sep in self.executable or (os.altsep and os.altsep in self.executable):
            path = Path(self.executable)
            if not path.is_file():
                raise CameraConfigError(
                    f"gphoto2 executable {self.executable} does not exist; install gphoto2 or pass the right path",
                    executable=self.executable,
                )
            if not os.access(path, os.X_OK):
                raise CameraConfigError(
                    f"gphoto2 executable {self.executable} is not executable; chmod +x it or pass another path",
                    executable=self.executable,
                )
            # absolute: the program runs with the capture's own working folder
            return str(path.resolve())
        found = shutil.which(self.executable)
        if found is None:
            raise CameraConfigError(
                f"gphoto2 executable {self.executable!r} was not found on PATH; install gphoto2 "
                "(e.g. apt install gphoto2) or pass executable=PATH",
                executable=self.executable,
            )
        return found

    def _run(self, workdir: Path, shutter: str | None = None) -> tuple[int, str, str]:
        argv = self.command(shutter)
        argv[0] = self._resolve_executable()
        try:
            done = run_bounded(argv, timeout_s=self.timeout_s, cwd=workdir, kill_leftovers=True)
        except OSError as exc:
            raise CameraConfigError(
                f"cannot start gphoto2 executable {self.executable}: {exc.strerror or exc}; check the path "
                "and its permissions",
                executable=self.executable,
            ) from exc
        out, err = done.stdout, done.stderr
        if done.timed_out:
            raise CameraTimeoutError(
                f"{self.executable} did not finish the capture within {self.timeout_s:g} s and was stopped; "
                "check that the camera is awake and focused (autofocus can hang; use manual focus), or raise "
                f"timeout_s for long exposures. Output: {_excerpt(err or out) or '(none)'}",
                executable=self.executable, stderr=_excerpt(err),
            )
        return int(done.returncode or 0), out, err

    def capture(self, name: str, shutter: str | None = None) -> Path:
        """Fire the camera, download the RAW frame and move it to ``dest_dir/<name><ext>``.

        Parameters
        ----------
        name
            File stem of the frame in ``dest_dir``; the RAW ending
            (lower case) is kept.
        shutter
            The shutter speed to set first (gphoto2's ``shutterspeed`` value, e.g. ``"1/250"``);
            None: the camera's current setting.

        Returns
        -------
        Path
            The frame in ``dest_dir``.

        Raises
        ------
        CameraConfigError
            The executable is missing or not executable, or ``name`` is not a plain file stem.
        CameraNotFoundError, CameraBusyError, CameraTimeoutError, CameraCommandError,
        CameraOutputMissingError
            See the module docstring.
        CameraFileExistsError, CameraTransferError
            The frame cannot be placed (the downloaded file is left in a
            ``.gphoto2-*`` folder inside ``dest_dir``).
        """
        check_capture_name(name)
        self.dest_dir.mkdir(parents=True, exist_ok=True)
        workdir = Path(tempfile.mkdtemp(prefix=".gphoto2-", dir=self.dest_dir))
        keep = False
        try:
            code, out, err = self._run(workdir, shutter)
            text = f"{err}\n{out}"
            kind = classify_gphoto2_error(text)
            if kind == "no_camera":
                raise CameraNotFoundError(
                    f"{self.executable}: no camera found; connect the camera by USB, switch it on, unmount it "
                    "from the desktop's file manager (which claims it), then check with "
                    f"'{self.executable} --auto-detect'",
                    executable=self.executable, stderr=_excerpt(err),
                )
            if kind == "busy":
                raise CameraBusyError(
                    f"{self.executable}: the camera is busy or claimed by another program "
                    f"({_excerpt(err or out)}); close other tethering programs or the file manager "
                    "(gvfs-gphoto2-volume-monitor), wait for the previous shot to finish, and try again",
                    executable=self.executable, stderr=_excerpt(err),
                )
            if code != 0:
                raise CameraCommandError(
                    f"{self.executable} exited with status {code}: {_excerpt(err or out) or '(no output)'}; "
                    f"run '{' '.join(self.command())}' by hand to see the full message",
                    returncode=code, executable=self.executable, stderr=_excerpt(err),
                )
            files = sorted(p for p in workdir.iterdir() if p.is_file() and not p.is_symlink())
            raws = [p for p in files if p.suffix.lower() in self.extensions]
            if not raws:
                got = ", ".join(p.name for p in files) or "nothing"
                hint = ("set the camera's image quality to RAW (or RAW+JPEG)" if files else
                        "check the camera's capture target setting and the card")
                raise CameraOutputMissingError(
                    f"{self.executable} reported success but downloaded {got} and no RAW file "
                    f"({', '.join(self.extensions)}); {hint}",
                    executable=self.executable, stderr=_excerpt(err),
                )
            if len(raws) > 1:
                raise CameraOutputMissingError(
                    f"{self.executable} downloaded several RAW files ({', '.join(p.name for p in raws)}) for one "
                    "capture; the frame is ambiguous. Clear pending images on the camera and capture again",
                    executable=self.executable,
                )
            raw = raws[0]
            if raw.stat().st_size == 0 or tiff_complete(raw) is False:
                raise CameraOutputMissingError(
                    f"{self.executable} downloaded {raw.name} but the file is empty or truncated; "
                    "check the USB cable and capture again",
                    executable=self.executable,
                )
            keep = True
            moved = move_file_atomic(raw, self.dest_dir / f"{name}{raw.suffix.lower()}")
            keep = False
            return moved
        finally:
            if not keep:
                shutil.rmtree(workdir, ignore_errors=True)
