"""Plain words for the session report: how far a material answer can be trusted, units, the capture plan.

The report is read by curators, not only by the engineers who ran the station, so every figure it
shows in its summary and captions goes through here: a region's answer becomes a verdict
(:func:`verdict`: reliable, uncertain, unreliable, not measured) with one sentence saying why, an
unknown aperture reads "unknown" (:func:`exposure_text`), and the capture plan is a table of named
settings rather than a programming-language dict (:func:`plan_rows`).

A region is **unreliable** when the materials code answers :data:`NO_FIT` or when the best candidate
misses the measurement by more than :data:`processing.materials.confidence.MAX_MISFIT` (a reduced
chi-square above 25: an answer written before that rule existed still names a material, and is
flagged all the same); **uncertain** when its confidence is below :data:`RELIABLE_CONFIDENCE`, when
other candidates cannot be told from it, or when its fit quality was not recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from processing.materials.confidence import MAX_MISFIT, NEUTRAL_METAL, NO_FIT, NOT_MEASURED

__all__ = ["Verdict", "verdict", "RELIABLE_CONFIDENCE", "exposure_text", "plan_rows", "misfit_words",
           "misfit_number", "LEVEL_LABEL"]

#: Lowest confidence called reliable.  The confidences are calibrated (the bench's reliability diagram in
#: the report): at 0.8 about one answer in five is wrong, which a curator should be told.
RELIABLE_CONFIDENCE = 0.8

#: Badge text of each verdict level.
LEVEL_LABEL = {"reliable": "reliable", "uncertain": "uncertain", "unreliable": "unreliable",
               "missing": "not measured"}


@dataclass(frozen=True)
class Verdict:
    """How far a region's material answer can be trusted.

    Attributes
    ----------
    level
        ``"reliable"``, ``"uncertain"``, ``"unreliable"`` or ``"missing"`` (not measured).
    answer
        The answer in words ("nami-shibuichi", "no candidate fits", ...).
    why
        One plain sentence: why this level.
    """

    level: str
    answer: str
    why: str

    @property
    def label(self) -> str:
        """The level's badge text."""
        return LEVEL_LABEL[self.level]


def misfit_words(misfit: float) -> str:
    """A reduced chi-square in words.

    Examples
    --------
    >>> misfit_words(0.8)
    'matches within the measurement noise'
    >>> misfit_words(159.0)
    'misses the measurement by about 13 times the expected noise'
    """
    if misfit <= 1.5:
        return "matches within the measurement noise"
    return f"misses the measurement by about {math.sqrt(misfit):.0f} times the expected noise"


def misfit_number(misfit: Any) -> str:
    """A reduced chi-square for a table: two decimals below 10, whole above; "" when not recorded.

    Examples
    --------
    >>> misfit_number(0.0271), misfit_number(159.77), misfit_number(None)
    ('0.03', '160', '')
    """
    value = _number(misfit)
    if value is None:
        return ""
    return f"{value:.2f}" if value < 10 else f"{value:.0f}"


def _number(value: Any) -> float | None:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if math.isfinite(out) else None


