"""Settings for every test pytest collects: the tests and the packages' doctests."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator

import pytest


@pytest.fixture(scope="session", autouse=True)
def _temporary_files_in_pytests_folder(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The system's temporary folder, for this test session, is a folder of pytest's own.

    Doctests and the code under test make temporary folders (``tempfile.mkdtemp``, a simulated station's
    ports) that outlive them; inside pytest's folder they go when pytest prunes its old runs instead of
    piling up in the system's.  ``TMPDIR`` carries the same folder to the commands the tests run.
    """
    folder = str(tmp_path_factory.mktemp("tempfile"))
    before = tempfile.tempdir, os.environ.get("TMPDIR")
    tempfile.tempdir = folder
    os.environ["TMPDIR"] = folder
    try:
        yield
    finally:
        tempfile.tempdir = before[0]
        if before[1] is None:
            os.environ.pop("TMPDIR", None)
        else:
            os.environ["TMPDIR"] = before[1]
