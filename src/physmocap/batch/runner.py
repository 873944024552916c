"""A batch from start to end: inputs -> tasks (finished runs skipped, unreadable inputs recorded), the engine
running the rest, the tables and the progress display updated as runs finish, Ctrl-C stopping it cleanly."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import TextIO

from ..config import Settings
from ..cores import usable_cores
from ..errors import InputError
from .inputs import BatchInput
from .progress import BatchProgress
from .table import write_tables
from .task import BatchTask, batch_key, empty_record, failed_record, finished_record

# Peak resident memory of one worker capturing a clip (overlay on), measured by benchmarks/bench_batch.py:
# workers beyond memory / this would swap instead of run.
WORKER_MEMORY_BYTES = 1.0e9
TABLE_INTERVAL_SECONDS = 2.0  # batch.csv and index.html are rewritten at most this often while runs finish


def default_workers(tasks: int | None = None) -> int:
    """Processes to run at once on this machine: one per core this process may use (detection and fit are
    CPU-bound and each worker is held to one thread), fewer if memory would not hold them, never more than
    `tasks`."""
    cores = usable_cores()
    try:
        memory = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        cores = min(cores, int(memory // WORKER_MEMORY_BYTES))
    except (ValueError, OSError, AttributeError):
        pass
    return max(1, min(cores, tasks if tasks else cores))


def run_batch(inputs: list[BatchInput], out_dir: str | os.PathLike, settings: Settings, *, overlay: bool = True,
              workers: int | None = None, ray: bool = False, ray_address: str | None = None,
              progress_stream: TextIO | None = None, progress_interval: float = 5.0) -> list[dict]:
    """Run every input into OUT/<name>/ like `physmocap capture` and return one record per input (the rows of
    OUT/batch.csv, in input order). `ray`: on Ray, a local instance of `workers` CPUs, or the cluster at
    `ray_address` ("auto", "host:port"). KeyboardInterrupt stops the workers and leaves the tables up to date."""
    out_dir = Path(out_dir).absolute()
    out_dir.mkdir(parents=True, exist_ok=True)
    records, frames, tasks = _prepare(inputs, out_dir, settings, overlay)
    progress = BatchProgress(len(inputs), sum(frames), progress_stream, progress_interval)
    for index, record in enumerate(records):
        if record["status"] != "pending":
            progress.finished(record, frames[index], earlier=record["status"] == "done")
    write_tables(out_dir, records)
    if not tasks:
        progress.close()
        return records
    workers = workers or default_workers(len(tasks))
    started = time.perf_counter()
    engine = _engine(ray, ray_address, workers)
    if ray:
        progress.note(f"Ray with {engine.cluster_cpus()} CPUs ready after {time.perf_counter() - started:.1f} s")
    order = {record["name"]: index for index, record in enumerate(records)}
    written = time.monotonic()
    try:
        for task in sorted(tasks, key=lambda t: -frames[order[t.name]]):  # longest first: the shortest tail
            engine.submit(task)
        while engine.unfinished():
            for task, record in engine.wait(timeout=1.0):
                index = order[task.name]
                records[index] = record
                progress.finished(record, record["frames"] or frames[index])
            if time.monotonic() - written >= TABLE_INTERVAL_SECONDS:
                write_tables(out_dir, records)
                written = time.monotonic()
            progress.tick()
    except KeyboardInterrupt:
        engine.stop()
        _collect_finished_on_disk(tasks, records, order)
        raise
    else:
        engine.close()
    finally:
        write_tables(out_dir, records)
        progress.close()
    return records


def _collect_finished_on_disk(tasks: list[BatchTask], records: list[dict], order: dict[str, int]) -> None:
    """Runs that wrote their batch.json before Ctrl-C but whose result had not reached this process yet: the
    table says done, as the next batch will, instead of pending."""
    for task in tasks:
        index = order[task.name]
        if records[index]["status"] == "pending" and (record := finished_record(task)) is not None:
            records[index] = dict(record, resumed=0)


def _prepare(inputs: list[BatchInput], out_dir: Path, settings: Settings, overlay: bool):
    """Records (finished by an earlier batch, failed on reading, or pending), frame counts and the tasks to run."""
    from ..io.video import probe_video
    from ..motion import Observations

    records, frames, tasks = [], [], []
    for item in inputs:
        try:
            key = batch_key(item.path, item.kind, settings, overlay)
        except OSError:
            key = ""  # missing or unreadable: the probe below says which, in the words `capture` uses
        task = BatchTask(item.name, str(item.path), item.kind, str(out_dir / item.name), settings,
                         overlay and item.kind == "video", key)
        record = finished_record(task) if key else None
        if record is not None:
            records.append(record)
            frames.append(int(record["frames"] or 0))
            continue
        try:
            count = (probe_video(item.path).frame_count if item.kind == "video"
                     else Observations.load(item.path).num_frames)
        except InputError as exc:
            records.append(failed_record(task, 2, str(exc), 0.0))
            frames.append(0)
            continue
        records.append(empty_record(item.name, str(item.path), item.kind, "pending"))
        frames.append(count)
        tasks.append(task)
    return records, frames, tasks


def _engine(ray: bool, address: str | None, workers: int):
    from .engines import ProcessPoolEngine, RayEngine

    if not ray:
        return ProcessPoolEngine(workers)
    try:
        import ray as _  # noqa: F401
    except ImportError:
        raise InputError("--ray needs Ray: pip install 'physmocap[ray]' (or pip install ray).") from None
    try:
        return RayEngine(address, workers)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = f"the Ray cluster at {address}" if address else "a local Ray"
        reason = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise InputError(f"--ray: could not start or reach {where} ({reason}).") from None
