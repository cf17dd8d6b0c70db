"""A pseudo-terminal pair standing in for a USB serial cable.

The device emulators (docs/simulator.md) sit on the master side of a pty
pair, and the driver opens the slave side (``/dev/pts/N``) through
pyserial exactly as it opens a real port.  Unplugging closes both ends (the
driver's reads and writes fail as with a pulled cable); plugging in again
creates a *new* pair whose number may differ.  So that a driver can find the
device again, the link keeps a stable symlink (``link_path``, e.g.
``<tmpdir>/turntable``) pointing at the current ``/dev/pts/N``, removed
while unplugged -- the same role ``/dev/serial/by-id/...`` plays for real
USB adapters.

Examples
--------
>>> import os, tempfile
>>> link = PtyLink(os.path.join(tempfile.mkdtemp(), "dev"))
>>> os.path.realpath(link.path) == link.device_path
True
>>> link.unplug(); os.path.exists(link.path)
False
>>> link.plug(); os.path.exists(link.path)
True
>>> link.close()
"""

from __future__ import annotations

import os
import select
import tempfile
import threading
import time
import tty
from pathlib import Path

__all__ = ["PtyLink", "PtyDevice"]


class PtyLink:
    """A pty pair plus an optional stable symlink to its slave device.

    Parameters
    ----------
    link_path
        Where to keep a symlink to the slave device; ``None`` for none (then
        :attr:`path` is the ``/dev/pts/N`` path itself).

    Attributes
    ----------
    master_fd
        The emulator's end (``-1`` while unplugged).
    device_path
        The current slave device path (``None`` while unplugged).
    """

    def __init__(self, link_path: str | os.PathLike[str] | None = None) -> None:
        self.link_path = Path(link_path) if link_path is not None else None
        self.master_fd = -1
        self._slave_fd = -1
        self.device_path: str | None = None
        self._lock = threading.Lock()
        self.plug()

    @property
    def path(self) -> str:
        """The path a driver should open (the symlink if there is one)."""
        if self.link_path is not None:
            return str(self.link_path)
        if self.device_path is None:
            raise RuntimeError("PtyLink is unplugged and has no link_path: call plug() first")
        return self.device_path

    @property
    def plugged(self) -> bool:
        """True while the pty pair exists."""
        return self.master_fd >= 0

    def plug(self) -> None:
        """Create a new pty pair (raw mode) and point the symlink at it."""
        with self._lock:
            if self.master_fd >= 0:
                return
            master, slave = os.openpty()
            tty.setraw(slave)  # no echo, no CR/LF translation, 8-bit clean
            os.set_blocking(master, False)
            self.master_fd, self._slave_fd = master, slave
            self.device_path = os.ttyname(slave)
            if self.link_path is not None:
                self.link_path.parent.mkdir(parents=True, exist_ok=True)
                tmp = self.link_path.with_name(self.link_path.name + ".new")
                if tmp.is_symlink() or tmp.exists():
                    tmp.unlink()
                os.symlink(self.device_path, tmp)
                os.replace(tmp, self.link_path)

    def unplug(self) -> None:
        """Close both ends and remove the symlink (the device is gone)."""
        with self._lock:
            if self.link_path is not None and self.link_path.is_symlink():
                self.link_path.unlink()
            for fd in (self.master_fd, self._slave_fd):
                if fd >= 0:
                    try:
                        os.close(fd)
                    except OSError:
                        pass
            self.master_fd = self._slave_fd = -1
            self.device_path = None

    def close(self) -> None:
        """Unplug for good."""
        self.unplug()

    def __enter__(self) -> PtyLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PtyDevice:
    """Life cycle shared by the firmware emulators.

    A subclass calls :meth:`_open_link` in its constructor, sets ``_lock``
    (an RLock), ``faults`` (with ``replug_after_s``), ``_replug_at`` and the
    output buffer ``_out``, and implements the hooks of the serving loop:
    ``_tick(now)`` (timed work), ``_next_wait(now)`` (seconds until the next
    timed event), ``_receive(data, now)`` (bytes from the host), ``_flush()``
    (write what ``_out`` holds) and ``_power_on()``; ``_before_unplug(now)`` is
    optional.  ``start``/``stop`` and the context manager run the loop on one
    daemon thread.  Without a ``link_path`` the stable symlink lives in a
    temporary folder removed by ``stop``.
    """

    _thread_name = "pty-device"

    def _open_link(self, link_path: str | os.PathLike[str] | None, prefix: str, name: str) -> None:
        self._tmpdir: tempfile.TemporaryDirectory[str] | None = None
        if link_path is None:
            self._tmpdir = tempfile.TemporaryDirectory(prefix=prefix)
            link_path = os.path.join(self._tmpdir.name, name)
        self.link = PtyLink(link_path)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def path(self) -> str:
        """Stable path for the driver to open (a symlink to ``/dev/pts/N``)."""
        return self.link.path

    def _before_unplug(self, now: float) -> None:
        """Called with the lock held just before the pty disappears."""

    def unplug(self, replug_after_s: float | None = None) -> None:
        """Pull the cable: the pty disappears and the device loses power."""
        with self._lock:
            self._before_unplug(time.monotonic())
            self.link.unplug()
            self._replug_at = None if replug_after_s is None else time.monotonic() + replug_after_s

    def replug(self) -> None:
        """Plug back in: a new pty (the symlink follows it), the device powered on."""
        with self._lock:
            self._replug_at = None
            self._power_on()
            self.link.plug()

    def _run(self) -> None:
        """Serve the pty until ``stop``: replug when due, run timed work, read and answer."""
        while not self._stop.is_set():
            with self._lock:
                now = time.monotonic()
                if not self.link.plugged:
                    if self._replug_at is None and self.faults.replug_after_s is not None:
                        self._replug_at = now + self.faults.replug_after_s
                    if self._replug_at is not None and now >= self._replug_at:
                        self.replug()
                    fd = -1
                else:
                    self._tick(now)
                    fd = self.link.master_fd
                    wait = max(0.0, self._next_wait(now))
            if fd < 0:
                self._stop.wait(0.01)
                continue
            try:
                r, _, _ = select.select([fd], [fd] if self._out else [], [], wait)
            except (OSError, ValueError):
                continue                       # the pty went away under us (unplug)
            with self._lock:
                if fd != self.link.master_fd:
                    continue
                if r:
                    try:
                        data = os.read(fd, 4096)
                    except OSError:
                        data = b""             # no reader attached (EIO) or nothing after all
                    self._receive(data, time.monotonic())
                self._flush()

    def start(self):
        """Start serving (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name=self._thread_name, daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and remove the pty."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self.link.close()
        if self._tmpdir is not None:
            self._tmpdir.cleanup()
            self._tmpdir = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
