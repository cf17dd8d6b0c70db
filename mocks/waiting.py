"""Polling for a condition that a simulator thread makes true, with a deadline.

Tests of the device emulators wait on conditions rather than sleeping a fixed
time, so they stay fast on an idle machine and correct on a loaded one.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["wait_until"]


def wait_until(predicate: Callable[[], object], timeout: float = 5.0, poll_s: float = 0.005) -> bool:
    """Poll ``predicate`` until it is true or ``timeout`` seconds pass; its last value as a bool.

    Examples
    --------
    >>> wait_until(lambda: True)
    True
    >>> wait_until(lambda: False, timeout=0.01)
    False
    """
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(poll_s)
    return bool(predicate())
