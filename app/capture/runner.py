"""The capture session: turntable, laser profiler and camera driven into a session, resumably.

See ``docs/session-format.md``.  A :class:`CapturePlan` expands into a fixed, ordered list of actions per pass,
each with a stable id (``p01/chart``, ``p01/profile/0042``,
``p01/frame/03``).  :func:`run_capture` performs the actions that the
session does not already hold (recorded *and* with an intact file), so an
interrupted capture continues with no missing and no duplicated step, however
it stopped (a device fault, Ctrl-C, ``kill -9``, a power cut).

Per pass of a ``scan`` plan: the object is placed (a hook: a prompt at the
station, a command in an unattended run), the table is zeroed, the chart
frame is shot (lasers off), then one full revolution of ``steps`` profiles
with the lasers re-asserted on every step; RAW frames are shot (lasers off)
at the camera angles, each snapped to the nearest step.  A ``sphere-calibration`` plan is one pass
of profiles of the reference sphere for the scanner calibration: no chart, and RAW frames only at the camera
angles it is given (the photos that tie the camera to the scanner; none by default).  A ``swatch`` plan
(a flat fabric sample, Yasuda et al. section 4) shoots only RAW frames, at
every step angle.  A ``probe`` plan shoots the chart, then exposure brackets of a
mirror sphere at one table angle, setting each frame's shutter speed first (a light probe,
docs/lighting.md; each frame's record keeps its ``shutter``).  At the end of a pass its profiles are gathered into one
``profiles.npz`` (``angles_deg``, ``x_mm``, ``z_mm``; NaN = no return).

Device faults are recovered where that is safe -- a vanished port is
reopened (waiting up to ``reconnect_timeout_s`` for the cable), a lost or
corrupted reply or frame is re-requested by the drivers, a reset device is
restored, a busy camera is retried, a profile with no return at all is
re-taken once after re-asserting the lasers (the firmware's laser watchdog)
-- and otherwise stop the capture with :class:`CaptureInterrupted`, whose
message names the device and what to do; the session is left consistent
and resumable in every case, and the lasers are switched off and the motor
released on any exit.

Resuming knows the table's angle: the session journals the target before
every move and the confirmed angle after it; on resume the firmware's own
position counter is read (``?``) before the board is reset, and the angle
is taken from it when it agrees with the journal.  If the board lost its
counter while a move was in flight (or a reset reached it before the move's
end could be heard), the table's angle is known only to within that move:
its confirmed angle becomes the zero of a new *table frame* of the pass
(``table_frame`` in the pass record, counted from 0, and in each profile's
and frame's record), and every profile and frame of the pass taken in an
earlier frame is taken again in the new one once the pass's other steps are
done -- all of a pass's data then share one zero, as registration assumes
(it places each pass as one rigid whole).
"""

from __future__ import annotations

import math
import os
import secrets
import shutil
import stat
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from app.session import Session, SessionError, check_regular_file, session_path, utc_now
from drivers.camera_errors import (
    CameraBadFrameError,
    CameraBusyError,
    CameraError,
    CameraTimeoutError,
)
from drivers.camera_hotfolder import raw_format_problem
from drivers.errors import (
    DeviceAlarm,
    DeviceError,
    DeviceTimeout,
    DriverError,
    TransportClosed,
    TransportError,
)
from processing.common.files import sha256_file

__all__ = [
    "PLAN_KINDS",
    "PROFILE_KINDS",
    "CAMERA_ONLY_KINDS",
    "CALIBRATION_KINDS",
    "DEFAULT_BOARD",
    "DEFAULT_CAMERA_ANGLES_DEG",
    "CapturePlan",
    "Action",
    "Shooter",
    "CaptureDevices",
    "CaptureHooks",
    "CaptureSettings",
    "CaptureProgress",
    "CaptureReport",
    "CaptureInterrupted",
    "run_capture",
    "load_pass_profiles",
    "ProfilesFileError",
    "parse_camera_angles",
    "placement_prompt",
    "open_for_resume",
    "keep_orphans",
    "check_not_linked",
    "MIN_VALID_SHARE",
]

PLAN_KINDS = ("scan", "sphere-calibration", "swatch", "camera-calibration", "lamp-calibration", "probe")
#: Plans that take laser profiles over a revolution (they need the profiler).
PROFILE_KINDS = ("scan", "sphere-calibration")
#: Plans that take only RAW frames, one at every step angle of each pass (no profiles).
CAMERA_ONLY_KINDS = ("swatch", "camera-calibration", "lamp-calibration", "probe")
#: Plans that calibrate the station (no colour chart by default).
CALIBRATION_KINDS = ("sphere-calibration", "camera-calibration", "lamp-calibration")
#: The ChArUco board a camera-calibration plan uses unless told otherwise (lengths in mm).
DEFAULT_BOARD = {"dictionary": "DICT_5X5_100", "squares_x": 7, "squares_y": 5, "square_mm": 8.0, "marker_mm": 6.0}
#: Table angles of a scan pass's RAW frames: every 30 deg, so a metal's highlights sweep its surface.
DEFAULT_CAMERA_ANGLES_DEG = tuple(float(a) for a in range(0, 360, 30))
#: Steps and passes per plan kind when not given.
_DEFAULT_STEPS = {"scan": 200, "sphere-calibration": 200, "swatch": 200, "camera-calibration": 12, "lamp-calibration": 12, "probe": 1}
_DEFAULT_PASSES = {"scan": 3, "sphere-calibration": 1, "swatch": 1, "camera-calibration": 3, "lamp-calibration": 1, "probe": 1}
#: Shutter speeds of a probe plan's brackets (gphoto2's ``shutterspeed`` values): 7 frames 2 EV apart.
PROBE_BRACKETS = ("1/4000", "1/1000", "1/250", "1/60", "1/15", "1/4", "1")


def shutter_seconds(value: str) -> float:
    """Seconds of a shutter-speed setting such as ``"1/250"``, ``"0.5"`` or ``"2"``.

    >>> shutter_seconds("1/250"), shutter_seconds("2")
    (0.004, 2.0)
    """
    num, _, den = str(value).strip().partition("/")
    try:
        seconds = float(num) / float(den) if den else float(num)
    except (ValueError, ZeroDivisionError):
        seconds = math.nan
    if not (math.isfinite(seconds) and 0 < seconds <= 3600):
        raise ValueError(f"{value!r} is not a shutter speed (e.g. 1/250, 0.5 or 2 seconds)")
    return seconds
#: A pass whose share of profiles with a laser return is below this is suspect (laser never on?).
MIN_VALID_SHARE = 0.05
STAGING = ".incoming"
ORPHANS = "orphans"


class CaptureInterrupted(RuntimeError):
    """The capture stopped before the plan was complete; the session is consistent and resumable.

    Attributes
    ----------
    session
        The session directory.
    reason
        ``"device"`` (a fault that could not be recovered), ``"cancelled"``
        (the user stopped it) or ``"error"`` (anything else).
    """

    def __init__(self, message: str, *, session: Path, reason: str = "device") -> None:
        super().__init__(message)
        self.session = session
        self.reason = reason


class ProfilesFileError(SessionError):
    """A pass's ``profiles.npz`` that passes its checksum but is not profiles; the message names it and says what to do."""


