"""The fields of an object-materials document checked before anything reads them.

A session folder from elsewhere is untrusted: its ``products/object-materials.json`` may match its checksum
and still hold a confidence that is a string, a share that is a list or a validation that is a number.  The
window, the report and the export format those fields; :func:`materials_document_problem` finds the first
field of the wrong kind, so that the reader refuses the file with one line instead of failing on it later.

Rules by a field's whole path come first (the top level's containers), then by its name at any depth (a
region's ``confidence``, a validation frame's ``mean_de2000``), then by the end of its name (``_mm2``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

__all__ = ["materials_document_problem"]


def _number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _count(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool) and x >= 0


def _optional(check: Callable[[Any], bool]) -> Callable[[Any], bool]:
    return lambda x: x is None or check(x)


_NUMBER = (_optional(_number), "a finite number or null")
_AREA = (lambda x: _number(x) and x >= 0, "a non-negative number (mm2)")
_AREAS = (lambda x: isinstance(x, list) and all(_number(a) and a >= 0 for a in x), "a list of non-negative numbers (mm2)")
_FRACTION = (_optional(lambda x: _number(x) and 0.0 <= x <= 1.0), "a number from 0 to 1 or null")
_COUNT = (_count, "a whole number of at least 0")
_TEXT = (_optional(lambda x: isinstance(x, str)), "a string or null")
_TABLE = (lambda x: isinstance(x, dict), "a table")
_LIST = (lambda x: isinstance(x, list), "a list")
_NAMES = (lambda x: isinstance(x, list) and all(isinstance(s, str) for s in x), "a list of strings")
_VALUES = (lambda x: isinstance(x, dict) and all(v is None or _number(v) for v in x.values()),
           "a table of finite numbers")


def _material_spec(x: Any) -> bool:
    """True for None or a spec :func:`processing.materials.presets.check_material_spec` accepts."""
    if x is None:
        return True
    if not isinstance(x, str):
        return False
    from processing.materials.presets import MaterialError, check_material_spec

    try:
        check_material_spec(x)
    except MaterialError:
        return False
    return True


_SPEC = (_material_spec, "a material spec kogei accepts (a preset with parameters in range, "
         "e.g. 'gold:roughness=0.2') or null")
_VECTOR = (_optional(lambda x: isinstance(x, list) and len(x) == 3 and all(map(_number, x))),
           "three finite numbers or null")

#: Rules by field name, at any depth of the document.
_BY_NAME: dict[str, tuple[Callable[[Any], bool], str]] = {
    "confidence": _FRACTION, "share": _FRACTION, "chi2_per_dof": _NUMBER, "coherence": _NUMBER,
    "colour_scatter": _NUMBER, "model_error": _NUMBER, "group": _NAMES, "parameters": _VALUES,
    "uncertainties": _VALUES, "facing": _VECTOR, "material": _TEXT, "spec": _SPEC, "advice": _TEXT,
    "note": _TEXT, "reason": _TEXT, "light_spectrum": _TEXT, "frame": _TEXT, "faces": _COUNT,
    "vertices": _COUNT, "n_observations": _COUNT, "n_lit": _COUNT, "pixels": _COUNT, "n_frames": _COUNT,
    "block_px": _COUNT, "pieces_tested": _COUNT, "pieces_disagreeing": _COUNT, "timings_s": _VALUES,
    "candidates": _LIST, "disagreeing_better_regions": _LIST,
}
#: Rules by the end of a field's name, at any depth.
_BY_SUFFIX: tuple[tuple[str, tuple[Callable[[Any], bool], str]], ...] = (
    ("_de2000", _NUMBER), ("_mm2", _AREA), ("_mm", _NUMBER), ("_px", _NUMBER), ("_s", _NUMBER),
)
#: Rules by a field's whole path, before those by name.
_BY_PATH: dict[str, tuple[Callable[[Any], bool], str]] = {
    "not_measured": _TABLE, "validation": _TABLE, "baseline": _TABLE, "segmentation": _TABLE, "frames": _TABLE,
    "normals": _TABLE, "segmentation.split.area_mm2": _AREAS, "validation.frames": _LIST, "validation.pooled": _TABLE,
    "validation.regions": _TABLE, "validation.point_spread": _TABLE, "frames.fit": _NAMES, "frames.held_out": _NAMES,
}


def _rule(key: str) -> tuple[Callable[[Any], bool], str] | None:
    if key in _BY_NAME:
        return _BY_NAME[key]
    return next((rule for suffix, rule in _BY_SUFFIX if key.endswith(suffix)), None)


def _walk(node: Any, path: str) -> str | None:
    """The first field under ``node`` that breaks its name's rule, as ``"path must be ..., got ..."``."""
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        where = f"{path}[{key}]" if isinstance(key, int) else f"{path}.{key}" if path else str(key)
        rule = _BY_PATH.get(where) or (_rule(key) if isinstance(key, str) else None)
        if rule is not None and not rule[0](value):
            return f"{where} must be {rule[1]}, got {_shown(value)}"
        found = _walk(value, where)
        if found:
            return found
    return None


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def materials_document_problem(doc: dict[str, Any]) -> str | None:
    """The first field of an object-materials document of the wrong kind, or None when every field is usable.

    Parameters
    ----------
    doc
        The parsed ``products/object-materials.json``.

    Returns
    -------
    str or None
        ``"<field path> must be <kind>, got <value>"``.

    Examples
    --------
    >>> ok = {"regions": [{"index": 0, "material": "gold", "confidence": 0.9, "group": ["gold"]}],
    ...       "not_measured": {"faces": 3, "share": 0.01, "facing": [0, 0, -1]}}
    >>> materials_document_problem(ok) is None
    True
    >>> materials_document_problem({**ok, "not_measured": {"share": "9 %"}})
    "not_measured.share must be a number from 0 to 1 or null, got '9 %'"
    >>> materials_document_problem({**ok, "validation": [3.0]})
    'validation must be a table, got [3.0]'
    >>> materials_document_problem({**ok, "validation": {"frames": [{"mean_de2000": float("nan")}]}})
    'validation.frames[0].mean_de2000 must be a finite number or null, got nan'
    """
    regions = doc.get("regions")
    if not isinstance(regions, list) or not regions:
        return f"regions must be a non-empty list of the regions, got {_shown(regions)}"
    for i, region in enumerate(regions):
        if not isinstance(region, dict) or region.get("index") != i:
            return f"regions[{i}] must be a table with index {i}, got {_shown(region)}"
    return _walk(doc, "")
