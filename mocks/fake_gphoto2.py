"""A fake ``gphoto2`` program that photographs the simulated world and downloads a DNG.

It answers the command line the camera driver uses
(:class:`drivers.camera_gphoto2.Gphoto2Camera`)::

    gphoto2 [--port PORT] [--set-config-value shutterspeed=T] --capture-image-and-download [--filename PATTERN]

like gphoto2 2.5 does: it prints ``New file is in location ... on the
camera`` / ``Saving file as NAME`` / ``Deleting file ... on the camera`` and
writes the frame into the current folder, expanding the pattern codes
``%f`` (the camera's file name, ``DSC_0001``...), ``%C`` (extension,
``dng``), ``%n`` (running number from 1), ``%%`` and the ``strftime`` date
codes ``%Y %m %d %H %M %S``.  ``--auto-detect`` and ``--version`` answer too.  ``--set-config-value shutterspeed=T`` (or
``--set-config``) sets the exposure of that capture (``1/4000``, ``0.5``, ``1``; seconds), as a bracketed
capture does; the configuration's ``exposure_s`` is used otherwise.  A light-probe world's frames record
the aperture f/8.

The frame is rendered from :class:`mocks.world.World` through the simulated
camera (:mod:`mocks.camera_sim`).  State lives in a JSON configuration file
(:func:`write_config`) named by the ``KOGEI_FAKE_GPHOTO2_CONFIG``
environment variable or built into the shim by :func:`install`::

    {"world": {...World.to_dict()...},
     "chart_first": true,        # capture number 1 shows the colour chart
     "chart_next": true,         # the next frame written shows the chart
     "placement": 0,             # the object's placement (for the noise seed)
     "exposure_s": 0.01, "seed": 0,
     "faults": {"no_camera": false, "busy": 0, "slow_s": 0.0,
                "exit_code": 0, "no_output": false, "saturate": false}}

``chart_next`` says that the next frame written shows the colour chart; a
written chart frame clears it (a failed capture does not), and the simulated
station (:mod:`mocks.station`) sets it again when the object is re-placed.
:func:`write_config` sets it to ``chart_first``, so capture number 1 shows the
chart.  The sensor noise of a frame is seeded by (``seed``, ``placement``,
frame kind, table angle) (:func:`mocks.noise_seed.frame_seed`), so a frame
re-taken after a fault is identical.  Every read-modify-write of the file
holds ``<config>.lock`` (:func:`config_lock`) because the station and this
program change it from different processes.

``busy`` counts down: that many captures fail with ``Could not claim the USB
device`` before the camera frees up.  A capture counter is kept in
``<config>.state``.  Error messages are gphoto2's own wording, printed to
standard error with exit status 1 (or ``exit_code``).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import re
import sys
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "CONFIG_ENV",
    "DEFAULT_FAULTS",
    "cache_mesh",
    "chart_seed_kind",
    "chart_taken",
    "config_lock",
    "expand_pattern",
    "install",
    "main",
    "parse_shutter",
    "read_config",
    "render_frame",
    "set_renderer",
    "update_config",
    "write_config",
]

#: Environment variable naming the configuration file (overrides the shim's built-in path).
CONFIG_ENV = "KOGEI_FAKE_GPHOTO2_CONFIG"

#: Fault switches and their "off" values.
DEFAULT_FAULTS: dict[str, Any] = {
    "no_camera": False,
    "busy": 0,
    "slow_s": 0.0,
    "exit_code": 0,
    "no_output": False,
    "saturate": False,
}

_SATURATION_BOOST = 30.0
_CODES = re.compile(r"%(.)")


def expand_pattern(pattern: str, *, basename: str, extension: str, number: int, when: float) -> str:
    """gphoto2's ``--filename`` pattern expanded for one file.

    Examples
    --------
    >>> expand_pattern("%f.%C", basename="DSC_0001", extension="dng", number=1, when=0)
    'DSC_0001.dng'
    >>> expand_pattern("shot-%n-100%%.%C", basename="X", extension="dng", number=7, when=0)
    'shot-7-100%.dng'
    """
    stamp = time.localtime(when)

    def one(m: re.Match[str]) -> str:
        c = m.group(1)
        if c == "f":
            return basename
        if c == "C":
            return extension
        if c == "n":
            return str(number)
        if c == "%":
            return "%"
        if c in "YmdHMS":
            return time.strftime("%" + c, stamp)
        raise ValueError(f"unknown filename pattern code %{c}")

    return _CODES.sub(one, pattern)


def write_config(path: str | os.PathLike[str], world: dict[str, Any], *, faults: dict[str, Any] | None = None,
                 chart_first: bool = True, exposure_s: float = 0.01, seed: int = 0, placement: int = 0,
                 renderer: str | os.PathLike[str] | None = None) -> Path:
    """Write a fake-gphoto2 configuration atomically (and reset its capture counter).

    ``renderer`` is the control folder of a simulated station that renders the frames in its own process
    (:func:`mocks.station_requests.request_render`); without it, or when nobody answers there, the
    program renders them itself.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = write_config(pathlib.Path(tempfile.mkdtemp()) / "cam.json", {"mesh": "hawk:2000"})
    >>> read_config(p)["faults"]["busy"]
    0
    """
    unknown = set(faults or {}) - set(DEFAULT_FAULTS)
    if unknown:
        raise ValueError(f"unknown fake gphoto2 fault(s) {', '.join(sorted(unknown))}; "
                         f"known: {', '.join(DEFAULT_FAULTS)}")
    config = {"world": world, "chart_first": bool(chart_first), "chart_next": bool(chart_first),
              "placement": int(placement), "exposure_s": float(exposure_s),
              "seed": int(seed), "faults": {**DEFAULT_FAULTS, **(faults or {})}}
    if renderer is not None:
        config["renderer"] = str(renderer)
    target = Path(path)
    with config_lock(target):
        _atomic_json(target, config)
    state = _state_path(target)
    if state.exists():
        state.unlink()
    return target


def read_config(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The configuration in ``path`` with missing fault switches filled in."""
    with open(path, encoding="utf-8") as fh:
        config = json.load(fh)
    config["faults"] = {**DEFAULT_FAULTS, **config.get("faults", {})}
    return config


