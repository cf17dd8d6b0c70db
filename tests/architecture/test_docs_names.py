"""Every dotted name that docs/architecture.md cites exists, so the equation table cannot rot."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

DOC = Path(__file__).resolve().parents[2] / "docs" / "architecture.md"
NAMES = sorted(set(re.findall(r"`((?:processing|render|app|mocks|drivers)(?:\.\w+)+)`", DOC.read_text(encoding="utf-8"))))


def _resolve(dotted: str) -> object:
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(dotted)


def test_the_page_cites_names():
    assert len(NAMES) > 20


@pytest.mark.parametrize("dotted", NAMES)
def test_a_cited_name_exists(dotted):
    assert _resolve(dotted) is not None
