"""Test-wide settings.

On CI (``CI`` set) hypothesis runs derandomized, so a landing is judged on a
reproducible set of examples; developers' runs keep exploring new random
examples, which is how edge cases (denormal cosines, ...) are found.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


# Files that take longest under ``make test`` (seconds per file from ``--durations=0``, slowest first).  With ``--dist loadfile``
# (pyproject's addopts) every file runs whole on one worker, so a module's fixtures are built once, and the
# workers take files in collection order (each worker is handed the next file while it still has two or fewer
# tests of its own pending): putting these first spreads them over both workers at the start instead of leaving
# one of them alone with a long file at the end.  The registration's tests are two files (pairs, several
# passes) so that they can run on both workers at once.
SLOWEST_FILES = (                                       # seconds per file, make test, 2026-11-29 (676 s in all)
    "tests/app/test_demo.py",                           # 123 s
    "tests/app/test_newcomer_path.py",                  # 93 s
    "tests/geometry/test_registration.py",              # 82 s the pairs
    "tests/gui/test_gui_whole_session_posed.py",        # 68 s
    "tests/app/test_batch.py",                          # 48 s
    "tests/app/test_process_session.py",                # 43 s fixture and its tests
    "tests/geometry/test_registration_passes.py",       # 42 s the pose graph, a pass that fits nowhere
    "tests/gui/test_gui_session.py",                    # 37 s
    "tests/app/test_register_command.py",               # 36 s
    "tests/gui/test_gui_materials_on_mesh.py",          # 35 s
    "tests/cloth/test_cloth_fit.py",                    # 34 s
    "tests/app/test_full_disk.py",                      # 33 s
    "tests/gui/test_gui_whole_session.py",              # 33 s
    "tests/geometry/test_photo_consistency.py",         # 32 s
    "tests/geometry/test_registration_turned.py",       # 29 s
    "tests/app/test_capture.py",                        # 28 s
    "tests/app/report/test_readable_report.py",         # 27 s fixture and its tests
)


def pytest_configure(config):
    """With several xdist workers on as many cores, each worker's OpenMP (Open3D) runs one thread.

    Two workers each starting a thread per core oversubscribe the cores; the spinning threads cost CPU
    time (the hawk's three-pass pose graph: 46 s of CPU with two threads, 41 s with one).  The variable is
    set in the controller before the workers start, so they inherit it before Open3D is loaded.
    """
    workers = getattr(config.option, "numprocesses", None)
    if isinstance(workers, int) and workers > 1:
        os.environ.setdefault("OMP_NUM_THREADS", "1")


def pytest_collection_modifyitems(session, config, items):
    """Move the files of :data:`SLOWEST_FILES` to the front, in that order; every file keeps its own order."""
    rank = {name: k for k, name in enumerate(SLOWEST_FILES)}

    def key(item) -> int:
        path = item.nodeid.split("::")[0]
        return rank.get(path, len(rank))

    items[:] = sorted(items, key=key)      # stable: the rest keep pytest's order