@contextlib.contextmanager
def config_lock(path: str | os.PathLike[str]) -> Iterator[None]:
    """Hold the configuration's lock file ``<config>.lock`` (``flock``, across processes).

    Examples
    --------
    >>> import tempfile, pathlib
    >>> with config_lock(pathlib.Path(tempfile.mkdtemp()) / "cam.json"):
    ...     pass
    """
    lock = Path(path).with_name(Path(path).name + ".lock")
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing releases the lock


def update_config(path: str | os.PathLike[str], *, faults: dict[str, Any] | None = None,
                  placement: int | None = None, chart_next: bool | None = None, chart_index: int | None = None,
                  shot_index: int | None = None,
                  **world_changes: Any) -> None:
    """Change fault switches, the placement, the chart flag and world settings (e.g. ``table_angle_deg``).

    ``chart_index`` numbers repeated chart frames of one placement: each is a
    new exposure (its own sensor noise), where index 0 is the single chart frame.
    ``shot_index`` numbers the object frames of a burst shot at one view in the same
    way (0: the first or only frame; the capture's ``before_frame`` hook sets it).

    The change is a read-modify-write under :func:`config_lock`, written
    atomically (temporary file + rename).
    """
    if faults:
        unknown = set(faults) - set(DEFAULT_FAULTS)
        if unknown:
            raise ValueError(f"unknown fake gphoto2 fault(s) {', '.join(sorted(unknown))}; "
                             f"known: {', '.join(DEFAULT_FAULTS)}")
    with config_lock(path):
        config = read_config(path)
        if faults:
            config["faults"].update(faults)
        if placement is not None:
            config["placement"] = int(placement)
        if chart_next is not None:
            config["chart_next"] = bool(chart_next)
        if chart_index is not None:
            config["chart_index"] = int(chart_index)
        if shot_index is not None:
            config["shot_index"] = int(shot_index)
        config["world"].update(world_changes)
        _atomic_json(Path(path), config)


def set_renderer(path: str | os.PathLike[str], renderer: str | os.PathLike[str] | None) -> None:
    """Set (a station's control folder) or clear (None) who renders the frames of configuration ``path``."""
    with config_lock(path):
        config = read_config(path)
        if renderer is None:
            config.pop("renderer", None)
        else:
            config["renderer"] = str(renderer)
        _atomic_json(Path(path), config)


def _chart_next(config: dict[str, Any], number: int) -> bool:
    """Whether capture ``number`` shows the chart (configurations without ``chart_next``: capture 1)."""
    if "chart_next" in config:
        return bool(config["chart_next"])
    return bool(config.get("chart_first", True)) and number == 1


