"""processing.common.npz.read_npz: an untrusted .npz is read only after every member is checked."""

from __future__ import annotations

import io
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

from processing.common.npz import read_npz
from processing.errors import InputError


class _Refused(InputError):
    """The caller's own error class."""


def _read(path: Path, keys=("a", "b"), **kw):
    return read_npz(path, keys, what="a test archive", remedy="write it again with the test", error=_Refused, **kw)


def _refused(path: Path, *needles: str, **kw) -> str:
    with pytest.raises(_Refused) as err:
        _read(path, **kw)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and msg.endswith(kw.get("memory_remedy", "write it again with the test"))
    for needle in needles:
        assert needle in msg, msg
    return msg


def _good(path: Path) -> Path:
    np.savez(path, a=np.arange(6, dtype=np.float32).reshape(2, 3), b=np.array([1, 2], np.int64))
    return path


def _huge_header(shape: tuple[int, ...], descr: str = "<i4") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + bytes(64)


def _replace_member(path: Path, name: str, data: bytes) -> None:
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    members[name] = data
    with zipfile.ZipFile(path, "w") as zf:
        for n, d in members.items():
            zf.writestr(n, d)


def test_a_good_archive_reads_like_np_load(tmp_path):
    got = _read(_good(tmp_path / "g.npz"))
    assert got["a"].shape == (2, 3) and got["a"].dtype == np.float32 and got["b"].tolist() == [1, 2]
    assert set(read_npz(tmp_path / "g.npz", what="x", remedy="y")) == {"a", "b"}


def test_deflated_archive_reads(tmp_path):
    np.savez_compressed(tmp_path / "c.npz", a=np.zeros((50, 50)), b=np.ones(3))
    assert _read(tmp_path / "c.npz")["a"].shape == (50, 50)


@pytest.mark.parametrize("content, needle", [(b"", "empty file"), (b"hello\n", "text file"),
                                             (bytes(range(256)) * 4, "not a zip archive")])
def test_not_a_zip(tmp_path, content, needle):
    (tmp_path / "x.npz").write_bytes(content)
    _refused(tmp_path / "x.npz", "not a test archive", needle)


def test_missing_array_and_pickled_objects(tmp_path):
    np.savez(tmp_path / "m.npz", a=np.zeros(2))
    _refused(tmp_path / "m.npz", "missing b")
    np.savez(tmp_path / "o.npz", a=np.zeros(2), b=np.array([{"x": 1}], dtype=object))
    with pytest.raises(_Refused, match=r"o\.npz: array 'b' holds Python objects"):
        _read(tmp_path / "o.npz")


def test_header_claiming_more_than_the_member_holds_is_refused_before_allocating(tmp_path):
    path = _good(tmp_path / "h.npz")
    _replace_member(path, "b.npy", _huge_header((100_000_000_000,)))
    _refused(path, "array 'b'", "(100000000000,)", "member holds")


def _claim_file_size(path: Path, name: str, size: int) -> None:
    """Rewrite the uncompressed size of ``name`` in the zip's local and central headers (a lying directory)."""
    raw = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as zf:
        struct.pack_into("<I", raw, zf.getinfo(name).header_offset + 22, size)
    pos = raw.find(b"PK\x01\x02")
    while pos >= 0:
        length = struct.unpack_from("<H", raw, pos + 28)[0]
        if raw[pos + 46: pos + 46 + length] == name.encode():
            struct.pack_into("<I", raw, pos + 24, size)
        pos = raw.find(b"PK\x01\x02", pos + 4)
    path.write_bytes(bytes(raw))


def test_zip_directory_claiming_a_huge_member_is_refused(tmp_path):
    """A header and a zip directory that agree on 1 GB, in a stored member of 192 bytes."""
    path = _good(tmp_path / "z.npz")
    header = _huge_header((1_000_000_000,), "|u1")
    _replace_member(path, "b.npy", header)
    _claim_file_size(path, "b.npy", len(header) - 64 + 1_000_000_000)
    with zipfile.ZipFile(path) as zf:
        assert zf.getinfo("b.npy").file_size == len(header) - 64 + 1_000_000_000
    _refused(path, "array 'b'", "the zip directory claims", "more than they can hold")


def test_arrays_larger_than_the_available_memory(tmp_path):
    _refused(_good(tmp_path / "big.npz"), "need", "GB is available", available_bytes=10, memory_remedy="free memory")


def test_memory_error_while_reading_is_one_line(tmp_path, monkeypatch):
    def boom(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr(np.lib.format, "read_array", boom)
    _refused(_good(tmp_path / "m.npz"), "array 'a'", "free memory", memory_remedy="free memory")


def test_truncated_archive(tmp_path):
    path = _good(tmp_path / "t.npz")
    path.write_bytes(path.read_bytes()[:200])
    _refused(path, "damaged")
