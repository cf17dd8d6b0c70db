"""Functions of processing/ and render/ stay short: at most 60 code lines each.

A longer function is a script of numbered steps waiting to become a driver
of named private functions.  Code lines are the body's lines that are not
blank, not comments and not the docstring.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LIMIT = 60
FILES = sorted(p for layer in ("processing", "render") for p in (ROOT / layer).rglob("*.py"))


def code_lines(lines: list[str], fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    """Non-blank, non-comment lines of ``fn``'s body after its docstring."""
    first = fn.body[0]
    start = first.lineno
    if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
        start = first.end_lineno + 1
    return sum(1 for line in lines[start - 1:fn.end_lineno] if line.strip() and not line.strip().startswith("#"))


def long_functions(path: Path) -> list[str]:
    """``name (n lines)`` for every function of a file over :data:`LIMIT` code lines."""
    text = path.read_text(encoding="utf-8")
    lines = text.split("\n")
    return [f"{node.name} at line {node.lineno} ({n} code lines)"
            for node in ast.walk(ast.parse(text)) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and (n := code_lines(lines, node)) > LIMIT]


def test_the_counter_counts_code_lines_only(tmp_path):
    src = 'def f():\n    """Doc.\n\n    More.\n    """\n    # note\n\n    a = 1\n    return a\n'
    assert code_lines(src.split("\n"), ast.parse(src).body[0]) == 2
    path = tmp_path / "long.py"
    path.write_text("def g():\n" + "    x = 1\n" * (LIMIT + 1))
    assert long_functions(path) == [f"g at line 1 ({LIMIT + 1} code lines)"]


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_functions_are_short(path):
    found = long_functions(path)
    assert not found, f"{path.relative_to(ROOT)}: " + "; ".join(found)
