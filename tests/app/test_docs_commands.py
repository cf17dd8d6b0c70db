"""The documents cannot go stale silently: every ``kogei`` command line in README.md and docs/*.md parses
with the real argument parser, the cheap ones run, and every relative link and #anchor resolves.

A command line is a line of a fenced or indented code block that starts with ``kogei COMMAND`` (a real
subcommand; printed output such as ``kogei process: INCOMPLETE: ...`` is not one).  A concrete command
must parse with :func:`app.cli.build_parser` exactly as written (placeholders such as ``SESSION`` are
ordinary arguments); a synopsis (``[--json]``, ``draft|standard``, ``SESSION...``, ``...``) must name
only options its subcommand has, and only values an option with choices accepts.  Commands quoted inside
another (``--before-pass 'kogei mock place ...'``) are checked too.  Commands that need no hardware and
no captured session run: ``kogei materials`` and ``kogei render MESH ...`` on a small generated mesh
(at 80 x 60 pixels).  The whole documented session path runs in tests/app/test_newcomer_path.py.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from app.cli import COMMANDS, build_parser, main

REPO = Path(__file__).resolve().parents[2]
DOCUMENTS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SYNOPSIS = re.compile(r"\[|\||\.\.\.")


def _code_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of every line in a fenced block or an indented (4+ spaces) code block."""
    out, fenced = [], False
    for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        if fenced or (line.startswith("    ") and line.strip()):
            out.append((no, line))
    return out


def documented_commands() -> list[tuple[str, str]]:
    """``(where, command)`` for every ``kogei COMMAND ...`` line, continuation lines joined."""
    found = []
    for path in DOCUMENTS:
        lines = _code_lines(path)
        i = 0
        while i < len(lines):
            no, line = lines[i]
            text = line.strip().removeprefix("$ ")
            i += 1
            if not text.startswith("kogei ") or text.split()[1] not in COMMANDS:
                continue
            # a trailing backslash, or a synopsis going on in an indented '[...' line
            while i < len(lines) and (text.endswith("\\") or lines[i][1].lstrip().startswith("[")) \
                    and lines[i][0] == no + 1:
                text = text.rstrip("\\") + " " + lines[i][1].strip()
                no = lines[i][0]
                i += 1
            found.append((f"{path.relative_to(REPO)}:{no}", text))
    return found


COMMAND_LINES = documented_commands()


def _tokens(command: str) -> list[str]:
    tokens = shlex.split(command, comments=True)
    return tokens[:-1] if tokens and tokens[-1] == "&" else tokens


def _subparser_chain(tokens: list[str]) -> list[argparse.ArgumentParser]:
    """The parser of ``kogei COMMAND`` and of its action (``kogei mock place``, ``kogei cloth fit``) if given."""
    chain = [build_parser()]
    for token in tokens[1:]:
        subs = [a for a in chain[-1]._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            break
        if token in subs[0].choices:
            chain.append(subs[0].choices[token])
    return chain[1:]


def _check_synopsis(where: str, tokens: list[str]) -> None:
    chain = _subparser_chain(tokens)
    options = {s: a for p in chain for a in p._actions for s in a.option_strings}
    for k, token in enumerate(tokens):
        if " " in token:                       # a quoted command or text, checked on its own
            continue
        for flag in re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", token):
            assert flag in options, f"{where}: {tokens[1]} has no option {flag} (documented: {' '.join(tokens)})"
            action = options[flag]
            value = tokens[k + 1] if k + 1 < len(tokens) and flag == token.strip("[]") else None
            if action.choices and value and "|" in value:
                values = [v.strip("[]") for v in value.split("|")]
                bad = [v for v in values if v not in action.choices]
                assert not bad, f"{where}: {flag} does not accept {bad} (choices {sorted(action.choices)})"


def _check(where: str, command: str) -> None:
    tokens = _tokens(command)
    for token in tokens[1:]:
        if token.startswith("kogei ") and token.split()[1] in COMMANDS:
            _check(f"{where} (quoted)", token)
    if SYNOPSIS.search(" ".join(t for t in tokens if " " not in t)):
        _check_synopsis(where, tokens)
        return
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            build_parser().parse_args(tokens[1:])
    except SystemExit:
        raise AssertionError(f"{where}: {command}\n  does not parse: {err.getvalue().strip()}") from None


def test_the_documents_hold_the_commands_of_every_job():
    """The collector finds the commands (an empty or shrunken list would make the next test vacuous)."""
    assert len(COMMAND_LINES) >= 60, COMMAND_LINES
    named = {_tokens(c)[1] for _, c in COMMAND_LINES}
    assert set(COMMANDS) - named <= {"project"}, set(COMMANDS) - named


@pytest.mark.parametrize("where,command", COMMAND_LINES, ids=[w for w, _ in COMMAND_LINES])
def test_every_documented_command_parses(where, command):
    _check(where, command)


def test_a_stale_command_is_caught():
    """The checks fail on an option that does not exist, in either form (they can fail)."""
    with pytest.raises(AssertionError, match="does not parse"):
        _check("x", "kogei process SESSION --no-such-option")
    with pytest.raises(AssertionError, match="has no option --colour-depth"):
        _check("x", "kogei batch SESSION... [--colour-depth N]")
    with pytest.raises(AssertionError, match="does not accept"):
        _check("x", "kogei process SESSION [--preset draft|fast]")
    with pytest.raises(AssertionError, match="quoted"):
        _check("x", "kogei capture --out S --before-pass 'kogei mock place --ctrl D'")


def _small_mesh(path: Path) -> Path:
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh.create_sphere(radius=20.0, resolution=12)
    mesh.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(path), mesh)
    return path


