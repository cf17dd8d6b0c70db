"""Checks shared by the command-line bad-input tests: one error line, exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

from app.cli import main
from app.session import MANIFEST

__all__ = ["files_under", "fails_with_one_line", "png_header"]


def png_header(width: int, height: int) -> bytes:
    """A PNG that declares ``width`` x ``height`` pixels and holds none (a decompression bomb's header)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def files_under(base: Path) -> dict[str, int]:
    """Every file under ``base`` with its size (what a failed command must leave as it was)."""
    return {str(p.relative_to(base)): p.stat().st_size for p in base.rglob("*") if p.is_file()}


def fails_with_one_line(argv: list[str], capsys, base: Path, *needles: str, manifests_may_change: bool = False) -> str:
    """Run ``kogei argv``: exit code 2, one line on stderr holding every needle, no file under ``base`` written.

    ``manifests_may_change``: opening a session may checkpoint its ``session.json``; nothing else may change.
    Returns the error line.
    """
    before = files_under(base)
    code = main(argv)
    out = capsys.readouterr()
    assert code == 2, (code, out.err)
    assert "Traceback" not in out.err, out.err
    # progress notes are indented; the error is one line, the last
    errors = [line for line in out.err.splitlines() if not line.startswith("  ")]
    assert len(errors) == 1 and out.err.rstrip().endswith(errors[0]), out.err
    err = errors[0]
    assert err.startswith(f"kogei {argv[0]}: error: "), err
    for n in needles:
        assert n in err, (n, err)
    after = files_under(base)
    changed = {k for k in set(before) | set(after) if before.get(k) != after.get(k)
               and not (manifests_may_change and Path(k).name == MANIFEST)}
    assert not changed, f"a failed command wrote files: {sorted(changed)}"
    return err
