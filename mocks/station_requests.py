"""The simulated station's control folder: another process asks for ``place`` and ``shoot`` through files.

A client (the capture command's hooks) writes ``request-<id>.json``
atomically; the station's control thread (:func:`serve_requests`) removes
it, carries it out and writes ``done-<id>.json``; the client reads and
removes the answer, or takes its request back when no answer comes in time.
:func:`request_place` and :func:`request_shoot` are the client side.
docs/simulator.md ("Control folder protocol") gives the messages.

Examples
--------
>>> import tempfile, threading, pathlib
>>> folder, stop = pathlib.Path(tempfile.mkdtemp()), threading.Event()
>>> server = threading.Thread(target=serve_requests, args=(folder, stop, 0.01, lambda p: {"ok": True, **p}))
>>> server.start()
>>> request_place(folder, 2)
{'ok': True, 'action': 'place', 'placement': 2}
>>> stop.set(); server.join()
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import threading
import time
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from processing.common.files import atomic_write_text

__all__ = ["StationError", "StationTimeout", "serve_requests", "request_place", "request_shoot", "request_render"]

_log = logging.getLogger("mocks.station")   # the station's log, as before the protocol had its own module
_REQUEST = re.compile(r"^request-([A-Za-z0-9_.-]{1,80})\.json$")


class StationError(RuntimeError):
    """The simulated station cannot do what was asked; the message says what to do."""


class StationTimeout(StationError, TimeoutError):
    """No simulated station answered a control request in time."""


def _atomic_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``data`` to ``path`` through a hidden temporary file and a rename (the folder must exist)."""
    atomic_write_text(path, json.dumps(data, indent=1), durable=False, make_parents=False)