def chart_seed_kind(config: dict[str, Any], kind: str) -> str:
    """The frame kind as the noise seed sees it: a repeated chart frame (``chart_index`` > 0) is a new exposure.

    >>> chart_seed_kind({"chart_index": 2}, "chart"), chart_seed_kind({}, "chart"), chart_seed_kind({"chart_index": 2}, "object")
    ('chart/2', 'chart', 'object')
    """
    k = int(config.get("chart_index", 0))
    return f"chart/{k}" if kind == "chart" and k > 0 else kind


def frame_shot(config: dict[str, Any], kind: str) -> int:
    """The number of an object frame in its burst (``shot_index``; 0 for a chart or a single frame).

    >>> frame_shot({"shot_index": 3}, "object"), frame_shot({"shot_index": 3}, "chart"), frame_shot({}, "object")
    (3, 0, 0)
    """
    return int(config.get("shot_index", 0)) if kind == "object" else 0


def chart_taken(path: str | os.PathLike[str], placement: int) -> None:
    """Clear ``chart_next`` after a chart frame of ``placement`` was written, unless the object was re-placed
    meanwhile (then the next frame must show the chart again)."""
    with config_lock(path):
        config = read_config(path)
        if int(config.get("placement", 0)) == placement and config.get("chart_next"):
            config["chart_next"] = False
            _atomic_json(Path(path), config)


def install(directory: str | os.PathLike[str], config: str | os.PathLike[str]) -> Path:
    """Install the fake as an executable ``<directory>/gphoto2`` bound to ``config``.

    The shim runs this module with the current interpreter (``#!`` line of
    ``sys.executable``) and the project on ``sys.path``.  Put ``directory``
    first on ``PATH`` or give its path to the camera driver.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> shim = install(d, d / "cam.json")
    >>> shim.name, os.access(shim, os.X_OK)
    ('gphoto2', True)
    """
    folder = Path(directory)
    folder.mkdir(parents=True, exist_ok=True)
    root = Path(__file__).resolve().parent.parent
    text = (
        f"#!{sys.executable}\n"
        "# Fake gphoto2 of the kogei simulator (mocks/fake_gphoto2.py).\n"
        "import sys\n"
        f"sys.path.insert(0, {str(root)!r})\n"
        "from mocks.fake_gphoto2 import main\n"
        f"sys.exit(main(sys.argv[1:], default_config={str(Path(config).resolve())!r}))\n"
    )
    from processing.common.files import atomic_path

    shim = folder / "gphoto2"
    with atomic_path(shim, durable=False) as tmp:
        tmp.write_text(text, encoding="utf-8")
        tmp.chmod(0o755)
    return shim


def _atomic_json(path: Path, data: dict[str, Any]) -> None:
    """Write ``data`` as JSON to ``path`` through a temporary file, ``fsync`` and a rename."""
    from processing.common.files import atomic_write_text  # here: --version and --auto-detect stay quick

    atomic_write_text(path, json.dumps(data, indent=1), make_parents=False)


def _state_path(config: Path) -> Path:
    return config.with_name(config.name + ".state")


def cache_mesh(config_path: str | os.PathLike[str], world: Any, source: str | None = None) -> Path:
    """Store ``world``'s mesh as the configuration's mesh cache ``<config>.mesh.npz``.

    Captures then load the mesh from the cache instead of rebuilding it (the
    procedural hawk takes seconds); a world without a mesh source (built from
    arrays) can be photographed only this way, under a ``source`` label that
    matches the configuration's ``world.mesh``.
    """
    import numpy as np

    from processing.common.files import atomic_path

    cache = Path(config_path).with_name(Path(config_path).name + ".mesh.npz")
    label = str(source if source is not None else world.mesh_source)
    with atomic_path(cache, durable=False) as tmp:    # a .npz name, so np.savez adds no suffix
        np.savez(tmp, source=label, vertices=world.vertices, triangles=world.triangles, region=world.region,
                 names=np.array(world.region_names),
                 materials=np.array([world.materials[n] for n in world.region_names]))
    return cache


