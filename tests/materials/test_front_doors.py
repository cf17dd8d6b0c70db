"""The materials and cloth packages import each other's modules; each entry point must import first."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("module", ["processing.materials", "processing.cloth", "processing.materials.presets",
                                    "processing.cloth.model"])
def test_imports_first_in_a_fresh_interpreter(module):
    code = f"import {module}, processing.materials as m, processing.cloth as c; print(len(m.__all__), len(c.__all__))"
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr


@pytest.mark.parametrize("package", ["processing.materials", "processing.cloth"])
def test_front_door_exports_every_public_name_of_its_modules(package):
    import importlib
    import pkgutil

    pkg = importlib.import_module(package)
    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name.startswith("_"):
            continue                    # private implementation modules (scikit-image style)
        mod = importlib.import_module(f"{package}.{info.name}")
        for name in mod.__all__:
            assert getattr(pkg, name) is getattr(mod, name), f"{package}.{name}"
            assert name in pkg.__all__
