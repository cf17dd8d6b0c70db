"""The layers' import rules hold on the whole tree, and the check catches a deliberate bad import."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.architecture.layering import violations

ROOT = Path(__file__).resolve().parents[2]


def test_the_tree_keeps_the_layering():
    found = violations(ROOT)
    assert not found, "import rules broken:\n" + "\n".join(map(str, found))


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return tmp_path


@pytest.mark.parametrize(("name", "text", "rule"), [
    ("processing/geometry/x.py", "def f():\n    from app.session import Session\n", "processing may import only"),
    ("processing/geometry/x.py", "import drivers.turntable\n", "processing may import only"),
    ("render/x.py", "from mocks import world\n", "render may import only"),
    ("render/x.py", "from PySide6 import QtCore\n", "only app may import Qt"),
    ("drivers/x.py", "import processing.errors\n", "drivers may import only"),
    ("mocks/x.py", "import drivers.transport\n", "mocks may import only"),
    ("processing/geometry/x.py", "from processing.spectral.spectra import cmfs\n", "independent"),
    ("processing/materials/x.py", "from ..geometry import surface\n", "independent"),
    ("processing/common/x.py", "import processing.materials.fresnel\n", "base layer"),
    ("mocks/x.py", "import importlib\nimportlib.import_module('PySide6.QtWidgets')\n", "only app may import Qt"),
])
def test_a_deliberate_bad_import_is_caught(tmp_path, name, text, rule):
    found = violations(_tree(tmp_path, {name: text}))
    assert len(found) == 1 and rule in found[0].rule and found[0].file == name


def test_allowed_imports_pass(tmp_path):
    root = _tree(tmp_path, {
        "app/x.py": "import drivers.turntable, mocks.world, render.renderer, processing.errors\n",
        "app/gui/w.py": "from PySide6 import QtWidgets\n",
        "render/x.py": "from processing.materials.lobes import Lobe\n",
        "mocks/x.py": "from render.scene import Scene\nfrom processing.geometry import surface\n",
        "processing/cloth/x.py": "from processing.materials.fresnel import f\nfrom processing.common.files import fsync_dir\n",
        "processing/geometry/x.py": "from .surface import y\nfrom processing.errors import InputError\n",
    })
    assert violations(root) == []
