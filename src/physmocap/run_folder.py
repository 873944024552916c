"""The run folder as a unit: one run at a time (a lock), no half-written files left from an interrupted run, and
no output of an earlier run left beside the outputs of this one."""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import logging
import os
from collections.abc import Iterator
from pathlib import Path

from .errors import OutputLocationError

log = logging.getLogger("physmocap")

LOCK_FILE = ".physmocap.lock"
# Outputs a run writes only on request (others are rewritten by every run); listed so that a run which does not
# write them removes an earlier run's copy even when that run's summary.json is gone.
OPTIONAL_OUTPUTS = ("overlay.mp4",)

_held: dict[Path, list[int]] = {}  # folders this process has locked: [file descriptor, nesting depth]


@contextlib.contextmanager
def locked_run_folder(folder: str | os.PathLike) -> Iterator[Path]:
    """Create `folder` if needed and hold its lock for the block; a second run into the same folder, from this
    machine or another process, is refused with OutputLocationError. Nested use in one process is allowed.
    On entry, half-written files that an interrupted run left (io.atomic's `.*.partial.*`) are removed."""
    folder = Path(folder)
    _make_folder(folder)
    key = folder.resolve()
    if key in _held:
        _held[key][1] += 1
        try:
            yield folder
        finally:
            _held[key][1] -= 1
        return
    fd = _acquire(folder)
    _held[key] = [fd, 1]
    try:
        remove_partial_files(folder)
        yield folder
    finally:
        del _held[key]
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


def _make_folder(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputLocationError(f"{folder}: is a file, not a folder; choose another output folder.") from None
    except OSError as exc:
        raise OutputLocationError(f"{folder}: the output folder cannot be created ({exc.strerror}).") from None


def _acquire(folder: Path) -> int:
    path = folder / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise OutputLocationError(f"{folder}: cannot write into the output folder ({exc.strerror}).") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
        os.close(fd)
        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
            raise OutputLocationError(f"{folder}: the output folder cannot be locked ({exc.strerror}).") from None
        raise OutputLocationError(f"{folder}: another physmocap run (process {holder}) is writing into this folder; "
                                  "wait for it to finish or choose another output folder.") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    return fd


def remove_partial_files(folder: Path) -> list[Path]:
    """Remove the half-written files (`.*.partial.*`, io.atomic) in `folder` and `folder/cache`; returns them."""
    partial = [p for d in (folder, folder / "cache") for p in d.glob(".*.partial*") if p.is_file()]
    for path in partial:
        path.unlink(missing_ok=True)
    if partial:
        log.warning("removed %d half-written file(s) an interrupted run left in %s", len(partial), folder)
    return partial


def previous_outputs(folder: Path) -> set[Path]:
    """The outputs an earlier run listed in summary.json, with OPTIONAL_OUTPUTS, that exist in `folder`."""
    listed: list[str] = []
    try:
        listed = list(json.loads((folder / "summary.json").read_text()).get("files", {}).values())
    except (OSError, ValueError, AttributeError):
        pass
    candidates = {Path(p) for p in listed} | {folder / name for name in OPTIONAL_OUTPUTS}
    inside = {p for p in candidates if p.resolve().parent == folder.resolve()}
    return {p for p in inside if p.is_file()}


def remove_stale_outputs(stale: set[Path], written: dict[str, str]) -> list[Path]:
    """Remove the files in `stale` that this run did not write (`written`: kind -> path); returns them."""
    kept = {Path(p).resolve() for p in written.values()}
    removed = sorted(p for p in stale if p.resolve() not in kept)
    for path in removed:
        path.unlink(missing_ok=True)
    return removed
