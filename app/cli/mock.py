"""``kogei mock``: run the simulated scan station, and ask it to re-place the object or shoot a frame.

The simulated devices are described in ``docs/simulator.md``.  Three actions:

``kogei mock [--world hawk|vase|inlaid-bowl|plain-bowl[:bare]|sphere[:R[:OFF]]|board[:TILT]|mirror-sphere[:R[:OFF]]|probe[:R[:filtered]]|MESH] [--triangles N] [--material SPEC] [--faults SPEC,...]
[--time-scale S] [--root DIR] [--seed N]``
    Starts :class:`mocks.station.SimulatedStation`, prints its turntable
    port, profiler port, gphoto2 shim, hot folder and control folder with
    the ``kogei capture`` command lines that use them, writes the same as
    ``station.json`` in the station's folder, and runs until Ctrl-C or
    SIGTERM (then the ptys disappear).
``kogei mock place [N] --control DIR``
    Asks that station to put the object in placement ``N`` (default: the
    ``KOGEI_PASS`` environment variable the capture command sets for its
    before-pass hook); the next camera frame then shows the colour chart.
``kogei mock shoot --control DIR``
    Asks it to write one frame into its hot folder (a tethering program's
    shutter).

``place`` and ``shoot`` exit 0, or 2 with a one-line message.

Examples
--------
>>> import argparse
>>> parser = argparse.ArgumentParser(prog="kogei")
>>> _ = add_parser(parser.add_subparsers(dest="command"))
>>> args = parser.parse_args(["mock", "place", "2", "--control", "/tmp/st/control"])
>>> args.mock_action, args.placement, args.control
('place', 2, '/tmp/st/control')
>>> parser.parse_args(["mock", "--seed", "3"]).mock_action is None
True
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from app.errors import UsageError
from processing.common.files import atomic_path
from processing.errors import InputError

__all__ = ["add_parser", "run", "capture_commands", "PASS_ENV", "SCAN_STEPS", "SCAN_CAMERA_ANGLES", "SPHERE_STEPS", "main"]

#: Environment variable the capture command sets for its before-pass hook (the pass number).
PASS_ENV = "KOGEI_PASS"
EXIT_FAILED = 2
#: Table steps per revolution of the printed scan command.  The passes of the simulated hawk register at
#: 60 steps and more (6 deg between profiles; seeds 0-3); at 36 (10 deg) two of three passes are left out.
SCAN_STEPS = 72
#: Table angles of the printed scan's RAW frames: four per pass keep a first simulated session quick (each
#: frame of the fake gphoto2 is a program run of about 2 s); drop the option for the capture's own default,
#: a frame every 30 deg, which kogei fit-materials needs (it holds out every 4th angle).
SCAN_CAMERA_ANGLES = "0,90,180,270"
#: Table steps of the printed reference-sphere scan (one pass, no camera; docs/processing.md, Calibration).
SPHERE_STEPS = 90


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``mock`` subcommand (with its ``place`` and ``shoot`` actions) to ``sub``."""
    p = sub.add_parser(
        "mock",
        help="run the simulated scan station (turntable, profiler, camera, hot folder) until Ctrl-C",
        description="Run the simulated scan station: a Horus turntable and a laser profiler on "
                    "pseudo-terminals, a fake gphoto2 and a hot folder, all looking at one simulated object. "
                    "'kogei mock place' and 'kogei mock shoot' talk to a running station.",
    )
    p.add_argument("--world", default="hawk", metavar="hawk|vase|inlaid-bowl|plain-bowl[:bare]|sphere[:R[:OFF]]|board[:TILT]|mirror-sphere[:R[:OFF]]|probe[:R[:filtered]]|MESH",
                   help="the procedural hawk head (default); a turned object (a thrown vase with a boss and a "
                        "faint band, a bowl with an inlaid motif, a plain bowl with a painted motif, or bare; "
                        "docs/simulator.md, Turned objects); a calibration sphere of radius R mm (default 25) "
                        "OFF mm from the axis (default 60); a ChArUco board (DICT_5X5_100, 7 x 5 squares of "
                        "8 mm, markers 6 mm) for camera calibration, 960 x 640 frames, placements 1, 2, 3 flat "
                        "and on 40 and 55 degree wedges, or every placement at TILT degrees (0 = flat, < 90); "
                        "a chrome ball for lamp calibration, radius R mm (default 20) OFF mm from the axis "
                        "(default 35), 960 x 640 frames; a chrome ball of radius R mm (default 20) on the table "
                        "centre in a simulated lit room with the chart beside it, for a light probe (kogei capture "
                        "--plan probe; probe:R:filtered shoots every frame through a magenta notch filter, whose "
                        "transmission it writes as lens-filter.csv in the station folder, for the second bracket "
                        "set of kogei probe --filter-frames); or a mesh file (PLY/OBJ/STL/glTF, millimetres; glTF in metres); "
                        "a mesh with per-face materials (a PLY with a face 'material' property such as "
                        "products/object-mesh.ply, a glTF with a primitive per material such as kogei export "
                        "writes) keeps them, one region each")
    p.add_argument("--triangles", type=int, default=None, metavar="N",
                   help="triangle count of the hawk mesh (default 4000)")
    p.add_argument("--material", default=None, metavar="SPEC",
                   help="material of every region, e.g. gold or nami-shibuichi:roughness=0.2 (see 'kogei materials'); "
                        "default: the hawk's own materials, nami-shibuichi for a mesh file; for a mesh with per-face "
                        "materials only the faces without one")
    p.add_argument("--faults", action="append", default=[], metavar="SPEC",
                   help="faults switched on at start, DEVICE.NAME=VALUE[,...], e.g. "
                        "turntable.garbage_replies=3,profiler.corrupt_frames=2,camera.busy=1; repeatable")
    p.add_argument("--time-scale", type=float, default=1.0, metavar="S",
                   help="real seconds per simulated second of table motion (default 1; 0 = instant)")
    p.add_argument("--root", default=None, metavar="DIR",
                   help="folder for the ports, shim, hot folder and control folder (default: a temporary "
                        "folder removed at exit)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="seed of placements and noise (default 0)")
    actions = p.add_subparsers(dest="mock_action", metavar="ACTION", title="actions",
                               description="without an action, run the station until Ctrl-C")
    place = actions.add_parser("place", help="ask a running station to re-place the object",
                               description="Put the object of a running 'kogei mock' station in placement N; "
                                           "the next camera frame shows the colour chart.")
    place.add_argument("placement", nargs="?", type=int, default=None, metavar="N",
                       help=f"placement number >= 1 (default: the {PASS_ENV} environment variable)")
    place.add_argument("--control", required=True, metavar="DIR", help="the station's control folder")
    place.add_argument("--timeout", type=float, default=30.0, metavar="S", help="seconds to wait (default 30)")
    shoot = actions.add_parser("shoot", help="ask a running station to shoot a frame into its hot folder",
                               description="Have a running 'kogei mock' station write one frame into its hot "
                                           "folder, as a tethering program does when the shutter fires.")
    shoot.add_argument("--control", required=True, metavar="DIR", help="the station's control folder")
    shoot.add_argument("--timeout", type=float, default=60.0, metavar="S", help="seconds to wait (default 60)")
    return p


def capture_commands(info: dict[str, Any], steps: int = SCAN_STEPS, passes: int = 3,
                     session: str = "kogei-session", plan: str | None = None) -> dict[str, str]:
    """The ``kogei capture`` command lines for a station's ``info()``: with gphoto2 and with the hot folder.

    ``plan`` is the plan's options for a calibration target (``--plan camera-calibration`` for the
    board, ``--plan lamp-calibration --sphere-radius R`` for the mirror sphere): camera only, the
    plan's own steps and passes.  ``plan="sphere"`` is the scanner calibration's scan of the reference
    sphere (``--plan sphere-calibration``): one pass of :data:`SPHERE_STEPS` profiles without the camera (the
    gphoto2 line) or with photos of the sphere every 30 deg (the hot-folder line, for ``kogei calibrate --camera
    ... --scanner``); never a chart.

    Examples
    --------
    >>> info = {"turntable": "/s/turntable", "profiler": "/s/profiler", "gphoto2": "/s/bin/gphoto2",
    ...         "hotfolder": "/s/hot", "control": "/s/control"}
    >>> print(capture_commands(info, 8, 2, "out")["gphoto2"])
    kogei capture --turntable /s/turntable --laser /s/profiler --camera gphoto2:/s/bin/gphoto2 --steps 8 --passes 2 --camera-angles 0,90,180,270 --out out --unattended --before-pass 'kogei mock place --control /s/control'
    >>> print(capture_commands(info, session="board", plan="--plan camera-calibration")["gphoto2"])
    kogei capture --turntable /s/turntable --camera gphoto2:/s/bin/gphoto2 --plan camera-calibration --out board --unattended --before-pass 'kogei mock place --control /s/control'
    >>> print(capture_commands(info, session="cal", plan="sphere")["gphoto2"])
    kogei capture --plan sphere-calibration --turntable /s/turntable --laser /s/profiler --camera none --steps 90 --out cal --unattended
    """
    q = shlex.quote
    place = f"kogei mock place --control {q(info['control'])}"
    shoot = f"kogei mock shoot --control {q(info['control'])}"
    if plan == "sphere":
        common = f"--plan sphere-calibration --turntable {q(info['turntable'])} --laser {q(info['profiler'])}"
        tail = f"--steps {SPHERE_STEPS} --out {q(session)} --unattended"
        photos = ",".join(str(a) for a in range(0, 360, 30))
        return {
            "gphoto2": f"kogei capture {common} --camera none {tail}",
            "hotfolder": (f"kogei capture {common} --camera {q('hotfolder:' + info['hotfolder'])} "
                          f"--shutter {q(shoot)} --hotfolder-stable 0.2 --camera-angles {photos} {tail}"),
        }
    if plan:
        common = f"--turntable {q(info['turntable'])}"
        tail = f"{plan} --out {q(session)} --unattended --before-pass {q(place)}"
    else:
        common = f"--turntable {q(info['turntable'])} --laser {q(info['profiler'])}"
        tail = (f"--steps {steps} --passes {passes} --camera-angles {SCAN_CAMERA_ANGLES} --out {q(session)} "
                f"--unattended --before-pass {q(place)}")
    return {
        "gphoto2": f"kogei capture {common} --camera {q('gphoto2:' + info['gphoto2'])} {tail}",
        "hotfolder": (f"kogei capture {common} --camera {q('hotfolder:' + info['hotfolder'])} "
                      f"--shutter {q(shoot)} --hotfolder-stable 0.2 {tail}"),
    }


def _build_world(args: argparse.Namespace) -> Any:
    from mocks.turned_objects import TURNED_OBJECTS
    from mocks.world import World, WorldError, station_world_settings
    from processing.materials.presets import MaterialError, get_material

    if args.material is not None:
        try:
            get_material(args.material)
        except MaterialError as exc:
            raise UsageError(f"--material {args.material}: {exc}") from None
    if args.material is not None and args.world.split(":")[0] in ("board", "mirror-sphere", "probe"):
        raise UsageError(f"--material does not apply to --world {args.world} (a printed board or a chrome ball)")
    if args.triangles is not None and args.world != "hawk":
        raise UsageError("--triangles sets the size of the procedural hawk; it does not apply to a mesh file")
    try:
        if args.world == "hawk":
            n = 4_000 if args.triangles is None else args.triangles
            if n < 500:
                raise UsageError(f"--triangles must be at least 500, got {n}")
            world = World.hawk(n, **station_world_settings())
            if args.material is not None:
                world.materials = {name: args.material for name in world.region_names}
            return world
        if args.world in TURNED_OBJECTS:
            world = World.turned(args.world, **station_world_settings())
            if args.material is not None:
                world.materials = {name: args.material for name in world.region_names}
            return world
        if args.world == "sphere" or args.world.startswith("sphere:"):
            parts = args.world.split(":")[1:]
            try:
                radius = float(parts[0]) if parts and parts[0] else 25.0
                offset = float(parts[1]) if len(parts) > 1 else 60.0
            except ValueError:
                raise UsageError(f"--world {args.world}: use sphere, sphere:RADIUS_MM or "
                                 "sphere:RADIUS_MM:OFFSET_MM") from None
            return World.calibration_sphere(radius, offset, chart_first=False, **station_world_settings())   # a calibration scan takes no chart
        if args.world == "board" or args.world.startswith("board:"):
            return _board_world(args.world)
        if args.world == "mirror-sphere" or args.world.startswith("mirror-sphere:"):
            return _mirror_world(args.world)
        if args.world == "probe" or args.world.startswith("probe:"):
            return _probe_world(args.world)
        path = Path(args.world)
        if not path.is_file():
            raise UsageError(f"--world {args.world}: no such mesh file; give 'hawk' or the path of a "
                             "PLY/OBJ/STL/glTF mesh in millimetres")
        return World.from_mesh_file(path, args.material or "nami-shibuichi", **station_world_settings())
    except (WorldError, ValueError) as exc:
        if isinstance(exc, UsageError):
            raise
        raise UsageError(f"--world {args.world}: {exc}") from None


def _board_world(spec: str) -> Any:
    """``board`` or ``board:TILT`` (degrees, every placement on that wedge)."""
    from mocks.board_world import BoardWorld

    parts = spec.split(":")[1:]
    if len(parts) > 1:
        raise UsageError(f"--world {spec}: use board or board:TILT_DEG")
    if not parts or not parts[0]:
        return BoardWorld.charuco()
    try:
        tilt = float(parts[0])
    except ValueError:
        raise UsageError(f"--world {spec}: TILT must be a number of degrees in [0, 90), e.g. board:55") from None
    return BoardWorld.charuco(tilts_deg=(tilt,))


def _mirror_world(spec: str) -> Any:
    """``mirror-sphere``, ``mirror-sphere:R`` or ``mirror-sphere:R:OFF`` (mm)."""
    from mocks.mirror_world import MirrorWorld

    parts = spec.split(":")[1:]
    try:
        if len(parts) > 2:
            raise ValueError
        radius = float(parts[0]) if parts and parts[0] else 20.0
        offset = float(parts[1]) if len(parts) > 1 else 35.0
    except ValueError:
        raise UsageError(f"--world {spec}: use mirror-sphere, mirror-sphere:RADIUS_MM or "
                         "mirror-sphere:RADIUS_MM:OFFSET_MM") from None
    return MirrorWorld.mirror_sphere(radius, offset)


def _probe_world(spec: str) -> Any:
    """``probe``, ``probe:R`` (mm) or ``probe:R:filtered``: the chrome ball on the table centre in the simulated
    room; ``filtered``: every frame through the magenta notch filter (:data:`mocks.probe_world.PROBE_FILTER`), the
    second bracket set of a probe from two sets."""
    from mocks.probe_world import PROBE_FILTER, ProbeWorld

    parts = spec.split(":")[1:]
    try:
        if len(parts) > 2 or (len(parts) == 2 and parts[1] != "filtered"):
            raise ValueError
        radius = float(parts[0]) if parts and parts[0] else 20.0
    except ValueError:
        raise UsageError(f"--world {spec}: use probe, probe:RADIUS_MM or probe:RADIUS_MM:filtered") from None
    return ProbeWorld.probe(radius, lens_filter=PROBE_FILTER if len(parts) == 2 else None)


def _calibration_plan(world: Any) -> str | None:
    """The capture plan options a calibration target needs ("sphere" for the reference sphere, None to scan)."""
    from mocks.board_world import BoardWorld
    from mocks.mirror_world import MirrorWorld
    from mocks.probe_world import ProbeWorld

    if str(getattr(world, "mesh_source", "")).startswith("sphere:"):
        return "sphere"
    if isinstance(world, ProbeWorld):
        return f"--plan probe --sphere-radius {world.sphere_radius_mm:g}"
    if isinstance(world, BoardWorld):
        return "--plan camera-calibration"
    if isinstance(world, MirrorWorld):
        return f"--plan lamp-calibration --sphere-radius {world.sphere_radius_mm:g}"
    return None


def _session_name(plan: str | None, world: Any = None) -> str:
    """The ``--out`` folder of the printed capture command."""
    if getattr(world, "lens_filter", None):
        return "probe-filtered-session"
    if plan is None:
        return "kogei-session"
    return "calibration-session" if plan == "sphere" else plan.split()[1] + "-session"


def _next_command(world: Any, plan: str | None, filter_csv: Path | None = None) -> str:
    """The command that processes the printed capture's session (``filter_csv``: the lens filter's data sheet)."""
    if plan == "sphere":
        radius = world.mesh_source.split(":")[1]
        return f"kogei calibrate calibration-session --sphere-radius {radius}"
    if plan is None:
        return "kogei process kogei-session --calibration calibration-session   # after a kogei mock --world sphere scan"
    if plan.startswith("--plan camera-calibration"):
        return "kogei calibrate --camera camera-calibration-session --scanner calibration-session"
    if plan.startswith("--plan probe") and filter_csv is not None:
        return ("kogei probe probe-session --camera-calibration camera-calibration-session --filter-frames "
                f"probe-filtered-session --filter {filter_csv} --out probe.exr   # with a probe-session shot "
                "without the filter")
    if plan.startswith("--plan probe"):
        return "kogei probe probe-session --camera-calibration camera-calibration-session --out probe.exr"
    return "kogei calibrate --lamp lamp-calibration-session --camera-calibration camera-calibration-session"


def _print_block(info: dict[str, Any], faults: str) -> None:
    cmds = info["capture"]
    lines = [
        (f"kogei simulated station: world {info['world']}, seed {info['seed']}, "
         f"time scale {info['time_scale']:g}, faults {faults}"),
        f"  turntable port   {info['turntable']}",
        f"  profiler port    {info['profiler']}",
        f"  gphoto2 shim     {info['gphoto2']}",
        f"  hot folder       {info['hotfolder']}",
        f"  control folder   {info['control']}",
        f"  station file     {info['station_file']}",
        ("scan the sphere (profiles only):" if "--camera none" in cmds["gphoto2"] else
         "capture with the gphoto2 camera:"),
        f"  {cmds['gphoto2']}",
        ("or with photos of the sphere (to tie a calibrated camera to the scanner), through the hot folder:"
         if "--camera none" in cmds["gphoto2"] else "capture with the hot folder:"),
        f"  {cmds['hotfolder']}",
        "then:",
        f"  {info['then']}",
        "Ctrl-C stops the station.",
    ]
    print("\n".join(lines), flush=True)


def _write_station_file(path: Path, info: dict[str, Any]) -> None:
    with atomic_path(path, durable=False, make_parents=False) as tmp:
        tmp.write_text(json.dumps(info, indent=1), encoding="utf-8")


def _serve(args: argparse.Namespace) -> int:
    from mocks.station import (
        FaultSpecError,
        SimulatedStation,
        format_faults,
        parse_faults,
    )

    try:
        faults = parse_faults(args.faults)
    except FaultSpecError as exc:
        raise UsageError(f"--faults: {exc}") from None
    if not (args.time_scale >= 0 and args.time_scale < float("inf")):
        raise UsageError(f"--time-scale must be >= 0 (0 = instant motion), got {args.time_scale!r}")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if args.root is not None and Path(args.root).exists() and not Path(args.root).is_dir():
        raise UsageError(f"--root {args.root} exists and is not a folder; give a folder (created if missing)")
    world = _build_world(args)
    root = None if args.root is None else Path(args.root).resolve()   # the printed commands work from any folder
    station = SimulatedStation(world, root=root, seed=args.seed, time_scale=args.time_scale)
    station.apply_faults(faults)
    stop = threading.Event()
    in_main = threading.current_thread() is threading.main_thread()
    previous = {}
    if in_main:
        # SIGINT too: a station started in the background by a script has SIGINT ignored by its shell,
        # yet `kill -INT` must stop it as Ctrl-C does
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    station_file = station.root / "station.json"
    try:
        station.start()
        info = {**station.info(), "station_file": str(station_file), "pid": os.getpid(),
                "faults": format_faults(faults)}
        plan = _calibration_plan(world)
        filter_csv = None
        if getattr(world, "lens_filter", None):
            # the filter's data sheet, as the lab has it for a real filter
            from mocks.probe_world import write_filter_csv

            filter_csv = write_filter_csv(station.root / "lens-filter.csv", world.lens_filter)
        info["capture"] = capture_commands(info, plan=plan, session=_session_name(plan, world))
        info["then"] = _next_command(world, plan, filter_csv)
        _write_station_file(station_file, info)
        _print_block(info, format_faults(faults))
        try:
            while not stop.wait(0.2):
                pass
        except KeyboardInterrupt:
            pass
    finally:
        station.stop()
        if station_file.exists():
            station_file.unlink()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    print("kogei mock: station stopped", flush=True)
    return 0


def _client(args: argparse.Namespace) -> int:
    from mocks.station import StationError, request_place, request_shoot

    try:
        if args.mock_action == "place":
            n = args.placement
            if n is None:
                raw = os.environ.get(PASS_ENV)
                if raw is None or not raw.strip():
                    raise UsageError(f"no placement number: give N (kogei mock place N --control DIR) or set "
                                     f"{PASS_ENV}")
                try:
                    n = int(raw)
                except ValueError:
                    raise UsageError(f"{PASS_ENV}={raw!r} is not a placement number (an integer >= 1)") from None
            if n < 1:
                raise UsageError(f"placement must be an integer >= 1, got {n}")
            answer = request_place(args.control, n, args.timeout)
            print(f"kogei mock place: placement {answer['placement']}; the next frame shows the colour chart")
        else:
            answer = request_shoot(args.control, args.timeout)
            print(f"kogei mock shoot: {answer['kind']} frame {answer['file']} at "
                  f"{float(answer['table_angle_deg']):.4f} deg")
    except (StationError, ValueError) as exc:
        if isinstance(exc, UsageError):
            raise
        print(f"kogei mock {args.mock_action}: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    return 0


def run(args: argparse.Namespace) -> int:
    """Run ``kogei mock`` (the station), ``kogei mock place`` or ``kogei mock shoot``; the exit status.

    Raises
    ------
    UsageError
        A bad option (unknown fault, missing mesh file, bad placement, ...).
    """
    if getattr(args, "mock_action", None) in ("place", "shoot"):
        return _client(args)
    return _serve(args)


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m app.cli.mock ...``: the same as ``kogei mock ...``."""
    parser = argparse.ArgumentParser(prog="kogei")
    add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["mock", *(sys.argv[1:] if argv is None else argv)])
    try:
        return run(args)
    except InputError as exc:
        print(f"kogei mock: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("kogei mock: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
