"""The import rules of kogei's layers, checked on the source text.

Every ``import`` and ``from ... import`` anywhere in a file counts, including
those inside functions, relative forms and ``importlib.import_module`` with a
literal name.  The allowed edges (``docs/architecture.md``):

* ``app`` -> ``drivers``, ``processing``, ``render``, ``mocks``;
* ``render`` -> ``processing``;
* ``mocks`` -> ``processing``, ``render``;
* ``processing`` and ``drivers`` import none of the other layers;
* only ``app`` imports Qt;
* inside ``processing``, ``geometry`` and the colour domains (``camera``,
  ``spectral``, ``materials``, ``cloth``) never import each other, and
  ``processing.common`` / ``processing.errors`` import no domain.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

LAYERS = ("app", "drivers", "processing", "render", "mocks")
ALLOWED = {
    "app": {"app", "drivers", "processing", "render", "mocks"},
    "render": {"render", "processing"},
    "mocks": {"mocks", "processing", "render"},
    "processing": {"processing"},
    "drivers": {"drivers"},
}
QT = ("PySide6", "PyQt5", "PyQt6", "shiboken6")
COLOUR = {"camera", "spectral", "materials", "cloth", "lighting"}
BASE = {"common", "errors"}


@dataclass(frozen=True)
class Violation:
    """One import that breaks a rule."""

    file: str
    line: int
    imported: str
    rule: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}: imports {self.imported}: {self.rule}"


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imports_of(source: str, module: str, is_package: bool) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in a source text."""
    found: list[tuple[int, str]] = []
    package = module if is_package else module.rpartition(".")[0]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            if base == "processing" and not node.level:
                # ``from processing import geometry`` names a subpackage
                found.extend((node.lineno, f"processing.{a.name}") for a in node.names)
            else:
                found.append((node.lineno, base))
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr == "import_module" and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            found.append((node.lineno, node.args[0].value))
    return found


def _rule_broken(module: str, imported: str) -> str | None:
    layer, top = module.split(".")[0], imported.split(".")[0]
    if top in QT and layer != "app":
        return "only app may import Qt"
    if top in LAYERS and top not in ALLOWED[layer]:
        return f"{layer} may import only {', '.join(sorted(ALLOWED[layer]))}"
    if layer == "processing" and top == "processing":
        here = module.split(".")[1] if module.count(".") else ""
        there = imported.split(".")[1] if imported.count(".") else ""
        if not there or not here or here == there:
            return None
        if here in BASE and there not in BASE:
            return f"processing.{here} is the base layer and imports no domain"
        if (here == "geometry" and there in COLOUR) or (here in COLOUR and there == "geometry"):
            return "processing.geometry and the colour domains are independent"
    return None


def violations(root: str | Path) -> list[Violation]:
    """Every import under ``root``'s layer folders that breaks a rule."""
    root = Path(root)
    found: list[Violation] = []
    for layer in LAYERS:
        for path in sorted((root / layer).rglob("*.py")):
            module = _module_name(root, path)
            source = path.read_text(encoding="utf-8")
            for line, imported in imports_of(source, module, path.name == "__init__.py"):
                rule = _rule_broken(module, imported)
                if rule:
                    found.append(Violation(path.relative_to(root).as_posix(), line, imported, rule))
    return found
