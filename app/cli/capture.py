"""``kogei capture``: a capture session from the command line (a thin shell over :mod:`app.capture.runner`).

Exit status: 0 complete; 1 stopped by a device fault (the session is
resumable, the message says what to fix) or, unattended, a pass with
(nearly) no laser returns; 2 bad input; 130 stopped with Ctrl-C
(resumable too).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
from pathlib import Path
from typing import Any

from app.capture import defaults
from app.errors import UsageError

__all__ = ["add_parser", "run"]

EXIT_INTERRUPTED = 1
EXIT_CANCELLED = 130


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "capture",
        help="capture a session: profiles over full revolutions plus RAW frames (resumable)",
        description="Drive the turntable, the laser profiler and the camera into a new session folder, or "
                    "continue an interrupted one with --resume.",
    )
    p.add_argument("--out", metavar="SESSION", help="new session folder (this or --resume is required)")
    p.add_argument("--resume", metavar="SESSION", help="continue an interrupted session (plan and devices are "
                                                        "read from it; ports may be overridden)")
    p.add_argument("--turntable", metavar="PORT", help="turntable serial port (path or pyserial URL)")
    p.add_argument("--laser", metavar="PORT", help="laser profiler serial port")
    p.add_argument("--camera", metavar="SPEC",
                   help="gphoto2, gphoto2:PATH (the gphoto2 program to run), hotfolder:DIR or none (required with "
                        "--out)")
    p.add_argument("--plan", choices=["scan", "sphere-calibration", "swatch", "camera-calibration", "lamp-calibration", "probe"],
                   default="scan",
                   help="scan: profiles + RAW frames (default); sphere-calibration: one pass of profiles of the "
                        "reference sphere for kogei calibrate, no chart, RAW frames only at --camera-angles (the "
                        "sphere photos that tie the camera to the scanner); swatch: RAW frames at every step (cloth); "
                        "camera-calibration: a ChArUco board at every step, one pass per placement of the board "
                        "(flat, then on wedges); lamp-calibration: a mirror sphere at every step; probe: the "
                        "colour chart, then exposure brackets of a mirror sphere (a light probe, kogei probe)")
    p.add_argument("--brackets", default=None, metavar="T,T,...",
                   help="probe: the brackets' shutter speeds in seconds, as the camera names them (default "
                        "1/4000,1/1000,1/250,1/60,1/15,1/4,1: 7 frames 2 EV apart)")
    p.add_argument("--holdout-burst", type=int, default=None, metavar="N",
                   help="scan: shoot N frames at each held-out camera angle (every 4th angle, the frames "
                        "kogei fit-materials validates on; default 1); the validation averages them, so its "
                        "photos' noise falls as 1/sqrt(N).  Each extra frame costs one more exposure and "
                        "download at that angle (no table move) and one RAW file")
    p.add_argument("--steps", type=int, default=None, metavar="N",
                   help="table positions per revolution, evenly spaced (default 200, i.e. 1.8 deg apart; 12 for the "
                        "camera and lamp calibration plans)")
    p.add_argument("--passes", type=int, default=None, metavar="N",
                   help="placements of the object (default 3 for scan and camera-calibration, else 1)")
    p.add_argument("--camera-angles", default=None, metavar="DEG,DEG,...",
                   help="table angles of the RAW frames of each scan pass (default every 30 deg: 0,30,...,330); "
                        "sphere-calibration: the sphere photos to take (default none)")
    p.add_argument("--board", default=None, metavar="FILE.json",
                   help="camera-calibration: the ChArUco board's definition (dictionary, squares_x, squares_y, "
                        "square_mm, marker_mm); default a 7 x 5 board of 8 mm squares, DICT_5X5_100")
    p.add_argument("--sphere-radius", type=float, default=None, metavar="MM",
                   help="lamp-calibration and probe: the mirror sphere's radius (mm), recorded with the plan "
                        "(default: none recorded; give it to kogei calibrate --lamp or kogei probe instead)")
    p.add_argument("--no-chart", action="store_true", help="do not shoot a colour-chart frame first in each pass")
    p.add_argument("--object", default=None, metavar="NAME",
                   help="object name for the session metadata (default: none)")
    p.add_argument("--notes", default=None, metavar="TEXT", help="free text for the session metadata (default: none)")
    p.add_argument("--unattended", action="store_true",
                   help="no prompts (a simulated or automated station); see --before-pass and --shutter")
    p.add_argument("--before-pass", default=None, metavar="CMD",
                   help="command run before each pass instead of the placement prompt (env KOGEI_PASS, "
                        "KOGEI_PASSES, KOGEI_SESSION); e.g. 'kogei mock place --control DIR'")
    p.add_argument("--shutter", default=None, metavar="CMD",
                   help="command that fires the camera for a hot folder (env KOGEI_FRAME)")
    p.add_argument("--trust-hooks", action="store_true",
                   help="on --resume, run the commands stored in a session created by another user or machine "
                        "(--before-pass, --shutter, the gphoto2 program); without it they are shown and refused")
    p.add_argument("--steps-per-degree", type=float, default=None, metavar="STEPS",
                   help="turntable motor steps per degree of table rotation (default "
                        f"{defaults.STEPS_PER_DEGREE:.4g} = {360 * defaults.STEPS_PER_DEGREE:.0f} steps per "
                        "revolution, the Horus turntable's)")
    p.add_argument("--speed", type=float, default=None, metavar="DEG_S",
                   help=f"turntable speed in deg/s (default {defaults.SPEED_DEG_S:g})")
    p.add_argument("--exposure-us", type=int, default=None, metavar="US",
                   help=f"laser profiler exposure in microseconds (µs; default {defaults.EXPOSURE_US})")
    p.add_argument("--camera-timeout", type=float, default=None, metavar="S",
                   help=f"seconds to wait for each RAW frame before calling it a fault (default "
                        f"{defaults.CAMERA_TIMEOUT_S:g})")
    p.add_argument("--hotfolder-stable", type=float, default=None, metavar="S",
                   help=f"seconds a hot-folder file must keep its size before it is taken (default "
                        f"{defaults.HOTFOLDER_STABLE_S:g})")
    p.add_argument("--reconnect-timeout", type=float, default=30.0, metavar="S",
                   help="seconds to wait for an unplugged device to come back (default 30)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _positive(name: str, value: float | None) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise UsageError(f"{name} must be a positive number, got {value!r}")


def _camera_angles(text: str | None) -> tuple[float, ...] | None:
    from app.capture.runner import parse_camera_angles

    if text is None:
        return None
    try:
        return parse_camera_angles(text, "--camera-angles")
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _board_file(path: str) -> dict[str, Any]:
    """The ChArUco board definition in a small JSON file."""
    from processing.common.files import JSONFileError, parse_json

    try:
        with open(path, "rb") as f:
            blob = f.read(65536)
        data = parse_json(blob, f"--board {path}", "give the board's JSON file")
    except OSError as exc:
        raise UsageError(f"--board {path}: unreadable ({exc.strerror or exc}); give the board's JSON file") from None
    except JSONFileError as exc:
        raise UsageError(str(exc)) from None
    if not isinstance(data, dict):
        raise UsageError(f"--board {path}: must hold an object with dictionary, squares_x, squares_y, square_mm, "
                         "marker_mm")
    return data


def _new_session(args: argparse.Namespace) -> tuple[Any, Any, dict[str, Any]]:
    from app.capture.devices import check_command, check_device_config, creator_record, parse_camera_spec
    from app.capture.runner import PROFILE_KINDS, CapturePlan
    from app.session import Session

    if not args.turntable:
        raise UsageError("--turntable PORT is required (see 'kogei devices' for the ports)")
    if args.camera is None:
        raise UsageError("--camera is required: gphoto2, gphoto2:PATH, hotfolder:DIR or none")
    camera = parse_camera_spec(args.camera)
    if args.plan in PROFILE_KINDS and not args.laser:
        raise UsageError(f"--laser PORT is required for a {args.plan} (the laser profiler's port)")
    if args.plan == "sphere-calibration" and args.camera_angles and camera["kind"] == "none":
        raise UsageError("--camera-angles: the sphere photos need a camera; give --camera, or leave "
                         "--camera-angles out for profiles only")
    if args.plan not in PROFILE_KINDS and camera["kind"] == "none":
        raise UsageError(f"a {args.plan} capture takes only RAW frames: give --camera")
    for name in ("speed", "steps_per_degree", "camera_timeout", "hotfolder_stable", "reconnect_timeout"):
        _positive("--" + name.replace("_", "-"), getattr(args, name))
    angles = _camera_angles(args.camera_angles)
    kw: dict[str, Any] = {"kind": args.plan, "chart": False if args.no_chart else None,
                          "camera": camera["kind"] != "none"}
    if args.steps is not None:
        kw["steps"] = args.steps
    if args.passes is not None:
        kw["passes"] = args.passes
    if angles is not None:
        kw["camera_angles_deg"] = angles
    if args.board is not None:
        if args.plan != "camera-calibration":
            raise UsageError("--board is for --plan camera-calibration")
        kw["board"] = _board_file(args.board)
    if args.sphere_radius is not None:
        if args.plan not in ("lamp-calibration", "probe"):
            raise UsageError("--sphere-radius is for --plan lamp-calibration or probe")
        kw["sphere_radius_mm"] = args.sphere_radius
    if args.brackets is not None:
        if args.plan != "probe":
            raise UsageError("--brackets is for --plan probe")
        kw["brackets"] = tuple(b.strip() for b in args.brackets.split(",") if b.strip())
    if args.holdout_burst is not None:
        if args.plan != "scan":
            raise UsageError("--holdout-burst is for --plan scan (the held-out camera angles)")
        if not 1 <= args.holdout_burst <= 99:
            raise UsageError(f"--holdout-burst must be 1..99 frames per held-out angle, got {args.holdout_burst}")
        kw["holdout_burst"] = args.holdout_burst
    try:
        plan = CapturePlan(**kw)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if camera["kind"] == "gphoto2" and args.camera_timeout:
        camera["timeout_s"] = args.camera_timeout
    if camera["kind"] == "hotfolder":
        if not Path(camera["folder"]).is_dir():
            raise UsageError(f"--camera hotfolder:{camera['folder']}: the folder does not exist; create it and "
                             "point the tethering program at it")
        if args.hotfolder_stable:
            camera["stable_s"] = args.hotfolder_stable
        if args.camera_timeout:
            camera["timeout_s"] = args.camera_timeout
    config: dict[str, Any] = {"turntable": {"port": args.turntable}, "camera": camera}
    if args.steps_per_degree:
        config["turntable"]["steps_per_degree"] = args.steps_per_degree
    if args.speed:
        config["turntable"]["speed_deg_s"] = args.speed
    if args.plan in PROFILE_KINDS:
        config["profiler"] = {"port": args.laser}
        if args.exposure_us is not None:
            config["profiler"]["exposure_us"] = args.exposure_us
    settings = {"unattended": bool(args.unattended), "before_pass": args.before_pass, "shutter": args.shutter,
                "device_config": config, "created_by": creator_record()}
    check_device_config(config)
    check_command(args.before_pass, "--before-pass")
    check_command(args.shutter, "--shutter")
    obj = {k: v for k, v in (("name", args.object), ("notes", args.notes)) if v}
    session = Session.create(args.out, plan=plan.to_dict(), object_info=obj, settings=settings,
                             devices={k: dict(v) for k, v in config.items()})
    return session, plan, settings


def _check_trust(session: Any, settings: dict[str, Any], config: dict[str, Any], args: argparse.Namespace) -> None:
    """Refuse (exit 2) to run a foreign session's stored commands without ``--trust-hooks``; list them first."""
    from app.capture.devices import created_here, stored_commands

    stored = stored_commands(settings, config, before_pass=args.before_pass, shutter=args.shutter,
                             camera=args.camera)
    origin = settings.get("created_by")
    if not stored or args.trust_hooks or created_here(origin):
        return
    session.close()
    who = (f"{origin.get('user') or 'uid ' + str(origin.get('uid'))} on {origin.get('host')}"
           if isinstance(origin, dict) else "an unknown user or machine")
    print(f"session {args.resume} stores these commands:", file=sys.stderr)
    for cmd in stored:
        print(f"    {cmd}", file=sys.stderr)
    raise UsageError(f"session {args.resume} was created by {who}, and its stored commands are not run "
                     "unless you trust them: read them above, then resume with --trust-hooks (or give them "
                     "again on the command line)")


