"""Shared helpers of the benchmarks: timing medians, peak memory, machine description."""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

__all__ = ["median_time", "peak_rss_mb", "machine_description", "run_case_subprocess", "ROOT"]

ROOT = Path(__file__).resolve().parents[1]


def median_time(fn: Callable[[], object], repeats: int = 3) -> tuple[float, list[float]]:
    """Median wall time of ``repeats`` calls (seconds) and the individual times."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (VmHWM), in MB."""
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def machine_description() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        mem_gb = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        mem_gb = float("nan")
    import numpy

    try:
        import open3d

        o3d = open3d.__version__
    except Exception:  # pragma: no cover - reported, not fatal
        o3d = "unavailable"
    return (
        f"{cpu}, {os.cpu_count()} cores, {mem_gb:.0f} GiB RAM; {platform.system()} {platform.release()}; "
        f"Python {platform.python_version()}, NumPy {numpy.__version__}, Open3D {o3d}; "
        f"{_dt.date.today().isoformat()}"
    )


def run_case_subprocess(module: str, case: str, *args: str, timeout: float = 1800) -> dict:
    """Run ``python -m MODULE --case CASE ...`` in a fresh process and return its JSON output.

    A fresh process per case gives an honest peak memory figure for that case alone.
    """
    cmd = [sys.executable, "-m", module, "--case", case, *args]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark case {module} {case} failed:\n{proc.stderr[-4000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])