def verdict(material: str | None, confidence: Any, misfit: Any, group: Any = (), reason: str = "") -> Verdict:
    """The verdict on one region's answer.

    Parameters
    ----------
    material
        The answer: a material, :data:`NEUTRAL_METAL`, :data:`NO_FIT`, :data:`NOT_MEASURED` or None.
    confidence
        Its stated confidence (0..1) or None.
    misfit
        Reduced chi-square of the best candidate (1: fits to the noise), or None when not recorded.
    group
        The candidates the answer stands for (best first).
    reason
        Why a region is not measured (what to capture).

    Returns
    -------
    Verdict

    Examples
    --------
    >>> verdict("lead", 0.99, 159.0).level
    'unreliable'
    >>> verdict("gold", 0.97, 0.6).level
    'reliable'
    >>> verdict("gold", 0.55, 0.6, ["gold", "bronze"]).why
    'confidence 0.55: about one such answer in 2 is wrong; cannot be told from bronze'
    """
    group = [str(g) for g in group or []]
    conf = _number(confidence)
    fit = _number(misfit)
    if material == NOT_MEASURED:
        return Verdict("missing", "not measured", reason or "too few usable observations to fit a material")
    if material is None:
        return Verdict("unreliable", "not identified", reason or "no material was identified")
    if material == NO_FIT:
        best = group[0] if group else "none"
        how = "" if fit is None else f": the closest, {best}, {misfit_words(fit)}"
        return Verdict("unreliable", "no candidate fits", f"none of the known materials matches{how}")
    if fit is not None and fit > MAX_MISFIT:
        return Verdict("unreliable", material, f"fits poorly: {misfit_words(fit)} (reduced chi-square {fit:.0f}, "
                                               f"above {MAX_MISFIT:.0f}), so the name is not trustworthy")
    notes = []
    if conf is not None and conf < RELIABLE_CONFIDENCE:
        notes.append(f"confidence {conf:.2f}: about one such answer in {max(2, round(1 / max(1 - conf, 1e-6)))} "
                     "is wrong")
    others = [g for g in group if g != material]
    if material == NEUTRAL_METAL:
        text = f"a colourless metal: one of {', '.join(group)}, which look alike to the camera"
        return Verdict("uncertain" if notes else "reliable", material, "; ".join([text] + notes))
    if others:
        notes.append("cannot be told from " + ", ".join(others[:3]) + (f" and {len(others) - 3} others"
                                                                        if len(others) > 3 else ""))
    if fit is None:
        notes.append("how well it fits was not recorded")
    if notes:
        return Verdict("uncertain", material, "; ".join(notes))
    why = f"confidence {conf:.2f}" if conf is not None else "fits"
    return Verdict("reliable", material, why + ("" if fit is None else f"; {misfit_words(fit)}"))


def exposure_text(exposure_s: Any, iso: Any, f_number: Any) -> str:
    """An exposure in words; a value the camera did not report reads "unknown" (never ``f/0.0``).

    Examples
    --------
    >>> exposure_text(0.0025, 100, 0.0)
    '1/400 s, ISO 100, aperture unknown'
    >>> exposure_text(None, None, 8)
    'time unknown, ISO unknown, f/8'
    """
    t, n, f = _number(exposure_s), _number(iso), _number(f_number)
    if t is None or t <= 0:
        time = "time unknown"
    elif t < 0.5:
        time = f"1/{round(1 / t)} s"
    else:
        time = f"{t:g} s"
    iso_text = "ISO unknown" if n is None or n <= 0 else f"ISO {n:.0f}"
    ap = "aperture unknown" if f is None or f <= 0 else f"f/{f:g}"
    return f"{time}, {iso_text}, {ap}"


_PLAN_LABELS = {
    "kind": "kind of capture", "steps": "table positions per turn", "passes": "placements of the object (passes)",
    "camera_angles_deg": "photos at table angles", "chart": "colour chart photographed", "lasers": "laser lines used",
    "camera": "camera used", "chart_frames": "chart photos per pass", "exposure_s": "exposure",
}


def _value(key: str, value: Any) -> str:
    if isinstance(value, bool):
        return "yes" if value else "no"
    if key.endswith("_deg") and isinstance(value, (list, tuple)):
        shown = ", ".join(f"{float(v):g}" for v in value[:24])
        return (f"{len(value)} angle{'s' if len(value) != 1 else ''}: {shown}{' ...' if len(value) > 24 else ''} "
                "degrees") if value else "none"
    if isinstance(value, (list, tuple)):
        return ", ".join(str(v) for v in value) or "none"
    if isinstance(value, dict):
        return "; ".join(f"{k}: {_value(str(k), v)}" for k, v in value.items()) or "none"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def plan_rows(plan: Any) -> list[tuple[str, str]]:
    """The capture plan as ``(setting, value)`` rows in words.

    Examples
    --------
    >>> plan_rows({"kind": "scan", "passes": 2, "chart": True, "camera_angles_deg": [0.0, 90.0]})
    [('kind of capture', 'scan'), ('placements of the object (passes)', '2'), ('colour chart photographed', 'yes'), \
('photos at table angles', '2 angles: 0, 90 degrees')]
    """
    if not isinstance(plan, dict):
        return []
    return [(_PLAN_LABELS.get(str(k), str(k).replace("_", " ")), _value(str(k), v)) for k, v in plan.items()]