def _world(data: dict[str, Any], config_path: Path) -> Any:
    """The configured world; the mesh is cached in ``<config>.mesh.npz`` so captures after the first
    do not rebuild it."""
    import numpy as np

    from mocks.world import World

    if "swatch" in data or "board" in data or "mirror" in data or "probe" in data:
        return World.from_dict(data)        # analytic or quick to build: nothing worth caching
    cache = config_path.with_name(config_path.name + ".mesh.npz")
    source = str(data.get("mesh", "hawk:4000"))
    if cache.exists():
        with np.load(cache, allow_pickle=False) as z:
            if str(z["source"]) == source:
                settings = {k: v for k, v in data.items() if k not in ("mesh", "materials")}
                world = World(z["vertices"], z["triangles"], z["region"], tuple(str(n) for n in z["names"]),
                              {**{str(n): str(m) for n, m in zip(z["names"], z["materials"])},
                               **data.get("materials", {})},
                              mesh_source=source, **_world_settings(settings))
                return world
    world = World.from_dict(data)
    cache_mesh(config_path, world, source)
    return world


def _world_settings(settings: dict[str, Any]) -> dict[str, Any]:
    from mocks.world import world_settings

    return world_settings(settings)


def _error(message: str, code: int = 1) -> int:
    sys.stderr.write(f"\n*** Error{message} ***\n\n")
    sys.stderr.flush()
    return code


def main(argv: Sequence[str] | None = None, default_config: str | None = None) -> int:
    """Run the fake with command-line ``argv``; returns the exit status."""
    parsed = _parse_args(list(sys.argv[1:] if argv is None else argv))
    if isinstance(parsed, int):
        return parsed
    pattern, capture, detect, exposure = parsed
    config_path = os.environ.get(CONFIG_ENV) or default_config
    if not config_path or not Path(config_path).is_file():
        sys.stderr.write(f"fake gphoto2: configuration {config_path!r} not found; set {CONFIG_ENV}\n")
        return 2
    config = read_config(config_path)
    faults = config["faults"]
    if detect:
        print("Model                          Port\n----------------------------------------------------------")
        if not faults["no_camera"]:
            print("Nikon DSC D5100 (PTP mode)     usb:001,004")
        return 0
    if not capture:
        sys.stderr.write("gphoto2: nothing to do; use --capture-image-and-download\n")
        return 1
    failed = _camera_faults(config_path, faults)
    if failed is not None:
        return failed
    if exposure is not None:          # a bracket: its own exposure, and its own noise
        config["exposure_s"] = exposure
        config["bracket"] = True
    return _capture(config_path, config, pattern)


def parse_shutter(value: str) -> float:
    """Seconds of a gphoto2 shutter-speed value (``1/250``, ``0.5``, ``2``, ``2s``).

    >>> parse_shutter("1/4000"), parse_shutter("2s")
    (0.00025, 2.0)
    """
    text = value.strip().rstrip("s")
    num, _, den = text.partition("/")
    seconds = float(num) / float(den) if den else float(num)
    if not (seconds > 0 and seconds < 3600):
        raise ValueError(value)
    return seconds


def _parse_args(args: list[str]) -> tuple[str, bool, bool, float | None] | int:
    """``(pattern, capture, detect, exposure_s)`` of the command line, or the exit status that ends the run."""
    pattern = "%f.%C"
    capture = detect = False
    exposure = None
    i = 0
    while i < len(args):
        a = args[i]
        if a == "--capture-image-and-download":
            capture = True
        elif a in ("--filename", "--port", "--set-config-value", "--set-config"):
            if i + 1 >= len(args):
                sys.stderr.write(f"{a}: missing argument\n")
                return 1
            if a == "--filename":
                pattern = args[i + 1]
            elif a.startswith("--set-config"):
                key, _, value = args[i + 1].partition("=")
                if key != "shutterspeed":
                    sys.stderr.write(f"\n*** Error: {key} not found in configuration tree. ***\n\n")
                    return 1
                try:
                    exposure = parse_shutter(value)
                except ValueError:
                    sys.stderr.write(f"\n*** Error: shutterspeed {value!r} is not a shutter speed. ***\n\n")
                    return 1
            i += 1
        elif a.startswith("--filename="):
            pattern = a.split("=", 1)[1]
        elif a == "--version":
            print("gphoto2 2.5.28 (kogei simulator)")
            return 0
        elif a == "--auto-detect":
            detect = True
        else:
            sys.stderr.write(f"gphoto2: unknown option {a!r} (this simulator knows --capture-image-and-download, "
                             "--filename, --port, --set-config-value, --auto-detect, --version)\n")
            return 1
        i += 1
    return pattern, capture, detect, exposure


