"""One input's run, as a worker process runs it: `capture_one(task) -> record`, the row of batch.csv.

A run is finished when its folder holds summary.json and batch.json whose key matches the task's: a digest of the
input file (path, size, modification time), its kind, every setting and the overlay choice. batch.json is
removed before a run starts and written after run_capture returns, so a run interrupted at any point, or one
that ran with other settings, is never mistaken for a finished one; its cached stages are reused all the same.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import signal
import socket
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS before numpy loads

from ..config import Settings
from ..cores import BATCH_WORKER_VARIABLE
from ..errors import PhysmocapError
from ..io.finite import json_text

RUN_RECORD = "batch.json"
ERROR_FILE = "error.txt"

# One thread per worker for every library that would otherwise start one per core: N workers on N cores then
# keep each core busy with one worker instead of N threads each (see docs/decisions/batch-workers.md).
THREAD_ENV = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                     "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")}

# The figures of a run's metrics.json (final motion) that batch.csv shows: the physical plausibility at a glance.
PLAUSIBILITY = ("skate_percent", "penetration_percent", "floating_percent", "mean_acceleration",
                "residual_force_percent_bw", "com_over_support_percent")


@dataclass(frozen=True)
class BatchTask:
    """What a worker needs for one input: `source` (absolute path) of `kind` "video" or "observations", the run
    folder `run_dir` (absolute, on the file system every worker shares), the settings, whether to render the
    overlay, and the batch key that marks the finished run."""

    name: str
    source: str
    kind: str
    run_dir: str
    settings: Settings
    overlay: bool
    key: str


def batch_key(source: Path, kind: str, settings: Settings, overlay: bool) -> str:
    """The digest a finished run is recognised by (see the module docstring)."""
    stat = source.stat()
    parts = ["batch", 1, physmocap.__version__, str(source.resolve()), stat.st_size, stat.st_mtime_ns, kind,
             settings.as_dict(), overlay]
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def finished_record(task: BatchTask) -> dict | None:
    """The record of the finished run of `task` left by an earlier batch, or None when it must (re)run."""
    run_dir = Path(task.run_dir)
    try:
        stored = json.loads((run_dir / RUN_RECORD).read_text())
    except (OSError, ValueError):
        return None
    if stored.get("key") != task.key or not (run_dir / "summary.json").is_file():
        return None
    return dict(stored["record"], resumed=1)


def limit_threads() -> None:
    """One compute thread in this process: the environment for libraries not loaded yet, OpenCV's own pool, and
    no stage's work on a second core (`cores.BATCH_WORKER_VARIABLE`)."""
    import cv2

    os.environ.update(THREAD_ENV)
    os.environ[BATCH_WORKER_VARIABLE] = "1"
    cv2.setNumThreads(1)


class _Terminated(BaseException):
    """SIGTERM while a run is in progress: unwinds it so atomic writes delete their temporary files."""


@contextlib.contextmanager
def _terminate_unwinds() -> Iterator[None]:
    def handler(signum, frame):
        raise _Terminated()
    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def capture_one(task: BatchTask) -> dict:
    """Run one input into its run folder and return its record (see `record_fields`). User errors become a failed
    record with the sentence and the exit status `physmocap capture` would give (2 bad input, 3 nothing could be
    reconstructed, 1 anything else, whose traceback goes to the run folder's error.txt); they never raise."""
    from ..pipeline import run_capture

    limit_threads()
    started = time.perf_counter()
    run_dir = Path(task.run_dir)
    (run_dir / RUN_RECORD).unlink(missing_ok=True)
    (run_dir / ERROR_FILE).unlink(missing_ok=True)
    source = {task.kind: task.source}  # run_capture(video=...) or run_capture(observations=...)
    try:
        with _terminate_unwinds():
            summary = run_capture(run_dir, task.settings, **source, overlay=task.overlay, progress=None)
    except _Terminated:
        os._exit(128 + signal.SIGTERM)  # the run unwound; nothing of this worker is needed any more
    except PhysmocapError as exc:  # the exit status and line `physmocap capture` would give
        reason = str(exc) if exc.prefix == "error" else f"{exc.prefix}: {exc}"
        return failed_record(task, exc.exit_code, reason, time.perf_counter() - started)
    except Exception as exc:  # a bug must not stop the batch: recorded, with its traceback beside the run
        from ..io.atomic import write_text

        write_text(run_dir / ERROR_FILE, traceback.format_exc())
        return failed_record(task, 1, f"unexpected error ({type(exc).__name__}: {exc}); the traceback is in "
                                      f"{task.name}/{ERROR_FILE}.", time.perf_counter() - started)
    record = done_record(task, summary, time.perf_counter() - started)
    from ..io.atomic import write_text

    write_text(run_dir / RUN_RECORD, json_text({"key": task.key, "record": record}, indent=1))
    return record


def record_fields() -> list[str]:
    """The columns of batch.csv, in order."""
    return ["name", "input", "kind", "status", "exit_status", "reason", "frames", "valid_frames", "wall_seconds",
            "frames_per_second", "physics", "physics_fallback_frames", "reprojection_error_px",
            "reprojection_error_percent_of_height", *PLAUSIBILITY, "fps_by_jumps", "cached_stages", "resumed", "node",
            "worker_peak_memory_mb"]


def empty_record(name: str, source: str, kind: str, status: str) -> dict:
    return dict.fromkeys(record_fields(), "") | dict(name=name, input=source, kind=kind, status=status)


def failed_record(task: BatchTask, exit_status: int, reason: str, seconds: float) -> dict:
    return empty_record(task.name, task.source, task.kind, "failed") | dict(
        exit_status=exit_status, reason=reason, wall_seconds=round(seconds, 2), resumed=0, node=socket.gethostname())


def done_record(task: BatchTask, summary, seconds: float) -> dict:
    """The record of a finished run from its summary, metrics.json and result.npz."""
    import numpy as np

    run_dir = Path(task.run_dir)
    try:
        metrics = json.loads((run_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        metrics = {}
    with np.load(run_dir / "result.npz", allow_pickle=False) as result:
        fallback = int(np.sum(result["physics_fallback"]))
    figures = {name: _rounded(metrics.get(name, {}).get("final")) for name in PLAUSIBILITY}
    clock = summary.video_clock  # the rate the jumps say, where it is not the video's (kinematics.clock)
    figures["fps_by_jumps"] = _rounded(clock.get("consistent_fps")) if clock.get("warning") else ""
    return empty_record(task.name, task.source, task.kind, "done") | figures | dict(
        exit_status=0, frames=summary.frames, valid_frames=summary.valid_frames, wall_seconds=round(seconds, 2),
        frames_per_second=round(summary.frames / max(seconds, 1e-9), 2), physics=summary.physics,
        physics_fallback_frames=fallback, reprojection_error_px=_rounded(summary.median_reprojection_error_px),
        reprojection_error_percent_of_height=_rounded(summary.median_reprojection_error_percent_of_height),
        cached_stages=" ".join(summary.cached_stages), resumed=0, node=socket.gethostname(),
        worker_peak_memory_mb=_peak_memory_mb())


def _peak_memory_mb() -> int:
    """The worker's peak resident memory so far, MB (a worker runs inputs one after another): for sizing."""
    import resource

    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)


def _rounded(value) -> float | str:
    """4 significant digits; '' for a missing or non-finite figure (every number written is finite)."""
    if value is None or not isinstance(value, (int, float)) or value != value or abs(value) == float("inf"):
        return ""
    return float(f"{value:.4g}")
