"""The stall accounting of bench.responsiveness: closed-form cases and the kernel's per-thread counters."""

from __future__ import annotations

import os
import threading

import pytest

pytest.importorskip("PySide6.QtCore", reason="the GUI tests need PySide6 (pip install 'kogei[gui]')")

from bench.responsiveness import own_stalls_ms, run_queue_waits_ns, stalls_ms, steal_ns


def test_own_stall_is_the_stall_less_the_excused_time_never_negative():
    stalls = stalls_ms([0.0, 0.010, 0.130, 0.240], 10)        # 0, 110, 100 ms
    assert stalls == pytest.approx([0.0, 110.0, 100.0])
    assert own_stalls_ms(stalls, [5.0, 30.0, 250.0]) == pytest.approx([0.0, 80.0, 0.0])


def test_mismatched_lengths_are_refused_readably():
    with pytest.raises(ValueError, match="one value per firing"):
        own_stalls_ms([1.0, 2.0], [0.0])


@pytest.mark.skipif(not os.path.exists(f"/proc/self/task/{threading.get_native_id()}/schedstat"),
                    reason="no per-thread schedstat (not Linux)")
def test_run_queue_waits_name_every_live_thread_and_never_decrease():
    ready, stop = threading.Event(), threading.Event()
    t = threading.Thread(target=lambda: (ready.set(), stop.wait(5)))
    t.start()
    ready.wait(5)
    try:
        first = run_queue_waits_ns()
        assert {threading.get_native_id(), t.native_id} <= first.keys()
        sum(range(200_000))
        second = run_queue_waits_ns()
        assert all(second[k] >= first[k] >= 0 for k in first.keys() & second.keys())
        assert steal_ns() >= 0
    finally:
        stop.set()
        t.join()
