"""Errors a user can fix. The command line prints their message as one sentence and exits non-zero."""


class InputError(Exception):
    """Bad input from the user: a missing or unreadable file, bad settings, a video without a person.

    The message is one sentence that names the file (or setting) and the problem.
    """


class ReconstructionError(Exception):
    """The input was readable but nothing usable could be reconstructed from it."""


class OutputLocationError(InputError):
    """The output folder cannot be used: not writable, a file in its place, or another run writing into it.
    (A kind of InputError: the user fixes it by choosing another place or waiting.)"""