def _camera_faults(config_path: str, faults: dict[str, Any]) -> int | None:
    """The exit status of a capture a fault switch makes fail (None: go on; ``slow_s`` only waits)."""
    if faults["no_camera"]:
        return _error(": No camera found.")
    if int(faults["busy"]) > 0:
        update_config(config_path, faults={"busy": int(faults["busy"]) - 1})
        sys.stderr.write("\n*** Error (-53: 'Could not claim the USB device') ***\n\n")
        return 1
    if float(faults["slow_s"]) > 0:
        time.sleep(float(faults["slow_s"]))
    if int(faults["exit_code"]) != 0:
        return _error(" (-1: 'Unspecified error')", int(faults["exit_code"]))
    return None


#: The last view rendered in this process (its world, spectral frame and key), which the next shots of a
#: burst reuse: the same world, placement and kind render the same radiance, so only the noise is drawn anew.
_LAST_VIEW: dict[str, Any] = {}


def render_frame(config_path: str | os.PathLike[str], config: dict[str, Any], path: str, kind: str) -> None:
    """Render the configured world's ``kind`` frame (``"chart"`` or ``"object"``) and write it to ``path`` (DNG).

    The capture's sensor noise is seeded by (``seed``, ``placement``, frame kind, table angle, the shot's
    number in a burst: ``shot_index``) and, for a bracket, its exposure, so the same frame renders the same
    wherever it is rendered: in this program or in the simulated station's process
    (:func:`_render_at_station`).  The shots after the first of a burst reuse the first shot's spectral
    render when it was made in this process (same world, placement and kind).
    """
    from mocks.camera_sim import simulate_raw, write_raw
    from mocks.noise_seed import frame_seed

    placement = int(config.get("placement", 0))
    shot = frame_shot(config, kind)
    key = (str(Path(config_path).resolve()), json.dumps(config["world"], sort_keys=True, default=str), placement, kind)
    if shot > 0 and _LAST_VIEW.get("key") == key:
        world, frame = _LAST_VIEW["world"], _LAST_VIEW["frame"]     # a burst's next shot: only the noise is new
    else:
        world = _world(config["world"], Path(config_path))
        frame = world.frame(kind)
        if "shot_index" in config:                  # a capture that shoots bursts: keep the view for its next shot
            _LAST_VIEW.update(key=key, world=world, frame=frame)
    exposure = float(config["exposure_s"])
    raw = simulate_raw(frame.radiance, frame.grid, frame.light, exposure_s=exposure,
                       seed=frame_seed(int(config["seed"]), placement, chart_seed_kind(config, kind),
                                       world.table_angle_deg, shot=shot)
                       + (int(round(1e6 * exposure)) if config.get("bracket") else 0),
                       exposure_boost=_SATURATION_BOOST if config["faults"]["saturate"] else 1.0)
    raw.f_number = getattr(world, "f_number", None)
    write_raw(path, raw)


def _render_at_station(config_path: str, config: dict[str, Any], path: str, kind: str) -> bool:
    """Have the simulated station that wrote the configuration render the frame (True), or False when none
    is watching its control folder (``renderer`` in the configuration).

    A fresh program would spend seconds importing the renderer's modules for every photograph; the
    station's process has them loaded.
    """
    control = config.get("renderer")
    if not control:
        return False
    from mocks.station_requests import request_render

    answer = request_render(control, {"config_path": str(Path(config_path).resolve()), "config": config,
                                      "path": path, "kind": kind})
    return answer is not None


def _capture(config_path: str, config: dict[str, Any], pattern: str) -> int:
    """Count the capture, render the frame and write it under ``pattern`` as gphoto2 reports it."""
    faults = config["faults"]
    state_path = _state_path(Path(config_path))
    count = int(json.loads(state_path.read_text())["count"]) if state_path.exists() else 0
    number = count + 1
    try:
        name = expand_pattern(pattern, basename=f"DSC_{number:04d}", extension="dng", number=number,
                              when=time.time())
    except ValueError as exc:
        sys.stderr.write(f"gphoto2: {exc}\n")
        return 1
    if "/" in name:
        os.makedirs(os.path.dirname(name) or ".", exist_ok=True)
    _atomic_json(state_path, {"count": number})
    print(f"New file is in location /capt{count:04d}.nef on the camera")
    if not faults["no_output"]:
        chart = _chart_next(config, number)
        kind = "chart" if chart else "object"
        target = os.path.abspath(name)
        if not _render_at_station(config_path, config, target, kind):
            render_frame(config_path, config, target, kind)
        if chart:
            chart_taken(config_path, int(config.get("placement", 0)))
        print(f"Saving file as {name}")
    print(f"Deleting file /capt{count:04d}.nef on the camera")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