RUNNABLE = [(w, c) for w, c in COMMAND_LINES
            if _tokens(c)[1] == "materials" or (_tokens(c)[1] == "render" and "MESH" in _tokens(c))]


@pytest.mark.parametrize("where,command", RUNNABLE, ids=[w for w, _ in RUNNABLE])
def test_documented_commands_without_a_session_run(where, command, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    tokens = _tokens(command)
    if "MESH" in tokens:
        mesh = str(_small_mesh(tmp_path / "mesh.ply"))
        tokens = [mesh if t == "MESH" else t for t in tokens] + ["--size", "80x60"]
    code = main(tokens[1:])
    out = capsys.readouterr()
    assert code == 0, f"{where}: {command}\n{out.err}"
    for flag in ("--out", "--xyz"):
        if flag in tokens:
            written = tmp_path / tokens[tokens.index(flag) + 1]
            assert written.is_file() and written.stat().st_size > 0, f"{where}: {written} not written"
    if tokens[1] == "materials":
        assert out.out.strip(), f"{where}: printed nothing"


# ------------------------------------------------------------------------------------------------ links
def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]|<[^>]+>", "", heading.strip().lower())
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    anchors = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip().startswith("```"):
            fenced = not fenced
        if fenced:
            continue
        m = re.match(r"#{1,6}\s+(.*)", line)
        if m:
            slug = _slug(m.group(1))
            n = seen.get(slug, 0)
            anchors.add(slug if n == 0 else f"{slug}-{n}")
            seen[slug] = n + 1
        anchors.update(re.findall(r"<a\s+(?:id|name)=\"([^\"]+)\"", line))
    return anchors


def _links(path: Path) -> list[tuple[int, str]]:
    out, fenced = [], False
    for no, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if line.strip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            out += [(no, t) for t in re.findall(r"\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", line)]
    return out


def test_slugs_follow_github():
    assert _slug("The report (`products/process-report.json`, also `kogei process --json`)") == \
        "the-report-productsprocess-reportjson-also-kogei-process---json"
    assert _slug("A first session, step by step") == "a-first-session-step-by-step"


def _broken_links(doc: Path) -> list[str]:
    broken = []
    for no, target in _links(doc):
        if re.match(r"[a-z]+:", target):          # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        dest = (doc.parent / file).resolve() if file else doc
        if not dest.exists():
            broken.append(f"{doc.name}:{no}: {target}: {file} does not exist")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            broken.append(f"{doc.name}:{no}: {target}: no heading #{anchor} in {dest.name}")
    return broken


@pytest.mark.parametrize("doc", DOCUMENTS, ids=[str(d.relative_to(REPO)) for d in DOCUMENTS])
def test_relative_links_and_anchors_resolve(doc):
    broken = _broken_links(doc)
    assert not broken, "\n".join(broken)


def test_a_broken_link_or_anchor_is_caught(tmp_path):
    (tmp_path / "a.md").write_text("# Title\n\n## Two words\n\n[ok](#two-words) [ok](a.md#title) "
                                   "[bad](#three-words) [bad](b.md) [web](https://example.org/x#y)\n")
    assert [b.split(": ")[1] for b in _broken_links(tmp_path / "a.md")] == ["#three-words", "b.md"]