def _open_session(args: argparse.Namespace) -> tuple[Any, Any, dict[str, Any]]:
    from app.capture.devices import check_command, check_device_config, parse_camera_spec
    from app.capture.runner import open_for_resume

    session, plan, settings, config = open_for_resume(args.resume)
    _check_trust(session, settings, config, args)
    if args.turntable:
        config.setdefault("turntable", {})["port"] = args.turntable
    if args.laser:
        config.setdefault("profiler", {})["port"] = args.laser
    if args.camera:
        config["camera"] = parse_camera_spec(args.camera)
    for key in ("before_pass", "shutter"):
        if getattr(args, key):
            settings[key] = getattr(args, key)
    if args.unattended:
        settings["unattended"] = True
    settings["device_config"] = config
    try:
        check_device_config(config)
        for key in ("before_pass", "shutter"):
            check_command(settings.get(key), "--" + key.replace("_", "-"))
    except UsageError:
        session.close()
        raise
    session.update("settings", settings)
    return session, plan, settings


def _hooks(session: Any, plan: Any, settings: dict[str, Any], cancel: threading.Event, quiet: bool):
    from app.capture.devices import run_hook_command
    from app.capture.runner import CaptureHooks, CaptureInterrupted, placement_prompt

    unattended = bool(settings.get("unattended"))
    env = {"KOGEI_SESSION": str(session.root), "KOGEI_PASSES": str(plan.passes)}

    def before_pass(p: int, passes: int) -> None:
        if settings.get("before_pass"):
            try:
                run_hook_command(settings["before_pass"], "--before-pass", {**env, "KOGEI_PASS": str(p)})
            except RuntimeError as exc:
                raise CaptureInterrupted(f"{exc}\nThe session {session.root} is intact; fix the command and run: "
                                         f"kogei capture --resume {session.root}", session=session.root,
                                         reason="error") from None
            return
        if unattended:
            return
        what = placement_prompt(plan.kind, p)
        chart = " and put the colour chart in view of the camera" if plan.camera and plan.chart else ""
        answer = input(f"\nPass {p} of {passes}: {what}{chart}.\nPress Enter to start, or q and Enter to stop: ")
        if answer.strip().lower().startswith("q"):
            raise CaptureInterrupted(f"stopped before pass {p}; resume with: kogei capture --resume {session.root}",
                                     session=session.root, reason="cancelled")

    def after_chart(p: int) -> None:
        if not unattended and not settings.get("before_pass"):
            input("Chart frame taken. Remove the chart from the view, then press Enter: ")

    def low_return(p: int, share: float, text: str) -> None:
        if unattended or settings.get("before_pass"):
            return
        answer = input(f"\nWarning: {text}.\nPress Enter to go on anyway, or q and Enter to stop: ")
        if answer.strip().lower().startswith("q"):
            raise CaptureInterrupted(f"stopped after pass {p} (no laser line); fix the laser, then resume with: "
                                     f"kogei capture --resume {session.root}", session=session.root,
                                     reason="cancelled")

    def message(text: str) -> None:
        if not quiet:
            print(f"  note: {text}", file=sys.stderr)

    return CaptureHooks(before_pass=before_pass, after_chart=after_chart, low_return=low_return, message=message,
                        cancel=cancel)


