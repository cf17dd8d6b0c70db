"""A simulated tethering program that drops DNG frames into a hot folder, slowly.

Real tethering tools write a RAW file in pieces while it downloads from the
camera, so the file is visible, growing, before it is complete.
:func:`write_in_chunks` reproduces that (``chunks`` writes ``interval_s``
apart, each flushed) and can stop part way (``partial=True``: the fault of a
program that crashed or a cable pulled mid-download, leaving a truncated
file).  :class:`HotFolderWriter` renders frames of the simulated world
(:mod:`mocks.world`, :mod:`mocks.camera_sim`) and writes them this way,
in the caller's thread or in a background thread.
"""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

__all__ = ["HotFolderWriter", "write_in_chunks"]


def write_in_chunks(path: str | os.PathLike[str], data: bytes, *, chunks: int = 4, interval_s: float = 0.05,
                    partial: bool = False) -> Path:
    """Write ``data`` to ``path`` in ``chunks`` flushed pieces ``interval_s`` apart.

    Parameters
    ----------
    path
        File to create (its folder must exist; an existing file is an error).
    data
        The complete file content.
    chunks
        Number of pieces (>= 1).
    interval_s
        Pause after each piece but the last (>= 0 s).
    partial
        Stop after about half of the pieces (at least one, never all when
        ``chunks > 1``), leaving a truncated file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = write_in_chunks(pathlib.Path(tempfile.mkdtemp()) / "a.dng", b"0123456789", chunks=3, interval_s=0)
    >>> p.read_bytes()
    b'0123456789'
    """
    if not isinstance(chunks, int) or chunks < 1:
        raise ValueError(f"chunks must be an integer >= 1, got {chunks!r}")
    if not interval_s >= 0:
        raise ValueError(f"interval_s must be >= 0 seconds, got {interval_s!r}")
    target = Path(path)
    bounds = [round(i * len(data) / chunks) for i in range(chunks + 1)]
    last = max(1, chunks // 2) if partial and chunks > 1 else chunks
    if partial and chunks == 1:
        bounds = [0, len(data) // 2]
        last = 1
    with open(target, "xb") as fh:
        for i in range(last):
            fh.write(data[bounds[i]:bounds[i + 1]])
            fh.flush()
            os.fsync(fh.fileno())
            if i < last - 1 and interval_s:
                time.sleep(interval_s)
    return target


@dataclass
class HotFolderWriter:
    """Writes simulated captures into ``folder`` as ``IMG_0001.DNG``, ``IMG_0002.DNG``, ...

    Attributes
    ----------
    folder
        The hot folder.
    world
        A :class:`mocks.world.World`.
    exposure_s
        Exposure time of the simulated camera.
    seed
        Noise seed of the first frame (then +1 per frame), unless a frame is
        given its own ``seed``.
    """

    folder: Path
    world: object
    exposure_s: float = 0.01
    seed: int = 0
    count: int = 0

    def frame_bytes(self, kind: str = "object", table_angle_deg: float | None = None,
                    *, saturate: bool = False, seed: int | None = None) -> bytes:
        """The DNG bytes of one simulated capture (noise seed ``seed``, default ``self.seed + self.count``)."""
        from mocks.camera_sim import simulate_raw
        from mocks.dng_writer import dng_bytes

        frame = self.world.frame(kind, table_angle_deg)  # type: ignore[attr-defined]
        raw = simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=self.exposure_s,
                           seed=self.seed + self.count if seed is None else int(seed),
                           exposure_boost=30.0 if saturate else 1.0)
        return dng_bytes(raw.bayer, black_level=raw.black_level, white_level=raw.white_level,
                         cfa_pattern=raw.cfa_pattern, color_matrix=raw.color_matrix,
                         as_shot_neutral=raw.as_shot_neutral, exposure_time=raw.exposure_time, iso=raw.iso,
                         make=raw.make, model=raw.model)

    def next_path(self) -> Path:
        """The file name the next capture gets."""
        return Path(self.folder) / f"IMG_{self.count + 1:04d}.DNG"

    def capture(self, kind: str = "object", table_angle_deg: float | None = None, *, chunks: int = 4,
                interval_s: float = 0.05, partial: bool = False, saturate: bool = False,
                background: bool = False, seed: int | None = None) -> Path | threading.Thread:
        """Render and write one frame; with ``background`` return the started writer thread.

        ``partial`` leaves a truncated file (the fault); ``saturate`` over-exposes;
        ``seed`` is the frame's noise seed (see :meth:`frame_bytes`).
        """
        data = self.frame_bytes(kind, table_angle_deg, saturate=saturate, seed=seed)
        path = self.next_path()
        self.count += 1
        if not background:
            return write_in_chunks(path, data, chunks=chunks, interval_s=interval_s, partial=partial)
        thread = threading.Thread(target=write_in_chunks, args=(path, data),
                                  kwargs={"chunks": chunks, "interval_s": interval_s, "partial": partial},
                                  daemon=True, name=f"hotfolder-writer-{path.name}")
        thread.start()
        return thread
