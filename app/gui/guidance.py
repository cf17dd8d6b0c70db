"""Guidance for the window's user: where the session stands among the steps, and a verdict on each quality figure.

:data:`STEPS` are the station's steps in order; :func:`current_step` says which
one is next from what has been done, and :func:`step_hint` what to do there.
The window shows them as a strip above the tabs (:class:`StepStrip`).

Every quality figure the window shows gets a verdict -- ``pass``, ``warn`` or
``fail`` -- with its thresholds and one line of explanation (:class:`Verdict`):

* **Sphere calibration** (:func:`sphere_verdict`): the rms of the reference
  sphere's points about the fitted sphere.  A calibration that is right leaves
  only the profiler's range noise (50 um for the simulated profiler, 20-100 um
  for line-profile sensors of this class); pass up to 0.1 mm, warn up to
  0.25 mm (the mesh carries that error), fail above.
* **Camera calibration** (:func:`camera_verdict`): the reprojection rms of the
  ChArUco board's corners.  Pass up to 0.5 px (corner detection's own error on
  sharp frames), warn up to 1.0 px (the calibration's own limit: above it
  ``kogei calibrate --camera`` refuses the result), fail above.
* **Chart detection** (:func:`chart_verdict`): the share of the 24 patches
  whose colour blob sits where the detected chart puts it.  Pass from 0.9 (at
  most two patches off), warn from 0.6, fail below (the patches sampled may be
  the wrong ones: mark the corners by hand).
* **Pairwise registration** (:func:`registration_verdict`): the pair's rms
  residual over the one expected from the clouds' own noise and spacing.
  Pass up to 2x, warn up to 4x (a small misalignment or a moved object),
  fail above or when the pair's check failed.
* **Materials on the mesh** (:func:`materials_verdict`): the regions the
  measurement found and their answers.  Pass when every region has a material
  told apart from the other candidates (and, when validated on the held-out
  photos, the measured materials predict them no worse than one material for
  the whole object); warn when a region is not measured, fits no candidate or
  cannot be told from another candidate, or, with two or more materials fitted,
  the held-out photos are predicted worse than by one material, or
  :data:`UNMEASURED_WARN_SHARE` of the surface or more has no usable
  observation (the why is the materials file's advice: which way that surface
  faces and what to capture); fail when no region has a fitted material.

Examples
--------
>>> sphere_verdict(0.062).level, sphere_verdict(0.18).level, sphere_verdict(0.4).level
('pass', 'warn', 'fail')
>>> registration_verdict(0.09, 0.03, verified=True).level
'warn'
>>> current_step({"devices": True, "calibrated": True, "session": True})
'Capture'
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["STEPS", "Verdict", "calibration_hint", "camera_verdict", "chart_verdict", "current_step", "materials_verdict", "registration_verdict",
           "sphere_verdict", "step_hint", "VERDICT_COLOURS", "describe"]

#: The station's steps, in order.
STEPS = ("Devices", "Calibrate", "Session", "Capture", "Process", "Materials", "Preview")

#: Colour of each verdict.
VERDICT_COLOURS = {"pass": "#2e9e44", "warn": "#b07800", "fail": "#d0312d"}

_HINTS = {
    "Devices": "connect the turntable and the profiler (Devices tab), or start a simulated station there",
    "Calibrate": "scan the reference sphere (plan sphere-calibration; with photos at a few camera angles when the "
                 "camera will be calibrated too), then 'Calibrate from the open session' (Processing tab)",
    "Session": "name the object and press 'New session' (Session tab)",
    "Capture": "press Start on the Capture tab and follow the prompts to re-place the object between passes",
    "Process": "press 'Process the open session' (Processing tab): registration and the watertight mesh",
    "Materials": "press 'Measure materials on the mesh' (Processing tab) when the photos are posed on the mesh, "
                 "or calibrate a frame with its chart and make the material map (Spectra and materials tab)",
    "Preview": "render the mesh under the light you choose (Preview tab)",
}


def current_step(done: dict[str, bool]) -> str:
    """The first step of :data:`STEPS` not done yet (``"Preview"`` when all are).

    ``done`` holds, by key: ``devices`` (instruments connected), ``calibrated``
    (a scanner calibration chosen), ``session`` (one open), ``captured`` (its
    capture complete), ``processed`` (it has a mesh), ``materials`` (a material
    map made or materials measured on the mesh).  A session already captured
    needs no instruments.

    Examples
    --------
    >>> current_step({})
    'Devices'
    >>> current_step({"session": True, "captured": True, "calibrated": True})
    'Process'
    """
    if done.get("session") and done.get("captured"):
        order = [("calibrated", "Calibrate"), ("processed", "Process"), ("materials", "Materials")]
    else:
        order = [("devices", "Devices"), ("calibrated", "Calibrate"), ("session", "Session"), ("captured", "Capture"),
                 ("processed", "Process"), ("materials", "Materials")]
    for key, step in order:
        if not done.get(key):
            return step
    return "Preview"


def step_hint(step: str) -> str:
    """One line on what to do at ``step``.

    >>> step_hint("Session")
    "name the object and press 'New session' (Session tab)"
    """
    return _HINTS[step]


@dataclass(frozen=True)
class Verdict:
    """A quality figure's verdict: ``level`` (pass / warn / fail), the figure as text, the thresholds and why."""

    level: str
    figure: str
    thresholds: str
    why: str

    @property
    def text(self) -> str:
        """``"0.062 mm: pass"``-style one-liner."""
        return f"{self.figure}: {self.level}"

    @property
    def tooltip(self) -> str:
        """The thresholds and the explanation, for a tooltip."""
        return f"{self.thresholds}. {self.why}"

    def html(self) -> str:
        """The verdict word, coloured."""
        return f"<b style='color:{VERDICT_COLOURS[self.level]}'>{self.level.upper()}</b>"


