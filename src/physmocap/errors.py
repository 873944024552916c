"""Errors a user can act on, one type per kind of problem. The command line prints the message as one sentence
naming the file (or setting) and the problem, and exits with the type's code:

    2    bad input or settings (InputError, SettingsError, CacheError)
    3    the input was readable but nothing could be reconstructed from it (ReconstructionError)
    4    the output location cannot be written (OutputLocationError)
    130  interrupted (Ctrl-C)
    1    a bug: anything else; the traceback goes to a crash log, the terminal gets one sentence with its path
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

EXIT_BAD_INPUT = 2
EXIT_NOTHING_RECONSTRUCTED = 3
EXIT_OUTPUT_NOT_WRITABLE = 4
EXIT_INTERRUPTED = 130
EXIT_BUG = 1
EXIT_CODES = (0, EXIT_BUG, EXIT_BAD_INPUT, EXIT_NOTHING_RECONSTRUCTED, EXIT_OUTPUT_NOT_WRITABLE, EXIT_INTERRUPTED)


class PhysmocapError(Exception):
    """A problem the user can fix; `exit_code` is what the command line exits with, `prefix` starts its line."""

    exit_code = EXIT_BAD_INPUT
    prefix = "error"


class InputError(PhysmocapError):
    """Bad input from the user: a missing or unreadable file, bad settings, a video without a person.

    The message is one sentence that names the file (or setting) and the problem.
    """


class SettingsError(InputError):
    """A setting out of range or one that makes no sense with this input (e.g. a floor above the person)."""


class CacheError(InputError):
    """A cache file of the run folder that is damaged and could not be rebuilt."""


class ReconstructionError(PhysmocapError):
    """The input was readable but nothing usable could be reconstructed from it."""

    exit_code = EXIT_NOTHING_RECONSTRUCTED
    prefix = "could not reconstruct"


class OutputLocationError(PhysmocapError):
    """The output file or folder cannot be created or written."""

    exit_code = EXIT_OUTPUT_NOT_WRITABLE


def check_output_folder(folder: str | os.PathLike) -> Path:
    """`folder` created if needed and shown to be writable by writing and removing a probe file in it; else an
    OutputLocationError naming it and the reason (a file in the way, no permission, a read-only file system)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputLocationError(f"{folder}: the output location is an existing file, not a folder "
                                  "(give a folder with -o).")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".physmocap-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise output_error(exc, folder, name_file=False) from None
    return folder


def output_error(exc: OSError, folder: str | os.PathLike, name_file: bool = True) -> OutputLocationError:
    """The sentence for an OSError met while creating or writing in the output location `folder`, naming the
    file it met (`name_file`) or the folder."""
    reasons = {errno.EACCES: "no permission to write there", errno.EPERM: "the folder may not be changed",
               errno.EROFS: "the file system is read-only", errno.ENOSPC: "the disk is full",
               errno.EDQUOT: "the disk quota is exceeded", errno.EEXIST: "a file is in the way",
               errno.ENOTDIR: "a file is in the way of a folder on that path",
               errno.ENOENT: "it cannot be created there"}
    fallback = exc.strerror or type(exc).__name__
    reason = fallback if exc.errno is None else reasons.get(exc.errno, fallback)
    where = exc.filename if name_file and exc.filename is not None else folder
    return OutputLocationError(f"{where}: cannot write the output there ({reason}).")