# ---------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class Action:
    """One step of a plan.

    ``kind`` is ``"chart"`` (the colour-chart frame), ``"profile"`` or
    ``"frame"`` (a RAW frame of the object) or ``"burst"`` (a further frame of a held-out
    frame's burst, ``shot`` 1, 2, ...: the same view again with its own sensor noise, for the
    held-out validation only); ``angle_deg`` is the table angle within the pass; ``shutter`` the
    shutter speed to set first (a probe's brackets), else None.
    """

    id: str
    kind: str
    pass_no: int
    index: int
    angle_deg: float
    shutter: str | None = None
    shot: int = 0

    @property
    def stem(self) -> str:
        """File stem of the action's file."""
        if self.kind == "chart":
            return "chart" if self.id.endswith("/chart") else f"chart_{self.index:02d}"
        if self.kind == "frame":
            return f"frame_{self.index:02d}"
        if self.kind == "burst":
            return f"frame_{self.index:02d}_burst_{self.shot:02d}"
        return f"{self.index:04d}"


@dataclass(frozen=True)
class CapturePlan:
    """What a capture session takes.

    Parameters
    ----------
    kind
        ``"scan"`` (profiles over a revolution plus RAW frames),
        ``"sphere-calibration"`` (one pass of profiles of the reference sphere for
        the scanner calibration, no chart; RAW frames only at the camera angles
        given, the sphere photos that tie the camera to the scanner),
        ``"swatch"`` (RAW frames at every step angle, no profiles: a cloth
        swatch), ``"camera-calibration"`` (RAW frames of a ChArUco board at
        every step angle; one pass per placement of the board, flat or on a
        wedge), ``"lamp-calibration"`` (RAW frames of a mirror sphere at
        every step angle) or ``"probe"`` (exposure brackets of a mirror sphere in
        the light to be measured, after the chart: docs/lighting.md).
    steps
        Table positions per revolution (equal angles from 0); default 200
        for ``scan``, ``sphere-calibration`` and ``swatch``, 12 for the
        camera and lamp calibrations.
    passes
        Placements of the object (re-placed by hand between passes);
        default 3 for ``scan`` and ``camera-calibration``, 1 otherwise.
    camera_angles_deg
        Table angles of the RAW frames of a ``scan`` or ``sphere-calibration``
        pass (snapped to the nearest step; default every 30 deg for a scan,
        none for a sphere calibration); ignored by the other kinds.
    chart
        Shoot the colour-chart frame first in every pass (default: yes,
        except for the calibration plans).
    lasers
        Turntable laser outputs to switch on while profiling (the laser
        line's power); they are off for every camera frame.
    camera
        False for a profiles-only scan (no camera frames, no chart).  A
        ``sphere-calibration`` plan with no camera angles needs no camera
        and is stored with ``camera`` False.
    chart_frames
        Chart frames per pass, their gains averaged by the fit (default 16
        for ``swatch``, whose fit is limited by the chart's pixel noise:
        docs/cloth.md; 1 for ``scan``).  One frame has the id ``pNN/chart``; several have
        ``pNN/chart/00``, ``pNN/chart/01``, ...
    board
        The ChArUco board of a ``camera-calibration`` plan (dictionary,
        squares, square and marker sizes in mm; default
        :data:`DEFAULT_BOARD`), stored with the plan in the session.
    sphere_radius_mm
        Radius of a ``lamp-calibration`` or ``probe`` plan's mirror sphere (mm), if known
        when capturing.
    brackets
        Shutter speeds of a ``probe`` plan's frames (default :data:`PROBE_BRACKETS`).
    holdout_burst
        Frames shot at each held-out camera angle of a ``scan`` (default 1: no burst).  The
        held-out angles are those the material fit leaves out for the validation: of the distinct
        camera angles ranked ascending, ranks ``holdout_every // 2``, ``holdout_every // 2 +
        holdout_every``, ... (``app.workflows.holdout_validation.holdout_frames``).  The first
        frame is the ordinary ``pNN/frame/KK``; the others are ``pNN/frame/KK/burst/01``, ...
        (kind ``"burst"``, ignored by posing and fitting) and the validation averages them
        with it in linear RAW, so the photo's noise falls as 1/sqrt(N).  Each extra frame costs
        one exposure and download (about as long as any other frame; no table move) and a RAW
        file's disk space.
    holdout_every
        One camera angle in ``holdout_every`` is held out (>= 2, default 4); used only with a burst.

    Examples
    --------
    >>> plan = CapturePlan("scan", steps=8, passes=2, camera_angles_deg=(0.0, 180.0))
    >>> [a.id for a in plan.pass_actions(1)][:4]
    ['p01/chart', 'p01/profile/0000', 'p01/frame/00', 'p01/profile/0001']
    >>> len(plan.actions())
    22
    >>> [a.id for a in CapturePlan("swatch", steps=2, passes=1, chart_frames=2).actions()]
    ['p01/chart/00', 'p01/chart/01', 'p01/frame/00', 'p01/frame/01']
    >>> sphere = CapturePlan("sphere-calibration", steps=4)
    >>> [a.id for a in sphere.actions()], sphere.camera
    (['p01/profile/0000', 'p01/profile/0001', 'p01/profile/0002', 'p01/profile/0003'], False)
    >>> burst = CapturePlan("scan", steps=4, passes=1, camera_angles_deg=(0.0, 90.0, 180.0, 270.0),
    ...                     chart=False, holdout_burst=3)
    >>> [a.id for a in burst.actions() if a.kind != "profile"]
    ['p01/frame/00', 'p01/frame/01', 'p01/frame/02', 'p01/frame/02/burst/01', 'p01/frame/02/burst/02', 'p01/frame/03']
    """

    kind: str = "scan"
    steps: int | None = None
    passes: int | None = None
    camera_angles_deg: tuple[float, ...] | None = None
    chart: bool | None = None
    lasers: tuple[int, ...] = (1,)
    camera: bool = True
    chart_frames: int | None = None
    board: dict[str, Any] | None = None
    sphere_radius_mm: float | None = None
    brackets: tuple[str, ...] | None = None
    holdout_burst: int = 1
    holdout_every: int = 4

    def __post_init__(self) -> None:
        if self.kind not in PLAN_KINDS:
            raise ValueError(f"plan kind must be one of {', '.join(PLAN_KINDS)}, got {self.kind!r}")
        self._resolve_defaults()
        if not isinstance(self.steps, int) or isinstance(self.steps, bool) or not 1 <= self.steps <= 100_000:
            raise ValueError(f"steps must be an integer in 1..100000 (table positions per revolution), got {self.steps!r}")
        if not isinstance(self.passes, int) or isinstance(self.passes, bool) or not 1 <= self.passes <= 99:
            raise ValueError(f"passes must be an integer in 1..99, got {self.passes!r}")
        angles = tuple(float(a) for a in self.camera_angles_deg)
        if not all(math.isfinite(a) for a in angles):
            raise ValueError(f"camera angles must be finite degrees, got {self.camera_angles_deg!r}")
        object.__setattr__(self, "camera_angles_deg", angles)
        object.__setattr__(self, "lasers", tuple(int(i) for i in self.lasers))
        if self.kind in CAMERA_ONLY_KINDS and not self.camera:
            raise ValueError(f"a {self.kind} plan needs the camera (it takes only RAW frames)")
        if self.chart_frames is None:
            object.__setattr__(self, "chart_frames", 16 if self.kind == "swatch" else 1)
        if not isinstance(self.chart_frames, int) or isinstance(self.chart_frames, bool) or \
                not 1 <= self.chart_frames <= 99:
            raise ValueError(f"chart_frames must be an integer in 1..99 (chart frames per pass), "
                             f"got {self.chart_frames!r}")
        for name, value, low in (("holdout_burst", self.holdout_burst, 1), ("holdout_every", self.holdout_every, 2)):
            if not isinstance(value, int) or isinstance(value, bool) or not low <= value <= 99:
                raise ValueError(f"{name} must be an integer in {low}..99, got {value!r}")
        if self.holdout_burst > 1 and self.kind != "scan":
            raise ValueError(f"holdout_burst is for a scan plan's held-out camera angles, not {self.kind!r}")

    def _resolve_defaults(self) -> None:
        """Fill the per-kind defaults and check the calibration plans' own fields."""
        if self.steps is None:
            object.__setattr__(self, "steps", _DEFAULT_STEPS[self.kind])
        if self.passes is None:
            object.__setattr__(self, "passes", _DEFAULT_PASSES[self.kind])
        if self.chart is None:
            object.__setattr__(self, "chart", self.kind not in CALIBRATION_KINDS)
        if self.camera_angles_deg is None:
            object.__setattr__(self, "camera_angles_deg",
                               () if self.kind == "sphere-calibration" else DEFAULT_CAMERA_ANGLES_DEG)
        if self.kind == "sphere-calibration":
            if self.chart:
                raise ValueError("a sphere-calibration plan takes no colour-chart frame (the scanner calibration "
                                 "reads only the profiles); leave the chart out")
            if not self.camera_angles_deg:         # no photos of the sphere: the camera is not needed
                object.__setattr__(self, "camera", False)
        if self.kind == "camera-calibration":
            board = dict(DEFAULT_BOARD if self.board is None else self.board)
            if set(board) != set(DEFAULT_BOARD):
                raise ValueError(f"board must have exactly the fields {', '.join(DEFAULT_BOARD)}, got {sorted(board)}")
            object.__setattr__(self, "board", board)
        elif self.board is not None:
            raise ValueError(f"board is for a camera-calibration plan, not {self.kind!r}")
        if self.kind == "probe":
            brackets = tuple(str(b) for b in (PROBE_BRACKETS if self.brackets is None else self.brackets))
            if not 1 <= len(brackets) <= 99:
                raise ValueError(f"brackets must list 1..99 shutter speeds, got {len(brackets)}")
            for b in brackets:
                shutter_seconds(b)
            object.__setattr__(self, "brackets", brackets)
            if self.steps != 1:
                raise ValueError(f"a probe plan shoots at one table angle (steps 1), got steps {self.steps!r}")
        elif self.brackets is not None:
            raise ValueError(f"brackets are for a probe plan, not {self.kind!r}")
        r = self.sphere_radius_mm
        if r is not None and not (isinstance(r, (int, float)) and not isinstance(r, bool)
                                  and math.isfinite(r) and 0 < r <= 500):
            raise ValueError(f"sphere_radius_mm must be a radius in (0, 500] mm, got {r!r}")

    @property
    def step_deg(self) -> float:
        """Angle between steps (degrees)."""
        return 360.0 / self.steps

    def step_angle(self, i: int) -> float:
        """Table angle of step ``i`` (degrees)."""
        return 360.0 * i / self.steps

    def _frame_steps(self) -> list[int]:
        return [int(round((a % 360.0) / self.step_deg)) % self.steps for a in self.camera_angles_deg]

    def burst_frames(self) -> set[int]:
        """Indices of the camera frames shot as a burst of :attr:`holdout_burst` (the held-out angles).

        The rule of ``app.workflows.holdout_validation.holdout_frames`` on the frames' step angles:
        distinct angles (to 0.01 deg) ranked ascending, ranks ``every // 2 + k * every`` held out.
        Empty without a burst.

        Examples
        --------
        >>> sorted(CapturePlan("scan", steps=12, holdout_burst=4).burst_frames())
        [2, 6, 10]
        """
        if self.holdout_burst <= 1 or not self.camera:
            return set()
        keys = [round(self.step_angle(s) % 360.0, 2) for s in self._frame_steps()]
        ranked = sorted(set(keys))
        held = {a for r, a in enumerate(ranked) if r % self.holdout_every == self.holdout_every // 2}
        return {k for k, a in enumerate(keys) if a in held}

    def pass_actions(self, pass_no: int) -> list[Action]:
        """The ordered actions of pass ``pass_no`` (1-based)."""
        p = f"p{pass_no:02d}"
        out: list[Action] = []
        if self.camera and self.chart:
            if self.chart_frames == 1:
                out.append(Action(f"{p}/chart", "chart", pass_no, 0, 0.0))
            else:
                out += [Action(f"{p}/chart/{k:02d}", "chart", pass_no, k, 0.0) for k in range(self.chart_frames)]
        if self.kind == "probe":
            out += [Action(f"{p}/frame/{i:02d}", "frame", pass_no, i, 0.0, shutter=b)
                    for i, b in enumerate(self.brackets)]
            return out
        if self.kind in CAMERA_ONLY_KINDS:
            out += [Action(f"{p}/frame/{i:02d}" if self.steps <= 100 else f"{p}/frame/{i:04d}", "frame",
                           pass_no, i, self.step_angle(i)) for i in range(self.steps)]
            return out
        frames: dict[int, list[int]] = defaultdict(list)
        if self.camera:
            for k, s in enumerate(self._frame_steps()):
                frames[s].append(k)
        burst = self.burst_frames()
        for i in range(self.steps):
            out.append(Action(f"{p}/profile/{i:04d}", "profile", pass_no, i, self.step_angle(i)))
            for k in frames.get(i, ()):
                out.append(Action(f"{p}/frame/{k:02d}", "frame", pass_no, k, self.step_angle(i)))
                if k in burst:
                    out += [Action(f"{p}/frame/{k:02d}/burst/{j:02d}", "burst", pass_no, k, self.step_angle(i),
                                   shot=j) for j in range(1, self.holdout_burst)]
        return out

    def actions(self) -> list[Action]:
        """Every action of every pass, in order."""
        return [a for p in range(1, self.passes + 1) for a in self.pass_actions(p)]

    def to_dict(self) -> dict[str, Any]:
        """JSON form (stored in the session manifest's ``plan``)."""
        out = {"kind": self.kind, "steps": self.steps, "passes": self.passes,
               "camera_angles_deg": list(self.camera_angles_deg), "chart": self.chart,
               "lasers": list(self.lasers), "camera": self.camera,
               "chart_frames": self.chart_frames}
        if self.board is not None:
            out["board"] = dict(self.board)
        if self.sphere_radius_mm is not None:
            out["sphere_radius_mm"] = float(self.sphere_radius_mm)
        if self.brackets is not None:
            out["brackets"] = list(self.brackets)
        if self.holdout_burst > 1:          # a plan without a burst is stored as before bursts existed
            out["holdout_burst"] = self.holdout_burst
            out["holdout_every"] = self.holdout_every
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CapturePlan:
        """Inverse of :meth:`to_dict`."""
        known = {"kind", "steps", "passes", "camera_angles_deg", "chart", "lasers", "camera", "chart_frames",
                 "board", "sphere_radius_mm", "brackets", "holdout_burst", "holdout_every"}
        args = {k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items() if k in known}
        # a manifest written before chart_frames existed was taken with one chart frame per pass
        args.setdefault("chart_frames", 1)
        return cls(**args)


def placement_prompt(kind: str, pass_no: int) -> str:
    """What the technician does before pass ``pass_no`` of a plan of ``kind`` (lower case, no full stop).

    Examples
    --------
    >>> placement_prompt("camera-calibration", 1)
    'lay the ChArUco board flat on the table, near its centre'
    """
    p = pass_no
    if kind == "camera-calibration":
        return ("lay the ChArUco board flat on the table, near its centre" if p == 1 else
                "prop the ChArUco board on a wedge facing the camera, at a tilt the passes before did not use")
    if kind == "sphere-calibration":
        return "put the reference sphere on the table, 5-6 cm from its centre, where the laser line crosses it"
    if kind == "lamp-calibration":
        return "put the mirror sphere on the table, 3-4 cm from its centre, with the lamps as they are for the scans"
    if kind == "probe":
        return ("put the mirror sphere on the table centre in the light to be measured, the colour chart flat "
                "beside it; switch the room's lights as they will be")
    if kind == "swatch":        # a swatch stays put; a new pass moves the lamp (pass_light_directions)
        return ("lay the swatch flat on the table centre" if p == 1 else
                f"move the lamp to the light direction of pass {p} in swatch.json; leave the swatch as it lies")
    return "place the object on the table" if p == 1 else "re-place the object in a new orientation"


# ---------------------------------------------------------------------------- devices and hooks
class Shooter(Protocol):
    """A camera as the capture sees it: shoot one RAW frame into a staging folder."""

    def shoot(self, name: str, shutter: str | None = None) -> Path:
        """Fire and return the new RAW file (named ``<name>.<ext>``) in the staging folder.

        ``shutter``: the shutter speed to set first (gphoto2's ``shutterspeed`` value); a camera that
        cannot set it (a hot folder) shoots as it is set, and the frame's own metadata tells the exposure.
        """
        ...


@dataclass
class CaptureDevices:
    """The connected (or connectable) instruments; any may be None if the plan does not need it.

    ``turntable`` is a :class:`drivers.turntable.Turntable`, ``profiler`` a
    :class:`drivers.profiler.LaserProfiler`; ``camera`` builds a
    :class:`Shooter` for a staging folder (the session's ``.incoming``).
    """

    turntable: Any = None
    profiler: Any = None
    camera: Callable[[Path], Shooter] | None = None
    info: dict[str, Any] = field(default_factory=dict)


@dataclass
class CaptureHooks:
    """What the capture asks of its caller (CLI, GUI, tests).

    Attributes
    ----------
    before_pass
        ``before_pass(pass_no, passes)``: place the object (and the chart)
        for a new pass; raise :class:`CaptureInterrupted` to stop.
    before_chart
        ``before_chart(pass_no, index)``: chart frame ``index`` of the pass
        is next (the chart must be in view).
    after_chart
        ``after_chart(pass_no)``: the pass's last chart frame is taken
        (remove the chart).
    before_frame
        ``before_frame(pass_no, index, shot)``: object frame ``index`` is
        next, as shot ``shot`` of its burst (0: the first or only frame).
        A camera needs nothing; a simulated one numbers its exposures by it.
    low_return
        ``low_return(pass_no, valid_share, text)``: the pass's profiles
        (nearly) never saw the laser line; ask whether to go on (raise
        :class:`CaptureInterrupted` to stop).
    progress
        Called after every action with a :class:`CaptureProgress`.
    message
        Called with human-readable notes (recoveries, warnings).
    cancel
        Set it to stop at the next action boundary (Ctrl-C, a GUI button).
    """

    before_pass: Callable[[int, int], None] | None = None
    before_chart: Callable[[int, int], None] | None = None
    after_chart: Callable[[int], None] | None = None
    before_frame: Callable[[int, int, int], None] | None = None
    low_return: Callable[[int, float, str], None] | None = None
    progress: Callable[[CaptureProgress], None] | None = None
    message: Callable[[str], None] | None = None
    cancel: threading.Event | None = None


@dataclass(frozen=True)
class CaptureSettings:
    """Recovery and timing settings.

    Attributes
    ----------
    reconnect_timeout_s
        How long to wait for a vanished port to come back.
    max_recoveries
        Recoveries of one action before giving up on it.
    camera_retries, camera_retry_wait_s
        Retries of a busy or timed-out camera, and the wait between them.
    profile_deadline_s
        Deadline of one profile, re-requests included.
    """

    reconnect_timeout_s: float = 30.0
    max_recoveries: int = 5
    camera_retries: int = 3
    camera_retry_wait_s: float = 1.0
    profile_deadline_s: float = 5.0


@dataclass(frozen=True)
class CaptureProgress:
    """Progress after one action."""

    done: int
    total: int
    pass_no: int
    action: str
    elapsed_s: float
    eta_s: float | None


@dataclass
class CaptureReport:
    """What :func:`run_capture` did."""

    session: Path
    taken: int = 0
    skipped: int = 0
    redone: list[str] = field(default_factory=list)
    recoveries: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    status: str = "complete"
    warnings: list[str] = field(default_factory=list)


# ---------------------------------------------------------------------------- the engine
def run_capture(session: Session, plan: CapturePlan, devices: CaptureDevices,
                hooks: CaptureHooks | None = None, settings: CaptureSettings | None = None) -> CaptureReport:
    """Take every action of ``plan`` the session does not hold yet.

    Parameters
    ----------
    session
        An open :class:`app.session.Session` (new or to resume); its
        manifest's ``plan`` must equal ``plan.to_dict()``.
    plan
        The plan.
    devices
        The instruments (connected here; closed on every exit).
    hooks, settings
        See :class:`CaptureHooks`, :class:`CaptureSettings`.

    Returns
    -------
    CaptureReport
        Counts of taken / skipped actions and the recoveries made.

    Raises
    ------
    CaptureInterrupted
        A fault that could not be recovered, or a cancel; the session is
        marked ``interrupted`` and can be resumed.
    """
    return _Runner(session, plan, devices, hooks or CaptureHooks(), settings or CaptureSettings()).run()


class _Runner:
    def __init__(self, session: Session, plan: CapturePlan, devices: CaptureDevices, hooks: CaptureHooks,
                 settings: CaptureSettings) -> None:
        stored = session.manifest.get("plan")
        if stored != plan.to_dict():
            raise SessionError(f"session {session.root} was planned as {stored!r}, not {plan.to_dict()!r}; "
                               "resume it with its own plan (kogei capture --resume reads it from the session)")
        needs_table = True
        needs_profiler = plan.kind in PROFILE_KINDS
        needs_camera = plan.camera
        missing = [name for name, need, dev in (("turntable", needs_table, devices.turntable),
                                                ("laser profiler", needs_profiler, devices.profiler),
                                                ("camera", needs_camera, devices.camera)) if need and dev is None]
        if missing:
            raise ValueError(f"this {plan.kind} plan needs the {' and the '.join(missing)}; connect "
                             f"{'it' if len(missing) == 1 else 'them'} or change the plan")
        self.session = session
        self.plan = plan
        self.dev = devices
        self.hooks = hooks
        self.settings = settings
        self.report = CaptureReport(session.root)
        self.camera: Shooter | None = None
        self.t0 = time.monotonic()
        self.durations: dict[str, list[float]] = defaultdict(list)
        self.actions = plan.actions()
        self.done = 0

    # ---------------------------------------------------------------- top level
    def run(self) -> CaptureReport:
        s = self.session
        resumed = bool(s.manifest["captures"]) or s.manifest["status"] in ("interrupted", "capturing")
        check_not_linked(s.root, STAGING, ORPHANS)
        s.set_status("capturing")
        s.event("resumed" if resumed else "started",
                f"{self.plan.kind}: {self.plan.passes} pass(es) x {self.plan.steps} steps")
        try:
            self._stage()
            self._connect(resumed)
            for p in range(1, self.plan.passes + 1):
                self._run_pass(p)
            s.set_status("complete")
            s.event("complete", f"{self.report.taken} taken, {self.report.skipped} already held")
            self.report.status = "complete"
        except CaptureInterrupted as exc:
            self._interrupted(exc.reason, str(exc))
            raise
        except KeyboardInterrupt:
            self._interrupted("cancelled", "interrupted by the user (Ctrl-C)")
            raise
        except (DriverError, CameraError, SessionError, OSError) as exc:
            self._interrupted("device", str(exc))
            raise CaptureInterrupted(self._resume_hint(str(exc)), session=s.root, reason="device") from exc
        except BaseException as exc:
            self._interrupted("error", f"{type(exc).__name__}: {exc}")
            raise
        finally:
            self._close_devices()
            self.report.elapsed_s = time.monotonic() - self.t0
            try:
                s.checkpoint()
            except (SessionError, OSError):   # a full disk: the journal has the rest
                pass
        return self.report

    def _resume_hint(self, text: str) -> str:
        return f"{text}\nThe session {self.session.root} is intact; fix the cause and run: " \
               f"kogei capture --resume {self.session.root}"

    def _interrupted(self, reason: str, text: str) -> None:
        self.report.status = "interrupted"
        try:
            self.session.set_status("interrupted")
            self.session.event("interrupted", f"{reason}: {text}")
        except (SessionError, OSError):   # a full disk: the journal has the rest
            pass

    def _note(self, text: str) -> None:
        self.report.recoveries.append(text)
        self._tell("note", text)

    def _tell(self, event: str, text: str) -> None:
        """Record ``text`` as a history event (skipped on a full disk: the journal has the rest) and show it."""
        try:
            self.session.event(event, text)
        except (SessionError, OSError):
            pass
        if self.hooks.message:
            self.hooks.message(text)

    def _check_cancel(self) -> None:
        if self.hooks.cancel is not None and self.hooks.cancel.is_set():
            raise CaptureInterrupted(self._resume_hint("capture stopped by the user"), session=self.session.root,
                                     reason="cancelled")

    # ---------------------------------------------------------------- set-up
    def _stage(self) -> None:
        """Empty the staging folder; files a crash left there are kept in ``orphans/`` (see :func:`keep_orphans`)."""
        staging = self.session.root / STAGING
        kept, links, keep = keep_orphans(self.session.root)
        if kept:
            self._note(f"kept {len(kept)} unrecorded file(s) from an interrupted capture in "
                       f"{keep}: {', '.join(kept)}")
        if links:
            self._note(f"removed {len(links)} symbolic link(s) from {STAGING} without following them: "
                       f"{', '.join(links)}")
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir(parents=True, exist_ok=True)
        if self.dev.camera is not None:
            self.camera = self.dev.camera(staging)

    def _connect(self, resumed: bool) -> None:
        info = dict(self.session.manifest.get("devices") or {})
        tt = self.dev.turntable
        if tt is not None:
            state = self.session.manifest["state"]
            current = self._current_pass()
            if resumed and current is not None and state.get("pass_no") == current:
                self._attach_turntable(state)
            else:
                self._guard("turntable", tt.connect)
            info["turntable"] = {**info.get("turntable", {}), "port": tt.transport.url,
                                 "firmware": tt.firmware_version, "steps_per_degree": tt.steps_per_degree}
        pr = self.dev.profiler
        if pr is not None:
            self._guard("laser profiler", pr.connect)
            self._guard("laser profiler", lambda: pr.laser(True))
            info["profiler"] = {**info.get("profiler", {}), "port": pr.port, "model": pr.model,
                                "serial_number": pr.serial_number, "firmware": pr.firmware_version,
                                "exposure_us": pr.exposure_us}
        info.update({k: v for k, v in self.dev.info.items() if k not in ("turntable", "profiler")})
        self.session.update("devices", info)

    def _guard(self, name: str, fn: Callable[[], Any]) -> Any:
        try:
            return fn()
        except TransportClosed as exc:
            raise CaptureInterrupted(self._resume_hint(f"{name}: {exc}; is it plugged in and powered?"),
                                     session=self.session.root) from exc
        except DriverError as exc:
            raise CaptureInterrupted(self._resume_hint(f"{name}: {exc}"), session=self.session.root) from exc

    def _current_pass(self) -> int | None:
        for p in range(1, self.plan.passes + 1):
            if self.session.pass_record(p).get("status") != "complete":
                return p if self.session.pass_record(p).get("zeroed") else None
        return None

    def _attach_turntable(self, state: dict[str, Any]) -> None:
        """Reconnect mid-pass and learn the table's angle (see the module docstring)."""
        tt = self.dev.turntable
        last = float(state.get("table_deg", 0.0))
        moving = state.get("moving_to")
        offset = float(state.get("fw_offset_deg", 0.0))
        read: float | None = None
        try:
            if not tt.transport.is_open:
                tt.transport.open()
            st = tt.status()
            reset_seen = any("Horus" in line for line in tt.unsolicited)
            if st.position is not None and not reset_seen and st.state == "Idle":
                steps = round(st.position * tt.firmware_steps_per_unit)   # the counter holds whole steps
                read = steps / tt.steps_per_degree + offset
        except (DriverError, OSError):
            read = None
        self._guard("turntable", tt.connect)
        half_step = 0.5 / tt.steps_per_degree + 1e-9
        if read is not None and abs(read - last) <= 1e-6:
            angle, uncertain = last, 0.0              # the journaled confirmed value itself, exactly
        elif read is not None and moving is not None and abs(read - float(moving)) <= half_step:
            angle, uncertain = read, 0.0              # the interrupted move finished (target rounded to a step)
        elif moving is None:
            angle, uncertain = last, 0.0
        else:
            angle, uncertain = last, abs(float(moving) - last)
        tt.assume_position(angle)
        p = state.get("pass_no")
        self.session.set_state(table_deg=angle, moving_to=None, fw_offset_deg=tt.firmware_offset_deg)
        if uncertain > 0:
            self._angle_lost(p, uncertain, f"the board lost its position during an interrupted move of pass {p}")
        else:
            self._note(f"turntable: resumed pass {p} at {angle:g} deg "
                       f"({'read from the firmware' if read is not None else 'last confirmed angle'})")

    def _close_devices(self) -> None:
        for dev in (self.dev.profiler, self.dev.turntable):
            if dev is not None:
                try:
                    dev.close()
                except Exception:  # noqa: BLE001 - closing is best effort; the drivers log why
                    pass

    # ---------------------------------------------------------------- passes
    def _run_pass(self, p: int) -> None:
        s = self.session
        actions = self.plan.pass_actions(p)
        rec = s.pass_record(p)
        pending = {a.id for a in actions if not self._held(a)}
        if not pending and rec.get("status") == "complete" and self._gathered_ok(p):
            self._skip(actions)
            return
        self._check_cancel()
        if not rec.get("placed"):
            if self.hooks.before_pass is not None:
                self.hooks.before_pass(p, self.plan.passes)
            s.update_pass(p, placed=utc_now(), status="capturing")
        if not rec.get("zeroed"):
            if self.plan.kind == "swatch" and p > 1:
                # the swatch stays where it lies while the lamp moves: finish the turn so that this pass's
                # zero is pass 1's, the orientation the fit's warp angle refers to
                self._move(360.0 * math.ceil(self.dev.turntable.position_deg / 360.0 - 1e-9), ())
            self._recover("turntable", self.dev.turntable.zero)
            s.set_state(pass_no=p, table_deg=0.0, moving_to=None, fw_offset_deg=0.0)
            s.update_pass(p, zeroed=True)
        for a in actions:
            if a.id not in pending:
                self._skip([a])
                continue
            self._take(p, a)
        rounds = 0
        while stale := [a for a in actions if self._in_earlier_frame(a)]:
            rounds += 1
            if rounds > self.settings.max_recoveries:
                raise CaptureInterrupted(self._resume_hint(
                    f"turntable: the table's angle was lost again while pass {p}'s earlier captures were being "
                    "taken again; check the turntable's cable and power"), session=s.root)
            frame = self._table_frame(p)
            self._note(f"pass {p}: {len(stale)} capture(s) taken before the table's angle was lost are taken "
                       f"again in its table frame {frame} (the pass's profiles and frames must share one zero)")
            self.actions.extend(stale)                # the progress counts them
            for a in stale:
                self._take(p, a)
        if self.plan.kind in PROFILE_KINDS:
            self._gather(p)
        s.update_pass(p, status="complete", completed=utc_now())
        s.checkpoint()

    def _take(self, p: int, a: Action) -> None:
        self._check_cancel()
        t = time.monotonic()
        if a.kind == "profile":
            self._profile(a)
        else:
            if a.kind == "chart" and self.hooks.before_chart is not None:
                self.hooks.before_chart(p, a.index)
            if a.kind in ("frame", "burst") and self.hooks.before_frame is not None:
                self.hooks.before_frame(p, a.index, a.shot)
            self._frame(a)
            if a.kind == "chart" and a.index == self.plan.chart_frames - 1 and self.hooks.after_chart is not None:
                self.hooks.after_chart(p)
        self.durations[a.kind].append(time.monotonic() - t)
        self.report.taken += 1
        self._progress(a)

    def _table_frame(self, p: int) -> int:
        """The pass's table frame: how many times the table's angle was lost in it (see the module docstring)."""
        return int(self.session.pass_record(p).get("table_frame", 0))

    def _frame_fields(self, a: Action) -> dict[str, Any]:
        """The table frame a profile or frame is taken in, for its record (nothing in frame 0)."""
        frame = self._table_frame(a.pass_no)
        return {"table_frame": frame} if frame and a.kind != "chart" else {}

    def _angle_lost(self, p: int | None, uncertain_deg: float, how: str) -> None:
        """The table's angle is known only to within ``uncertain_deg``: start a new table frame of pass ``p``."""
        if p is None or self.session.pass_record(p).get("status") == "complete":
            # between passes (the swatch's turn back to pass 1's zero): the next pass's zero is set anew
            self._note(f"turntable: {how}; the table's angle is known only to within {uncertain_deg:g} deg "
                       "before the next pass is zeroed")
            return
        frame = self._table_frame(p) + 1
        self.session.update_pass(p, table_frame=frame)
        self._note(f"turntable: {how}; the table's angle is known only to within {uncertain_deg:g} deg, so its "
                   f"confirmed angle starts table frame {frame} of pass {p} and the pass's earlier profiles "
                   "and frames are taken again in it")

    def _in_earlier_frame(self, a: Action) -> bool:
        """True if ``a`` was taken in an earlier table frame of its pass (before the table's angle was lost)."""
        rec = self.session.capture(a.id)
        return (rec is not None and a.kind != "chart"
                and int(rec.get("table_frame", 0)) != self._table_frame(a.pass_no))

    def _held(self, a: Action) -> bool:
        rec = self.session.capture(a.id)
        if rec is None or rec.get("status") != "done" or self._in_earlier_frame(a):
            return False
        problem = self.session.verify_file(rec)
        if problem is None:
            return True
        self.report.redone.append(a.id)
        self._note(f"{a.id}: {problem}; taking it again")
        return False

    def _skip(self, actions: list[Action]) -> None:
        for a in actions:
            self.report.skipped += 1
            self._progress(a)

    def _progress(self, a: Action) -> None:
        self.done += 1
        if self.hooks.progress is None:
            return
        rest = self.actions[self.done:]
        means = {k: float(np.mean(v)) for k, v in self.durations.items() if v}
        if means:
            overall = float(np.mean([x for v in self.durations.values() for x in v]))
            eta: float | None = sum(means.get(r.kind, overall) for r in rest)
        else:
            eta = None
        self.hooks.progress(CaptureProgress(self.done, len(self.actions), a.pass_no, a.id,
                                            time.monotonic() - self.t0, eta))

    # ---------------------------------------------------------------- recovery
    def _recover(self, name: str, fn: Callable[[], Any]) -> Any:
        """Call ``fn`` recovering a vanished port / silent device by reconnecting, up to ``max_recoveries``."""
        dev = self.dev.turntable if name == "turntable" else self.dev.profiler
        attempts = 0
        while True:
            try:
                result = fn()
                self._collect_recoveries(name, dev)
                return result
            except (TransportClosed, DeviceTimeout) as exc:
                attempts += 1
                if attempts > self.settings.max_recoveries:
                    raise CaptureInterrupted(self._resume_hint(f"{name}: {exc}; gave up after {attempts - 1} "
                                                               "reconnections"), session=self.session.root) from exc
                what = "port vanished" if isinstance(exc, TransportClosed) else "stopped answering"
                self._note(f"{name} on {dev.transport.url}: {what} ({exc}); reconnecting "
                           f"(waiting up to {self.settings.reconnect_timeout_s:g} s)")
                try:
                    dev.reconnect(timeout_s=self.settings.reconnect_timeout_s)
                except (TransportError, DriverError) as again:
                    raise CaptureInterrupted(self._resume_hint(
                        f"{name} on {dev.transport.url} did not come back within "
                        f"{self.settings.reconnect_timeout_s:g} s ({again}); plug it back in and power it"),
                        session=self.session.root) from again
                if name == "turntable" and dev.position_uncertain_deg > 0:
                    self._angle_lost(self.session.manifest["state"].get("pass_no"), dev.position_uncertain_deg,
                                     "the board was reset before the end of a move could be heard")
            except DeviceAlarm as exc:
                raise CaptureInterrupted(self._resume_hint(
                    f"{name}: {exc}; the move was aborted (a jam?): clear it, then resume"),
                    session=self.session.root) from exc
            except DeviceError as exc:
                raise CaptureInterrupted(self._resume_hint(f"{name}: {exc}"), session=self.session.root) from exc

    def _collect_recoveries(self, name: str, dev: Any) -> None:
        """Move the driver's own recoveries (re-requests, resends, resets) into the session history."""
        rec = getattr(dev, "recoveries", None)
        while rec:
            self._note(f"{name}: {rec.popleft()}")

    def _move(self, target: float, lasers: tuple[int, ...]) -> float:
        tt = self.dev.turntable
        if abs(tt.position_deg - target) > 1e-9:
            self.session.set_state(moving_to=target, table_deg=tt.position_deg, fw_offset_deg=tt.firmware_offset_deg)
        return self._recover("turntable", lambda: tt.step(target, lasers=lasers))

    # ---------------------------------------------------------------- actions
    def _profile(self, a: Action) -> None:
        s, pr = self.session, self.dev.profiler
        angle = self._move(a.angle_deg, self.plan.lasers)
        prof = self._recover("laser profiler", lambda: pr.profile(self.settings.profile_deadline_s))
        if not prof.valid.any() and self.plan.lasers:
            # A laser the firmware's watchdog switched off shows as a profile with no return at all:
            # re-assert the lasers and take it once more (an empty view stays empty, at the cost of one profile).
            tt = self.dev.turntable
            for i in self.plan.lasers:
                self._recover("turntable", lambda i=i: tt.laser(i, True))
            again = self._recover("laser profiler", lambda: pr.profile(self.settings.profile_deadline_s))
            if again.valid.any():
                self._note(f"{a.id}: no laser return until the lasers were re-asserted (the firmware's watchdog?)")
            prof = again
        info = s.write_arrays(f"passes/p{a.pass_no:02d}/profiles/{a.stem}.npz",
                              x_mm=prof.x_mm.astype(np.float32), z_mm=prof.z_mm.astype(np.float32),
                              angle_deg=np.float64(angle), seq=np.int64(prof.seq),
                              timestamp_us=np.int64(prof.timestamp_us))
        s.add_capture(a.id, kind="profile", **{"pass": a.pass_no}, index=a.index, angle_deg=angle,
                      **self._frame_fields(a), valid=int(prof.valid.sum()), file=info.path, sha256=info.sha256,
                      bytes=info.bytes,
                      state={"table_deg": angle, "moving_to": None,
                             "fw_offset_deg": self.dev.turntable.firmware_offset_deg})

    def _frame(self, a: Action) -> None:
        s = self.session
        angle = self._move(a.angle_deg, ())
        path = self._shoot(f"p{a.pass_no:02d}_{a.stem}", a.shutter)
        info = s.adopt_file(path, f"passes/p{a.pass_no:02d}/raw/{a.stem}{path.suffix.lower()}")
        extra: dict[str, Any] = {} if a.shutter is None else {"shutter": a.shutter}
        if a.kind == "burst":
            extra.update(burst_of=f"p{a.pass_no:02d}/frame/{a.index:02d}", shot=a.shot)
        s.add_capture(a.id, kind=a.kind, **{"pass": a.pass_no}, index=a.index, angle_deg=angle, **extra,
                      **self._frame_fields(a),
                      file=info.path, sha256=info.sha256, bytes=info.bytes,
                      state={"table_deg": angle, "moving_to": None,
                             "fw_offset_deg": self.dev.turntable.firmware_offset_deg})

    def _shoot(self, name: str, shutter: str | None = None) -> Path:
        assert self.camera is not None
        tries = 0
        while True:
            try:
                shot = self.camera.shoot(name) if shutter is None else self.camera.shoot(name, shutter=shutter)
                return self._checked(shot)
            except (CameraBusyError, CameraTimeoutError, CameraBadFrameError) as exc:
                tries += 1
                if tries > self.settings.camera_retries:
                    raise CaptureInterrupted(self._resume_hint(f"camera: {exc} (tried {tries} times)"),
                                             session=self.session.root) from exc
                self._note(f"camera: {exc}; retrying in {self.settings.camera_retry_wait_s:g} s "
                           f"({tries}/{self.settings.camera_retries})")
                time.sleep(self.settings.camera_retry_wait_s)
            except CameraError as exc:
                raise CaptureInterrupted(self._resume_hint(f"camera: {exc}"), session=self.session.root) from exc

    def _checked(self, path: Path) -> Path:
        """``path`` if it is the RAW format its ending claims; else it is moved to ``orphans/`` and refused."""
        problem = raw_format_problem(path)
        if problem is None:
            return path
        keep = _unique_folder(self.session.root / ORPHANS)
        os.replace(path, keep / path.name)
        raise CameraBadFrameError(f"the camera delivered {problem} (kept as "
                                  f"{(keep / path.name).relative_to(self.session.root).as_posix()}); check that "
                                  "the camera saves RAW and the USB cable")

    # ---------------------------------------------------------------- end of pass
    def _gathered_ok(self, p: int) -> bool:
        if self.plan.kind not in PROFILE_KINDS:
            return True
        rec = self.session.capture(f"p{p:02d}/profiles")
        return rec is not None and self.session.verify_file(rec) is None

    def _gather(self, p: int) -> None:
        """Write the pass's profiles as one ``profiles.npz`` (angles_deg (S,), x_mm and z_mm (S, P))."""
        s = self.session
        rows = []
        for a in self.plan.pass_actions(p):
            if a.kind != "profile":
                continue
            rows.append(_read_profile(s.path(s.capture(a.id)["file"]), s.root))
        width = max(r[1].size for r in rows)
        x = np.full((len(rows), width), np.nan, np.float32)
        zz = np.full((len(rows), width), np.nan, np.float32)
        for i, (_, xr, zr) in enumerate(rows):
            x[i, :xr.size] = xr
            zz[i, :zr.size] = zr
        angles = np.array([r[0] for r in rows])
        info = s.write_arrays(f"passes/p{p:02d}/profiles.npz", angles_deg=angles, x_mm=x, z_mm=zz)
        s.add_capture(f"p{p:02d}/profiles", kind="profiles", **{"pass": p}, steps=len(rows), points=width,
                      file=info.path, sha256=info.sha256, bytes=info.bytes)
        self._check_returns(p, zz)

    def _check_returns(self, p: int, z_mm: np.ndarray) -> None:
        """Record the pass's share of profiles with a laser return; warn (and ask) when it is near zero."""
        share = float(np.isfinite(z_mm).any(axis=1).mean()) if z_mm.size else 0.0
        self.session.update_pass(p, valid_share=round(share, 4))
        if share >= MIN_VALID_SHARE:
            return
        text = (f"pass {p}: only {share:.0%} of its {z_mm.shape[0]} profiles saw the laser line; check the "
                "laser (power, the turntable's laser output, its aim) before the object leaves the table")
        self.report.warnings.append(text)
        self._tell("warning", text)
        if self.hooks.low_return is not None:
            self.hooks.low_return(p, share, text)


def _read_profile(path: Path, root: Path) -> tuple[float, np.ndarray, np.ndarray]:
    """``(angle_deg, x_mm, z_mm)`` of one profile's ``.npz`` (untrusted on resume: checked before it is read)."""
    from processing.common.npz import read_npz

    remedy = f"delete it and resume the capture ('kogei capture --resume {root}') to take the profile again"
    z = read_npz(path, ("angle_deg", "x_mm", "z_mm"), what="a laser profile", remedy=remedy, error=SessionError)
    x, zz, angle = z["x_mm"], z["z_mm"], z["angle_deg"]
    if (angle.shape != () or angle.dtype.kind not in "fiu" or x.ndim != 1 or zz.shape != x.shape
            or x.dtype.kind != "f" or zz.dtype.kind != "f"):
        raise SessionError(f"{path}: not a laser profile (angle_deg {angle.dtype} {angle.shape}, x_mm {x.dtype} "
                           f"{x.shape}, z_mm {zz.dtype} {zz.shape}); {remedy}")
    return float(angle), x, zz


def check_not_linked(root: Path, *names: str) -> None:
    """Raise :class:`SessionError` if ``root/<name>`` is a symbolic link (kogei never follows one in a session)."""
    for name in names:
        path = Path(root) / name
        if path.is_symlink():
            raise SessionError(f"session {root}: {name} is a symbolic link (to {os.readlink(path)}); kogei does not "
                               f"follow links inside a session: remove the link {path} and resume")


def _unique_folder(parent: Path) -> Path:
    """A new folder ``parent/<UTC time>-<random>`` (never an existing one, even within the same second)."""
    parent.mkdir(parents=True, exist_ok=True)
    while True:
        path = parent / f"{time.strftime('%Y%m%dT%H%M%S', time.gmtime())}-{secrets.token_hex(4)}"
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue


def keep_orphans(root: Path) -> tuple[list[str], list[str], str]:
    """Move the regular files under ``root/.incoming`` into a new ``orphans/<time>-<unique>/`` folder.

    Each file keeps its path relative to ``.incoming`` (two gphoto2 work folders each holding
    ``capt0000.dng`` keep both).  Symbolic links are never followed: ``.incoming`` or ``orphans``
    being a link raises :class:`SessionError`; a link inside ``.incoming`` is listed, not moved
    (the folder is removed afterwards, which removes the link and not its target).

    Returns
    -------
    tuple
        The kept files (relative to ``.incoming``), the links found, and the folder they went to
        (relative to ``root``; empty when nothing was kept).
    """
    root = Path(root)
    check_not_linked(root, STAGING, ORPHANS)
    staging = root / STAGING
    if not staging.is_dir():
        return [], [], ""
    files: list[str] = []
    links: list[str] = []
    for folder, dirs, names in os.walk(staging, followlinks=False):
        for name in sorted(dirs + names):
            path = Path(folder) / name
            rel = path.relative_to(staging).as_posix()
            st = path.lstat()
            if stat.S_ISLNK(st.st_mode):
                links.append(rel)
            elif stat.S_ISREG(st.st_mode):
                files.append(rel)
    if not files:
        return [], sorted(links), ""
    keep = _unique_folder(root / ORPHANS)
    for rel in files:
        target = keep / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(staging / rel, target)
    return sorted(files), sorted(links), keep.relative_to(root).as_posix()


def open_for_resume(root: str | Path) -> tuple[Any, CapturePlan, dict[str, Any], dict[str, Any]]:
    """Open an unfinished session to resume its capture: the open session, its plan, its settings
    and a copy of its device configuration (``UsageError`` for a bad or complete session).

    The caller adjusts the settings and devices (new ports, a camera) and stores them with
    ``session.update("settings", ...)`` before capturing.
    """
    from app.errors import UsageError
    from app.session import Session, SessionError

    try:
        session = Session.open(root)
    except SessionError as exc:
        raise UsageError(str(exc)) from None
    if session.manifest["status"] == "complete":
        session.close()
        raise UsageError(f"session {root} is already complete; nothing to resume")
    settings = session.manifest.get("settings") or {}
    config = settings.get("device_config") or {} if isinstance(settings, dict) else None
    if not isinstance(config, dict) or not all(isinstance(v, dict) for v in config.values()):
        session.close()
        raise UsageError(f"session {root}: settings.device_config in session.json is not a table of devices; "
                         "the session is damaged (restore session.json from a copy)")
    try:
        plan = CapturePlan.from_dict(session.manifest["plan"])
    except (ValueError, TypeError) as exc:
        session.close()
        raise UsageError(f"session {root}: plan in session.json is not valid: {exc}") from None
    return session, plan, dict(settings), {k: dict(v) for k, v in config.items()}


def parse_camera_angles(text: str, what: str = "camera angles") -> tuple[float, ...]:
    """Camera angles (degrees) typed as numbers separated by commas; ``ValueError`` naming ``what`` otherwise.

    Examples
    --------
    >>> parse_camera_angles("0, 90,180"), parse_camera_angles(" ")
    ((0.0, 90.0, 180.0), ())
    """
    if not text.strip():
        return ()
    try:
        angles = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{what} {text!r}: give degrees separated by commas, e.g. 0,90,180,270") from None
    if not all(math.isfinite(a) for a in angles):
        raise ValueError(f"{what} {text!r}: angles must be finite")
    return angles


def load_pass_profiles(session_root: str | Path, pass_no: int) -> dict[str, np.ndarray]:
    """The gathered profiles of a pass: ``angles_deg (S,)``, ``x_mm (S, P)``, ``z_mm (S, P)`` (NaN invalid).

    The file is untrusted (a sender can rewrite it and its checksum): see :func:`_read_profiles`.

    Raises
    ------
    SessionError
        The pass is not complete or its file fails its checksum.
    ProfilesFileError
        The file is not the pass's profiles (one line naming it and what to do).
    """
    manifest = Session.read(session_root)
    captures = manifest.get("captures")
    key = f"p{int(pass_no):02d}/profiles"
    rec = captures.get(key) if isinstance(captures, dict) else None
    if rec is None:
        raise SessionError(f"session {session_root}: pass {pass_no} has no gathered profiles (the pass is not "
                           f"complete); resume the capture with 'kogei capture --resume {session_root}'")
    if not isinstance(rec, dict) or not isinstance(rec.get("file"), str) or not isinstance(rec.get("sha256"), str):
        raise SessionError(f"session {session_root}: captures[{key!r}] in session.json is not a record with "
                           "'file' and 'sha256'; the session is damaged")
    path = check_regular_file(session_path(session_root, rec["file"], f"captures.{key}.file"),
                              f"captures.{key}.file")
    if sha256_file(path) != rec["sha256"]:
        raise SessionError(f"session {session_root}: {rec['file']} is missing or fails its checksum")
    return _read_profiles(path, session_root, int(pass_no))


#: The arrays of a pass's ``profiles.npz``.
_PROFILE_ARRAYS = ("angles_deg", "x_mm", "z_mm")


def _profiles_remedy(session_root: str | Path, pass_no: int) -> str:
    """What to do about a pass's unreadable ``profiles.npz``."""
    return (f"restore the file from a copy of the session, or delete it and resume the capture ('kogei capture "
            f"--resume {session_root}') to gather pass {pass_no}'s profiles again (or capture the pass again)")


def _read_profiles(path: Path, session_root: str | Path, pass_no: int) -> dict[str, np.ndarray]:
    """``angles_deg (S,)``, ``x_mm (S, P)``, ``z_mm (S, P)`` of a pass's untrusted ``profiles.npz``.

    Parameters
    ----------
    path
        The pass's ``profiles.npz``.
    session_root
        The session (for the remedy).
    pass_no
        The pass (for the messages).

    Returns
    -------
    dict
        The three arrays, checked.

    Raises
    ------
    ProfilesFileError
        One line naming the file and what to do: not a zip, a missing array, pickled objects, a header
        claiming more than the file holds, a wrong dtype or shapes that do not match.
    """
    from processing.common.npz import read_npz
    from render.renderer import available_memory_bytes

    remedy = _profiles_remedy(session_root, pass_no)
    data = read_npz(path, _PROFILE_ARRAYS, what=f"the profiles of pass {pass_no}", remedy=remedy,
                    error=ProfilesFileError, available_bytes=available_memory_bytes())
    a, x, z = (data[k] for k in _PROFILE_ARRAYS)
    for key, arr, ndim in (("angles_deg", a, 1), ("x_mm", x, 2), ("z_mm", z, 2)):
        if arr.dtype.kind not in ("fiu" if key == "angles_deg" else "f") or arr.ndim != ndim:
            raise ProfilesFileError(f"{path}: array {key!r} of pass {pass_no} must be {ndim}-D "
                                    f"{'numeric' if key == 'angles_deg' else 'floating-point'}, got {arr.dtype} "
                                    f"of shape {arr.shape}; {remedy}")
    if z.shape != x.shape or a.shape != (x.shape[0],):
        raise ProfilesFileError(f"{path}: the arrays of pass {pass_no} do not match (angles_deg {a.shape}, "
                                f"x_mm {x.shape}, z_mm {z.shape}; expected (S,), (S, P), (S, P)); {remedy}")
    if not np.all(np.isfinite(a)) or np.isinf(x).any() or np.isinf(z).any():
        raise ProfilesFileError(f"{path}: pass {pass_no} has infinite values in x_mm or z_mm or a non-finite "
                                f"angle; {remedy}")
    return {"angles_deg": a, "x_mm": x, "z_mm": z}
