"""Shared helpers of the benchmark scripts: data locations, machine description, timing."""

from __future__ import annotations

import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("PHYSMOCAP_SHARED", REPO.parent / "shared"))
VIDEOS = SHARED / "data" / "videos"
MOCAP = SHARED / "data" / "mocap"
RESULTS = REPO / "benchmarks" / "results"



def machine_description() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def git_revision() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=REPO).stdout.strip()
    except OSError:
        return "unknown"


def median_time(fn, repeats: int = 3) -> tuple[float, object]:
    """Median wall time of `repeats` calls, and the last call's result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times), result
