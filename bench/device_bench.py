"""Host-side overhead per turntable step against the instant firmware emulator.

Issue #3 benchmark: with ``time_scale=0`` the emulated table moves
instantly, so the wall time of :meth:`drivers.turntable.Turntable.step`
(motor and laser re-assertion plus the move: four command round trips over a
real pty) is the host's own cost.  Target: <= 5 ms per step.

Run ``python -m bench.device_bench [--steps N]``; prints
``{"overhead_ms_per_step": <median>, ...}``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from drivers.transport import SerialTransport
from drivers.turntable import Turntable
from mocks.horus_firmware import HorusFirmware

__all__ = ["measure_step_overhead", "main"]


def measure_step_overhead(steps: int = 200, wire_log: bool = True) -> dict[str, float]:
    """Median and 95th percentile wall time of ``Turntable.step`` (ms).

    Parameters
    ----------
    steps
        Number of steps (one full revolution at ``360/steps`` degrees each).
    wire_log
        Write the wire log to a temporary file, as a capture session does.

    Returns
    -------
    dict
        ``overhead_ms_per_step`` (median), ``p95_ms``, ``steps``.

    Examples
    --------
    >>> r = measure_step_overhead(steps=5)
    >>> r["steps"], r["overhead_ms_per_step"] > 0
    (5, True)
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    with tempfile.TemporaryDirectory() as tmp, HorusFirmware(Path(tmp) / "turntable", time_scale=0.0) as fw:
        log = Path(tmp) / "wire.log" if wire_log else None
        with Turntable(SerialTransport(fw.path, wire_log=log, label="turntable")) as tt:
            tt.step(0.0, lasers=[1])  # warm-up
            times = []
            for k in range(1, steps + 1):
                t0 = time.perf_counter()
                tt.step(k * 360.0 / steps)
                times.append(time.perf_counter() - t0)
    times.sort()
    return {
        "overhead_ms_per_step": 1e3 * statistics.median(times),
        "p95_ms": 1e3 * times[min(len(times) - 1, int(0.95 * len(times)))],
        "steps": steps,
    }


def main() -> None:
    """Print the measurement as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400)
    args = ap.parse_args()
    print(json.dumps(measure_step_overhead(args.steps)))


if __name__ == "__main__":
    main()