def _level(value: float, good: float, bad: float) -> str:
    return "pass" if value <= good else "warn" if value <= bad else "fail"


def sphere_verdict(rms_mm: float) -> Verdict:
    """The reference sphere's residual rms after calibration (see the module docstring)."""
    level = _level(rms_mm, 0.1, 0.25)
    why = {"pass": "the sphere fits to the profiler's own noise: the calibration adds no visible error",
           "warn": "the sphere fits worse than the profiler's noise: the mesh will carry this error; rescan the "
                   "sphere if the scan was disturbed",
           "fail": "the sphere does not fit: the sphere radius given or the scan is wrong; check the radius and "
                   "rescan"}[level]
    return Verdict(level, f"sphere residual rms {rms_mm:.3f} mm", "pass <= 0.10 mm, warn <= 0.25 mm, fail above",
                   why)


def camera_verdict(rms_px: float) -> Verdict:
    """The camera calibration's reprojection rms over the board's corners (see the module docstring).

    >>> camera_verdict(0.12).level, camera_verdict(0.7).level, camera_verdict(1.5).level
    ('pass', 'warn', 'fail')
    """
    level = _level(rms_px, 0.5, 1.0)
    why = {"pass": "the board's corners land where the calibrated camera puts them, to a fraction of a pixel",
           "warn": "the corners land up to a pixel off: photos posed on the mesh may be off by as much; check "
                   "that the board is flat and sharp",
           "fail": "the corners do not fit one camera: the board moved, is not flat or the frames are blurred; "
                   "photograph it again"}[level]
    return Verdict(level, f"reprojection rms {rms_px:.3f} px", "pass <= 0.5 px, warn <= 1.0 px, fail above", why)


def chart_verdict(confidence: float, method: str = "mcc") -> Verdict:
    """The chart detection's confidence (see the module docstring); corners marked by hand pass."""
    if method == "manual":
        return Verdict("pass", "chart placed from the marked corners", "pass: corners marked by hand",
                       "the patches are where the four clicked corners put them")
    level = "pass" if confidence >= 0.9 else "warn" if confidence >= 0.6 else "fail"
    why = {"pass": "the patches found agree with the chart's layout",
           "warn": "some patches were not found where the layout puts them: check the outline on the frame",
           "fail": "most patches disagree with the layout: the colours sampled may be wrong; mark the corners by "
                   "hand"}[level]
    return Verdict(level, f"chart confidence {confidence:.2f}", "pass >= 0.90, warn >= 0.60, fail below", why)


def registration_verdict(rmse_mm: float | None, expected_mm: float | None, verified: bool) -> Verdict:
    """A registered pair's residual against the one its clouds' noise explains (see the module docstring)."""
    thresholds = "pass <= 2x the expected residual, warn <= 4x, fail above or when the pair's check failed"
    if rmse_mm is None or not verified:
        return Verdict("fail", "not registered" if rmse_mm is None else f"rms {rmse_mm:.4f} mm, check failed",
                       thresholds, "the passes are not aligned: use the manual 3-point registration")
    ratio = rmse_mm / expected_mm if expected_mm else float("inf")
    level = _level(ratio, 2.0, 4.0)
    why = {"pass": "the passes agree to the scanner's noise",
           "warn": "the passes agree less well than their noise allows: a small misalignment, or the object moved",
           "fail": "the passes disagree: the alignment is wrong; use the manual 3-point registration"}[level]
    return Verdict(level, f"{ratio:.1f}x the expected residual", thresholds, why)


def _undecided(region: dict[str, Any]) -> bool:
    """True for a region without one material told apart: not measured, no fit, or a group of candidates."""
    material = region.get("material")
    if material in ("not measured", "no candidate fits", "neutral metal"):
        return True
    return any(g != material for g in (region.get("group") or []))


#: Share of the surface without a measured material from which the materials' verdict warns (a hawk standing on
#: its neck's cut face leaves about 2 % of its surface unseen; a placement plan that never lights a whole side, 10 %).
UNMEASURED_WARN_SHARE = 0.05