def _shutter(settings: dict[str, Any], session_root: Path):
    from app.capture.devices import run_hook_command

    cmd = settings.get("shutter")
    if not cmd:
        if settings.get("unattended"):
            return None
        return lambda: print("  fire the camera now (waiting for the frame in the hot folder)", file=sys.stderr)
    return lambda: run_hook_command(cmd, "--shutter", {"KOGEI_SESSION": str(session_root)})


def run(args: argparse.Namespace) -> int:
    from app.capture.devices import build_devices
    from app.capture.runner import CaptureInterrupted, CaptureSettings, run_capture

    if bool(args.out) == bool(args.resume):
        raise UsageError("give either --out SESSION (a new session) or --resume SESSION")
    if args.out and not args.unattended and not args.before_pass and not sys.stdin.isatty():
        raise UsageError("standard input is not a terminal, so the placement prompts cannot be answered; "
                         "use --unattended (with --before-pass CMD to place the object) or run in a terminal")
    session, plan, settings = _new_session(args) if args.out else _open_session(args)
    if not settings.get("unattended") and not settings.get("before_pass") and not sys.stdin.isatty():
        session.close()
        raise UsageError("standard input is not a terminal, so the placement prompts cannot be answered; "
                         "resume with --unattended (and --before-pass CMD to place the object) or in a terminal")
    cancel = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        if cancel.is_set():
            signal.signal(signal.SIGINT, signal.default_int_handler)
            raise KeyboardInterrupt
        cancel.set()
        print("\nstopping after the current step (Ctrl-C again to stop at once)", file=sys.stderr)

    old_int = signal.signal(signal.SIGINT, on_signal)
    old_term = signal.signal(signal.SIGTERM, on_signal)
    hooks = _hooks(session, plan, settings, cancel, args.quiet)
    reported = False
    try:
        devices = build_devices(settings["device_config"], session.root, _shutter(settings, session.root))
        with _progress(args.quiet) as show:
            hooks.progress = show
            report = run_capture(session, plan, devices, hooks,
                                 CaptureSettings(reconnect_timeout_s=args.reconnect_timeout))
    except CaptureInterrupted as exc:
        reported = True                             # its line already says how to resume
        print(f"kogei capture: {exc}", file=sys.stderr)
        return EXIT_CANCELLED if exc.reason == "cancelled" else EXIT_INTERRUPTED
    except KeyboardInterrupt:
        reported = True
        print(f"kogei capture: stopped; the session is resumable: kogei capture --resume {session.root}",
              file=sys.stderr)
        return EXIT_CANCELLED
    except ValueError as exc:
        if isinstance(exc.__cause__, OSError):      # a wire log that cannot be written: a full disk
            raise _disk_message(session.root, exc.__cause__) from None
        raise UsageError(str(exc)) from None
    except OSError as exc:
        raise _disk_message(session.root, exc) from None
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
        closed = _close(session, quiet=reported or sys.exc_info()[0] is not None)
    if not closed:                                  # a full disk at the end: said in one line; not "complete"
        return 2
    print(f"session {report.session}: complete; {report.taken} captures taken, {report.skipped} already held, "
          f"{len(report.recoveries)} recoveries, {report.elapsed_s:.1f} s")
    for text in report.warnings:
        print(f"  warning: {text}", file=sys.stderr)
    if report.warnings and settings.get("unattended"):
        print(f"kogei capture: {len(report.warnings)} pass(es) of {report.session} have (nearly) no laser "
              "returns (valid_share in the manifest); check the laser before processing", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0


def _disk_message(root: Path, exc: OSError) -> Exception:
    """The one-line "free space / make it writable, then resume" error for ``exc`` while writing ``root``."""
    from app.session import disk_error

    return disk_error(root, f"write {exc.filename or 'a file'}", exc)


def _close(session: Any, quiet: bool = False) -> bool:
    """Close the session; a failure (a full disk) is reported in one line, its journal keeps the captures.

    With ``quiet`` (an error is already being reported) a failure to close adds no second line.
    Returns whether the session was closed cleanly.
    """
    from app.session import SessionError

    try:
        session.close()
    except (SessionError, OSError) as exc:
        if quiet:
            return False
        reason = exc.strerror if isinstance(exc, OSError) else str(exc).split(": ", 2)[-1].split(";")[0]
        print(f"kogei capture: session {session.root}: every capture is taken and kept in its journal, but "
              f"session.json could not be saved ({reason}): free space or make the folder writable, then run "
              f"'kogei report {session.root}' (or any command on the session) to save it", file=sys.stderr)
        return False
    return True


class _progress:
    """A rich progress bar with ETA on a terminal; a line per 10% otherwise."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self._bar = None
        self._task = None
        self._last_decile = -1

    def __enter__(self):
        if not self.quiet and sys.stderr.isatty():
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            self._bar = Progress(TextColumn("{task.description}"), BarColumn(),
                                 TextColumn("{task.completed}/{task.total}"), TimeRemainingColumn(),
                                 transient=False)
            self._bar.__enter__()
        return self.update

    def update(self, p: Any) -> None:
        if self.quiet:
            return
        if self._bar is not None:
            if self._task is None:
                self._task = self._bar.add_task("capture", total=p.total)
            # the total grows when a pass's earlier captures are taken again (the table's angle was lost)
            self._bar.update(self._task, completed=p.done, total=p.total, description=f"pass {p.pass_no}: {p.action}")
            return
        decile = int(10 * p.done / p.total)
        if decile != self._last_decile or p.done == p.total:
            self._last_decile = decile
            eta = f", about {p.eta_s:.0f} s left" if p.eta_s is not None and p.done < p.total else ""
            print(f"capture: {p.done}/{p.total} ({100 * p.done / p.total:.0f}%) pass {p.pass_no}{eta}",
                  file=sys.stderr)

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.__exit__(None, None, None)
