"""Host-side overhead per turntable step against the instant firmware emulator.

Benchmark: with ``time_scale=0`` the emulated table moves
instantly, so the wall time of :meth:`drivers.turntable.Turntable.step`
(motor and laser re-assertion plus the move: four command round trips over a
real pty) is the host's own cost.  Target: <= 5 ms per step.

:func:`measure_capture` times a whole capture pass (``app.capture.runner``) against
the simulated station: per profile step the turntable step, the profile
(trigger, frame, CRC), the atomic file write and the journal append, with
the station's own ray casting measured separately and subtracted.

Run ``python -m bench.device_bench [--steps N]``; prints
``{"overhead_ms_per_step": <median>, ..., "capture": {...}}``.
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

__all__ = ["measure_step_overhead", "measure_capture", "main"]


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


def measure_capture(steps: int = 400) -> dict[str, float]:
    """Time one scan pass of ``steps`` profiles (camera off) through :func:`app.capture.runner.run_capture`.

    Returns
    -------
    dict
        ``step_ms`` (median wall time per profile step), ``profiles_per_s``
        (whole pass), ``device_ms`` (median time of the station's own
        profile computation: ray casting the world, which real hardware does
        in the sensor), ``host_ms`` (``step_ms - device_ms``), ``store_ms``
        (median cost of writing one profile into the session: atomic file +
        journal record), ``points`` per profile.
    """
    import numpy as np

    from app.capture.devices import build_devices
    from app.capture.runner import CaptureHooks, CapturePlan, run_capture
    from app.session import Session
    from mocks.station import SimulatedStation
    from mocks.world import World

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        with SimulatedStation(World.hawk(20_000), root=root / "station") as st:
            plan = CapturePlan("scan", steps=steps, passes=1, camera=False)
            config = {"turntable": {"port": str(st.turntable_path)}, "profiler": {"port": str(st.profiler_path)}}
            session = Session.create(root / "session", plan=plan.to_dict())
            stamps: list[float] = []
            hooks = CaptureHooks(before_pass=lambda p, n: st.place(p),
                                 progress=lambda p: stamps.append(time.perf_counter()))
            t0 = time.perf_counter()
            run_capture(session, plan, build_devices(config, session.root), hooks)
            total = time.perf_counter() - t0
            device = []
            for _ in range(50):
                t = time.perf_counter()
                st._source()
                device.append(time.perf_counter() - t)
            store = []
            x = np.full(st.n_points, 1.0, np.float32)
            for i in range(100):
                t = time.perf_counter()
                info = session.write_arrays(f"bench/{i:04d}.npz", x_mm=x, z_mm=x, angle_deg=np.float64(i))
                session.add_capture(f"bench/{i}", file=info.path, sha256=info.sha256, bytes=info.bytes,
                                    state={"table_deg": float(i)})
                store.append(time.perf_counter() - t)
            session.close()
            points = st.n_points
    step = statistics.median(np.diff(stamps)) * 1e3
    dev = statistics.median(device) * 1e3
    return {"steps": steps, "points": points, "step_ms": step, "profiles_per_s": steps / total,
            "device_ms": dev, "host_ms": step - dev, "store_ms": statistics.median(store) * 1e3}


def main() -> None:
    """Print the measurement as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400)
    args = ap.parse_args()
    result = measure_step_overhead(args.steps)
    result["capture"] = measure_capture(args.steps)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
