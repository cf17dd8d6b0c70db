"""Every public function and class of processing/ and render/ documents its parameters and result.

"Public" is what a module lists in ``__all__``.  A function (or a class's
``__init__`` signature, for classes) with parameters needs a numpydoc
``Parameters`` section; one whose return annotation is not ``None`` needs
``Returns`` (or ``Yields`` for a generator).  ruff checks the sections' form;
this checks they are there.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FILES = sorted(p for layer in ("processing", "render") for p in (ROOT / layer).rglob("*.py"))


def _all_names(tree: ast.Module) -> list[str]:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            return [e.value for e in node.value.elts if isinstance(e, ast.Constant)]
    return []


def _params(fn: ast.FunctionDef | ast.AsyncFunctionDef, method: bool) -> list[str]:
    a = fn.args
    names = [x.arg for x in (*a.posonlyargs, *a.args, *a.kwonlyargs)]
    if a.vararg:
        names.append(a.vararg.arg)
    if a.kwarg:
        names.append(a.kwarg.arg)
    return names[1:] if method and names else names


def _returns_value(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    r = fn.returns
    return r is not None and not (isinstance(r, ast.Constant) and r.value is None)


def missing_sections(path: Path) -> list[str]:
    """``name: what is missing`` for each public function or class of a module."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    public = set(_all_names(tree))
    out = []
    for node in tree.body:
        if getattr(node, "name", None) not in public:
            continue
        doc = ast.get_docstring(node) or ""
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            if _params(node, False) and "Parameters\n" not in doc:
                out.append(f"{node.name}: no Parameters section")
            if _returns_value(node) and "Returns\n" not in doc and "Yields\n" not in doc:
                out.append(f"{node.name}: no Returns section")
        elif isinstance(node, ast.ClassDef):
            init = next((b for b in node.body if isinstance(b, ast.FunctionDef) and b.name == "__init__"), None)
            fields = [b for b in node.body if isinstance(b, ast.AnnAssign)]
            if not doc:
                out.append(f"{node.name}: no docstring")
            elif init is not None and _params(init, True) and "Parameters\n" not in doc and "Attributes\n" not in doc \
                    and "Parameters\n" not in (ast.get_docstring(init) or ""):
                out.append(f"{node.name}: no Parameters section")
            elif init is None and len(fields) > 1 and "Parameters\n" not in doc and "Attributes\n" not in doc:
                out.append(f"{node.name}: fields not documented (Parameters or Attributes)")
    return out


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_public_names_document_parameters_and_returns(path):
    missing = missing_sections(path)
    assert not missing, f"{path.relative_to(ROOT)}: " + "; ".join(missing)