def materials_verdict(doc: dict[str, Any]) -> Verdict:
    """The materials measured on the mesh (``products/object-materials.json``; see the module docstring).

    Examples
    --------
    >>> gold = {"material": "gold", "confidence": 0.93, "group": ["gold"]}
    >>> materials_verdict({"regions": [gold]}).level
    'pass'
    >>> materials_verdict({"regions": [gold, {"material": "not measured", "group": []}]}).text
    '2 regions, 1 not decided: warn'
    >>> urushi = {"material": "red urushi", "confidence": 0.97, "group": ["red urushi"]}
    >>> materials_verdict({"regions": [gold, urushi], "validation": {"mean_de2000": 6.0,
    ...                                                              "baseline_mean_de2000": 5.0}}).level
    'warn'
    >>> unseen = {"share": 0.095, "advice": "seen but never lit, on the side facing down: add a placement"}
    >>> v = materials_verdict({"regions": [gold, urushi], "not_measured": unseen})
    >>> v.level, v.text
    ('warn', '2 regions, 9.5 % of the surface not measured: warn')
    >>> v.why
    '9.5 % of the surface not measured: seen but never lit, on the side facing down: add a placement'
    """
    regions = list(doc.get("regions") or [])
    thresholds = ("pass: every region has one material told apart from the others (and the held-out photos are "
                  "predicted no worse than by one material); warn: a region not measured, fitting no candidate or "
                  f"not told apart, worse than one material, or {100 * UNMEASURED_WARN_SHARE:.0f} % of the surface "
                  "or more not measured; fail: no region measured")
    undecided = sum(_undecided(r) for r in regions)
    fitted = sum(r.get("material") not in ("not measured", "no candidate fits") for r in regions)
    val = doc.get("validation") or {}
    de, base = val.get("mean_de2000"), val.get("baseline_mean_de2000")
    # with one material fitted the measured render is the one-material render: nothing to compare
    worse = fitted >= 2 and de is not None and base is not None and float(de) > float(base)
    unmeasured = doc.get("not_measured") or {}
    share = float(unmeasured.get("share") or 0.0)
    unseen = share >= UNMEASURED_WARN_SHARE
    figure = f"{len(regions)} region{'s' if len(regions) != 1 else ''}" + (
        f", {undecided} not decided" if undecided else "") + (
        f", {100 * share:.1f} % of the surface not measured" if unseen else "")
    if not fitted:
        return Verdict("fail", figure, thresholds, "no region has a fitted material: check the lamp and camera "
                       "calibrations and that the photos show the object")
    causes = [why for flag, why in (
        (undecided, "a region has no single answer: photograph it under more lamp angles or name the catalogued "
                    "materials"),
        (worse, "the measured materials predict the held-out photos worse than one material for the whole object"),
        (unseen, f"{100 * share:.1f} % of the surface not measured: "
                 + str(unmeasured.get("advice") or "add a placement that shows it to the camera and the lamp")))
        if flag]
    if causes:
        return Verdict("warn", figure, thresholds, "; ".join(causes))
    return Verdict("pass", figure, thresholds, "every region has one material, told apart from the other candidates")


def calibration_hint(done: dict[str, Any]) -> str | None:
    """What to do next for the camera and lamp calibration, or None when nothing is pending.

    ``done`` holds, besides :func:`current_step`'s keys: ``camera`` and ``lamps`` (a camera / lamp
    calibration chosen for processing), ``target`` (the plan kind of the open session when it is a
    ``camera-calibration`` or ``lamp-calibration`` one) and ``target_captured`` (its capture complete).
    They are needed only to pose the photos on the mesh (*Measure materials on the mesh*).

    Examples
    --------
    >>> calibration_hint({"calibrated": True, "target": "camera-calibration", "target_captured": True})
    "press 'Calibrate the camera from the open session (board)' (Processing tab)"
    >>> calibration_hint({"calibrated": True, "camera": True, "lamps": True}) is None
    True
    """
    target, captured = done.get("target"), done.get("target_captured")
    if target == "camera-calibration":
        if not captured:
            return "press Start on the Capture tab (plan camera-calibration): the board at every step, flat then on wedges"
        if not done.get("calibrated"):
            return "calibrate the scanner first (a sphere scan with photos): it ties the camera to the turntable"
        if not done.get("camera"):
            return "press 'Calibrate the camera from the open session (board)' (Processing tab)"
    if target == "lamp-calibration":
        if not captured:
            return "press Start on the Capture tab (plan lamp-calibration): the chrome sphere at every step"
        if not done.get("camera"):
            return "calibrate the camera first (the ChArUco board), then the lamps"
        if not done.get("lamps"):
            return "press 'Calibrate the lamps from the open session (mirror sphere)' (Processing tab)"
    if not done.get("calibrated") or (done.get("camera") and done.get("lamps")):
        return None
    if not done.get("camera"):
        return "for materials on the mesh, capture the ChArUco board in a new session (plan camera-calibration)"
    return "for materials on the mesh, capture the chrome sphere in a new session (plan lamp-calibration)"


def describe(done: dict[str, Any]) -> str:
    """The strip's line: the next step and what to do there."""
    step = current_step(done)
    return f"Next: {step} — {step_hint(step)}"
