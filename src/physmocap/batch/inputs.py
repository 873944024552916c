"""The command line's INPUTS -> one `BatchInput` per video or observations file, each with its own run folder name.

An input is a video file, an observations file (.npz, as `physmocap detect` writes), a folder (searched, with its
subfolders, for video files) or a text file (.txt, .list, .lst) listing such paths one a line (blank lines and
lines starting with # are skipped; relative paths are relative to the list's folder). A path that does not exist
stays an input and fails with its own sentence, so that one typo never stops a batch; a list file that cannot be
read stops it before it starts (the list is the command).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

VIDEO_SUFFIXES = frozenset({".mp4", ".mov", ".avi", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".flv",
                            ".ts", ".mts", ".3gp"})
OBSERVATIONS_SUFFIX = ".npz"
LIST_SUFFIXES = frozenset({".txt", ".list", ".lst"})


@dataclass(frozen=True)
class BatchInput:
    """One input of a batch: `path` (absolute), its `kind` ("video" or "observations") and `name`, the run folder
    inside the batch's output folder (unique within the batch)."""

    path: Path
    kind: str
    name: str


def expand_inputs(paths: list[Path], out_dir: Path) -> list[BatchInput]:
    """The batch inputs of the command line's INPUTS, in the order given (folders sorted by path), each file once.

    Files inside `out_dir` are never inputs (its run folders hold overlay.mp4 files). Raises InputError when a
    list file cannot be read or when nothing at all is found."""
    out_dir = out_dir.resolve()
    found: list[tuple[Path, str]] = []
    seen: set[Path] = set()

    def add(path: Path, kind: str) -> None:
        same = path.resolve()  # one file named twice (a link, a list and a folder) runs once
        if same not in seen:
            seen.add(same)
            found.append((path, kind))

    def visit(path: Path, lists: tuple[Path, ...]) -> None:
        path = Path(os.path.abspath(path.expanduser()))  # absolute, with .. folded: workers may start elsewhere
        if path.is_dir():
            for video in sorted(p for p in path.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file()):
                if not _hidden(video.relative_to(path)) and not video.resolve().is_relative_to(out_dir):
                    add(video, "video")
        elif path.suffix.lower() in LIST_SUFFIXES:
            if path.resolve() in lists:
                raise InputError(f"{path}: the list includes itself (through {lists[-1]}).")
            for line in _read_list(path):
                visit(path.parent / line, lists + (path.resolve(),))
        else:
            add(path, "observations" if path.suffix.lower() == OBSERVATIONS_SUFFIX else "video")

    for path in paths:
        visit(Path(path), ())
    if not found:
        raise InputError("no video or observations file found in " + ", ".join(str(p) for p in paths) + ".")
    names = unique_names([path for path, _ in found])
    return [BatchInput(path, kind, name) for (path, kind), name in zip(found, names, strict=True)]


def _hidden(relative: Path) -> bool:
    return any(part.startswith(".") for part in relative.parts)


def _read_list(path: Path) -> list[str]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such list file.") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable text file listing inputs ({exc}).") from None
    lines = [line.strip() for line in text.splitlines() if line.strip() and not line.strip().startswith("#")]
    if any("\0" in line for line in lines):
        raise InputError(f"{path}: a line holds a NUL character, which no path can; not a list of inputs.")
    return lines


def unique_names(paths: list[Path]) -> list[str]:
    """Run folder names: each file's stem made safe for a folder name; a name already taken gets -2, -3, ...
    in input order, so that the same command always gives the same names (and a re-run finds its runs)."""
    names: list[str] = []
    taken: set[str] = set()
    for path in paths:
        base = re.sub(r"[^A-Za-z0-9._-]+", "_", path.stem).strip("._") or "input"
        name, n = base, 1
        while name.lower() in taken:  # case-insensitive: two names must not share a folder on macOS or Windows
            n += 1
            name = f"{base}-{n}"
        taken.add(name.lower())
        names.append(name)
    return names
