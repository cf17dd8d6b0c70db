"""The version of the code a processing step runs: a SHA-256 over the source files it uses.

``kogei batch`` reruns a step when its code changed (docs/batch.md).  The
step names the ``app`` modules it calls; their source files are hashed
together with every ``processing`` and ``render`` module they import,
directly or transitively (found by reading ``import`` statements anywhere in
the files with :mod:`ast`, so imports inside functions count too).  Editing
any of those files, even a comment, changes the version; editing a driver or
the GUI does not.

Examples
--------
>>> v = code_version(("app.session",))
>>> len(v.sha256), "app/session.py" in v.files
(64, True)
"""

from __future__ import annotations

import ast
import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CodeVersion", "code_version", "module_imports", "FOLLOWED_PACKAGES"]

#: Packages whose modules are followed through their imports (pure computation the steps depend on).
FOLLOWED_PACKAGES = ("processing", "render")
_ROOT = Path(__file__).resolve().parents[2]


@dataclass(frozen=True)
class CodeVersion:
    """SHA-256 over the sorted (path, content) pairs, and the files (relative to the project root)."""

    sha256: str
    files: tuple[str, ...]


def _module_file(name: str) -> Path | None:
    path = _ROOT.joinpath(*name.split("."))
    for candidate in (path.with_suffix(".py"), path / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def module_imports(source: str, package: str = "") -> set[str]:
    """Absolute names of the modules a source text imports (``import a.b``, ``from a import b``, relative forms).

    ``from x import y`` yields both ``x`` and ``x.y`` (``y`` may be a submodule);
    names that are not modules are dropped by the caller.

    Examples
    --------
    >>> sorted(module_imports("import numpy as np\\nfrom processing import spectra\\n"))
    ['numpy', 'processing', 'processing.spectra']
    """
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parts, base] if base else parts)
            if base:
                names.add(base)
                names.update(f"{base}.{alias.name}" for alias in node.names if alias.name != "*")
    return names


@functools.lru_cache(maxsize=64)
def code_version(modules: tuple[str, ...]) -> CodeVersion:
    """Hash the named modules and every ``processing``/``render`` module they reach through imports.

    Parameters
    ----------
    modules
        Dotted module names (e.g. ``("app.workflows.process_session",)``); each must exist.

    Raises
    ------
    ValueError
        A named module has no source file in the project.
    """
    seen: dict[str, Path] = {}
    waiting = list(modules)
    for name in modules:
        if _module_file(name) is None:
            raise ValueError(f"code_version: module {name!r} has no source file under {_ROOT}")
    while waiting:
        name = waiting.pop()
        if name in seen:
            continue
        path = _module_file(name)
        if path is None:
            continue
        seen[name] = path
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for imported in module_imports(path.read_text(encoding="utf-8"), package):
            if imported.split(".")[0] in FOLLOWED_PACKAGES:
                # Importing a.b.c runs a/__init__.py and a/b/__init__.py too.
                parts = imported.split(".")
                waiting.extend(n for n in (".".join(parts[:i]) for i in range(1, len(parts) + 1)) if n not in seen)
    digest = hashlib.sha256()
    files = []
    for path in sorted(set(seen.values())):
        rel = path.relative_to(_ROOT).as_posix() if path.is_relative_to(_ROOT) else str(path)
        files.append(rel)
        digest.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
    return CodeVersion(digest.hexdigest(), tuple(files))
