"""``kogei calibrate``: the station's scanner, camera and lamp calibrations from calibration sessions.

Shells over :func:`app.workflows.calibration.calibrate_session` (the scanner,
from a sphere scan), :func:`app.workflows.station_calibration.calibrate_camera_session`
(``--camera``: a ChArUco board session tied to the scanner by the sphere
session's photos) and :func:`app.workflows.station_calibration.calibrate_lamp_session`
(``--lamp``: a mirror-sphere session).  Scan sessions use the results with
``kogei process SESSION --calibration SPHERE_SESSION --camera-calibration
BOARD_SESSION --lamp-calibration LAMP_SESSION``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from app.errors import UsageError

__all__ = ["add_parser", "run"]


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="scanner, camera or lamp calibration from a calibration session",
                       description="Scanner: fit the laser plane's pose relative to the table axis from one pass of "
                                   "a sphere of known radius (kogei calibrate SPHERE_SESSION --sphere-radius MM).  "
                                   "Camera: intrinsics and pose in the table frame from a camera-calibration "
                                   "session (kogei calibrate --camera BOARD_SESSION --scanner SPHERE_SESSION).  "
                                   "Lamps: positions or directions from a lamp-calibration session (kogei calibrate "
                                   "--lamp LAMP_SESSION --camera-calibration BOARD_SESSION).  Each result is stored "
                                   "in the session it was fitted from.")
    p.add_argument("session", metavar="SESSION", nargs="?", help="the sphere session (scanner calibration)")
    p.add_argument("--sphere-radius", type=float, default=None, metavar="MM",
                   help="radius of the reference sphere (mm, from its certificate); for --lamp: of the mirror "
                        "sphere (default: the plan's)")
    p.add_argument("--sphere-height", type=float, default=None, metavar="MM",
                   help="height of the sphere's centre above the table (mm) if the table top is not in view "
                        "(a sphere resting on the table: its radius) (default: measured on the table top in the scan)")
    p.add_argument("--pass", dest="pass_no", type=int, default=1, metavar="N", help="which pass to use (default 1)")
    cam = p.add_argument_group("camera (--camera)")
    cam.add_argument("--camera", metavar="BOARD_SESSION", default=None,
                     help="calibrate the camera from this camera-calibration session")
    cam.add_argument("--scanner", metavar="SPHERE_SESSION", default=None,
                     help="the scanner-calibrated sphere session whose photos of the sphere tie the camera to the "
                          "scanner's frame (required with --camera)")
    cam.add_argument("--focal-mm", type=float, default=None, metavar="MM",
                     help="manual start: the lens's focal length (mm), with --sensor-mm (default: found from the board "
                          "views alone)")
    cam.add_argument("--sensor-mm", type=float, default=None, metavar="MM",
                     help="manual start: the sensor's width (mm), with --focal-mm (default: found from the board views "
                          "alone)")
    cam.add_argument("--max-rms", type=float, default=1.0, metavar="PX",
                     help="refuse a calibration whose reprojection RMS is above this (px, default 1.0)")
    lamp = p.add_argument_group("lamps (--lamp)")
    lamp.add_argument("--lamp", metavar="LAMP_SESSION", default=None,
                      help="locate the lamps from this lamp-calibration session")
    lamp.add_argument("--camera-calibration", metavar="BOARD_SESSION|FILE.json", default=None,
                      help="the camera calibration to use (required with --lamp)")
    lamp.add_argument("--lamp-model", choices=["auto", "point", "distant"], default="auto",
                      help="point lamp, distant lamp, or decide from the rays (default auto)")
    lamp.add_argument("--lamps", type=int, default=None, metavar="N",
                      help="number of lamps (default: the most highlights seen in one frame)")
    lamp.add_argument("--lamp-spectrum", default=None, metavar="NAME|CCT",
                      help="the lamps' spectrum: a name (D65, A, ...) or a correlated colour temperature in K (default: "
                          "not recorded)")
    p.add_argument("--decode", choices=["demosaic", "bin2x2"], default="demosaic",
                   help="how RAW frames are decoded for --camera and --lamp (default demosaic: full resolution)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _say(text: str) -> None:
    print(f"  {text}", file=sys.stderr)


#: Options that belong to one mode only (a given option of another mode is refused, not ignored).
_ONLY = {"camera": (("scanner", "--scanner"), ("focal_mm", "--focal-mm"), ("sensor_mm", "--sensor-mm")),
         "lamp": (("camera_calibration", "--camera-calibration"), ("lamps", "--lamps"),
                  ("lamp_spectrum", "--lamp-spectrum")),
         "scanner": (("session", "SESSION"), ("sphere_height", "--sphere-height"))}
_MODE = {"camera": "--camera BOARD_SESSION", "lamp": "--lamp LAMP_SESSION", "scanner": "SESSION --sphere-radius MM"}


def _check_mode_options(args: argparse.Namespace, mode: str) -> None:
    """Refuse options of another mode than ``mode`` (``camera``, ``lamp`` or ``scanner``)."""
    for other, options in _ONLY.items():
        if other == mode:
            continue
        for attr, flag in options:
            if getattr(args, attr) is not None:
                raise UsageError(f"{flag} is for {_MODE[other]}, not for {_MODE[mode]}: leave it out or run the "
                                 f"{other} calibration separately")


def run(args: argparse.Namespace) -> int:
    if args.camera and args.lamp:
        raise UsageError("give --camera or --lamp, not both: calibrate the camera first, then the lamps with it")
    _check_mode_options(args, "camera" if args.camera else "lamp" if args.lamp else "scanner")
    if args.camera:
        if not args.scanner:
            raise UsageError("--camera needs --scanner SPHERE_SESSION: the scanner-calibrated sphere session whose "
                             "photos tie the camera to the turntable")
        from app.workflows.station_calibration import calibrate_camera_session

        ref = calibrate_camera_session(args.camera, args.scanner, focal_mm=args.focal_mm, sensor_mm=args.sensor_mm,
                                       max_rms_px=args.max_rms, decode=args.decode, message=_say)
        text = (f"calibrated the camera from {args.camera}: reprojection rms {ref['rms_px']:.3f} px "
                f"-> {Path(args.camera) / ref['path']}")
    elif args.lamp:
        if not args.camera_calibration:
            raise UsageError("--lamp needs --camera-calibration BOARD_SESSION (a calibrated camera)")
        from app.workflows.station_calibration import calibrate_lamp_session

        ref = calibrate_lamp_session(args.lamp, args.camera_calibration, sphere_radius_mm=args.sphere_radius,
                                     model=args.lamp_model, n_lamps=args.lamps, spectrum=args.lamp_spectrum,
                                     decode=args.decode, message=_say)
        text = f"located {ref['lamps']} lamp(s) from {args.lamp} -> {Path(args.lamp) / ref['path']}"
    else:
        if not args.session or args.sphere_radius is None:
            raise UsageError("give SESSION --sphere-radius MM (scanner), --camera BOARD_SESSION --scanner "
                             "SPHERE_SESSION (camera) or --lamp LAMP_SESSION --camera-calibration BOARD_SESSION "
                             "(lamps)")
        from app.workflows.calibration import calibrate_session

        ref = calibrate_session(args.session, args.sphere_radius, sphere_height_mm=args.sphere_height,
                                pass_no=args.pass_no)
        text = (f"calibrated {args.session}: sphere residual rms {ref['rms_mm']:.4f} mm, max {ref['max_mm']:.4f} mm "
                f"-> {Path(args.session) / ref['path']}")
    print(json.dumps(ref, indent=1) if args.json else text)
    return 0