# ------------------------------------------------------------------ station side
def serve_requests(control_dir: str | os.PathLike[str], stop: threading.Event, poll_s: float,
                   perform: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
    """Answer the request files of ``control_dir`` until ``stop`` is set (the station's control thread).

    Parameters
    ----------
    control_dir
        The watched folder (a missing folder is polled until it appears).
    stop
        Set to end the loop; it is checked every ``poll_s`` seconds.
    poll_s
        Polling period (s).
    perform
        Carries out a request (a JSON object with an ``"action"``) and
        returns the answer; its exceptions become ``{"ok": false, "error": ...}``.
    """
    folder = Path(control_dir)
    while not stop.wait(poll_s):
        try:
            names = sorted(os.listdir(folder))
        except FileNotFoundError:
            continue
        for name in names:
            m = _REQUEST.match(name)
            if m and not stop.is_set():
                _answer(folder / name, m.group(1), perform)


def _answer(request: Path, rid: str, perform: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
    """Take the request file ``request``, carry it out and write ``done-<rid>.json`` beside it."""
    try:
        text = request.read_text(encoding="utf-8")
        request.unlink()
    except FileNotFoundError:
        return  # taken back by its client (timed out)
    answer: dict[str, Any]
    try:
        payload = json.loads(text)
        if not isinstance(payload, dict):
            raise StationError("a request must be a JSON object with an 'action'")
        answer = perform(payload)
    except json.JSONDecodeError as exc:
        answer = {"ok": False, "error": f"request {request.name} is not valid JSON: {exc}"}
    except Exception as exc:  # the control thread answers every request and keeps serving
        _log.warning("control request %s failed: %s", request.name, exc)
        answer = {"ok": False, "error": str(exc) or type(exc).__name__}
    try:
        _atomic_json(request.parent / f"done-{rid}.json", answer)
    except OSError as exc:
        _log.warning("cannot answer control request %s: %s", request.name, exc)


# ------------------------------------------------------------------ client side
def _request(control_dir: str | os.PathLike[str], payload: dict[str, Any], timeout_s: float,
             poll_s: float = 0.01) -> dict[str, Any]:
    """Drop ``payload`` as a request in ``control_dir`` and wait for the station's answer."""
    folder = Path(control_dir)
    if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
        raise ValueError(f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
    if not folder.is_dir():
        raise StationError(f"no simulated station control folder {folder}: start `kogei mock` and pass the "
                           "control folder it prints")
    rid = f"{os.getpid()}-{uuid.uuid4().hex[:12]}"
    request = folder / f"request-{rid}.json"
    done = folder / f"done-{rid}.json"
    _atomic_json(request, payload)
    end = time.monotonic() + timeout_s
    while True:
        try:
            text = done.read_text(encoding="utf-8")
        except FileNotFoundError:
            if time.monotonic() >= end:
                break
            time.sleep(poll_s)
            continue
        done.unlink(missing_ok=True)
        answer = json.loads(text)
        if not answer.get("ok"):
            raise StationError(f"the simulated station at {folder} could not {payload['action']}: "
                               f"{answer.get('error', 'no reason given')}")
        return answer
    try:
        request.unlink()
        unclaimed = True
    except FileNotFoundError:
        unclaimed = False
    if unclaimed:
        raise StationTimeout(f"no simulated station answered in {folder} within {timeout_s:g} s: start "
                             "`kogei mock` (it prints its control folder) or check the --control folder")
    raise StationTimeout(f"the simulated station at {folder} took the {payload['action']} request but did not "
                         f"finish within {timeout_s:g} s; raise the timeout")


def request_place(control_dir: str | os.PathLike[str], placement: int, timeout_s: float = 10.0) -> dict[str, Any]:
    """Ask the station watching ``control_dir`` to put the object in placement ``placement``.

    Parameters
    ----------
    control_dir
        The station's control folder (``kogei mock`` prints it).
    placement
        Placement number (>= 1).
    timeout_s
        How long to wait for the answer (s).

    Returns
    -------
    dict
        The station's answer: ``{"ok": True, "action": "place", "placement": n, "pose": [[...]]}``.

    Raises
    ------
    StationTimeout
        No station answered within ``timeout_s`` (the message names the
        folder and says to start ``kogei mock``).
    StationError
        The folder does not exist or the station refused (the message gives
        its reason).
    """
    if not isinstance(placement, int) or isinstance(placement, bool) or placement < 1:
        raise ValueError(f"placement must be an integer >= 1, got {placement!r}")
    return _request(control_dir, {"action": "place", "placement": placement}, timeout_s)


def request_shoot(control_dir: str | os.PathLike[str], timeout_s: float = 60.0) -> dict[str, Any]:
    """Ask the station watching ``control_dir`` to shoot a frame into its hot folder.

    Parameters
    ----------
    control_dir
        The station's control folder.
    timeout_s
        How long to wait for the answer (s).

    Returns
    -------
    dict
        ``{"ok": True, "action": "shoot", "file": path, "kind": "chart"|"object",
        "table_angle_deg": a, "placement": n, "partial": bool}`` once the file
        is written.

    Raises
    ------
    StationTimeout, StationError
        As :func:`request_place`.
    """
    return _request(control_dir, {"action": "shoot"}, timeout_s)


def request_render(control_dir: str | os.PathLike[str], payload: dict[str, Any], claim_timeout_s: float = 2.0,
                   timeout_s: float = 300.0, poll_s: float = 0.01) -> dict[str, Any] | None:
    """Ask the station watching ``control_dir`` to render a fake-gphoto2 frame (``{"action": "render", ...}``).

    The station process has the world's modules imported and its mesh in memory, so a frame it renders
    costs the rendering alone, where a fresh ``gphoto2`` process would first spend seconds importing.

    Parameters
    ----------
    control_dir
        The station's control folder.
    payload
        The request (its ``"action"`` is set to ``"render"``).
    claim_timeout_s
        How long to wait for the station to take the request (s); no station taking it is not an error.
    timeout_s
        How long to wait for the answer once the request is taken (s).
    poll_s
        Polling period (s).

    Returns
    -------
    dict or None
        The station's answer, or None when no station took the request within ``claim_timeout_s`` (the
        request is taken back: the caller renders the frame itself).

    Raises
    ------
    StationError
        The station took the request and refused it or did not finish within ``timeout_s``.
    """
    folder = Path(control_dir)
    if not folder.is_dir():
        return None
    rid = f"{os.getpid()}-{uuid.uuid4().hex[:12]}"
    request = folder / f"request-{rid}.json"
    done = folder / f"done-{rid}.json"
    _atomic_json(request, {**payload, "action": "render"})
    start = time.monotonic()
    claimed = False
    while True:
        try:
            text = done.read_text(encoding="utf-8")
        except FileNotFoundError:
            now = time.monotonic()
            if not claimed and now - start >= claim_timeout_s:
                try:
                    request.unlink()
                    return None                 # no station watching: nobody took it
                except FileNotFoundError:
                    claimed = True
            if claimed and now - start >= timeout_s:
                raise StationTimeout(f"the simulated station at {folder} took the render request but did not "
                                     f"finish within {timeout_s:g} s") from None
            time.sleep(poll_s)
            continue
        done.unlink(missing_ok=True)
        answer = json.loads(text)
        if not answer.get("ok"):
            raise StationError(f"the simulated station at {folder} could not render: "
                               f"{answer.get('error', 'no reason given')}")
        return answer
