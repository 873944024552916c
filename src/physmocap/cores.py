"""How many cores this process may keep busy: one rule for detection's two graphs, trajectory optimisation's
windows two at a time and the batch's worker count."""

from __future__ import annotations

import multiprocessing
import os

BATCH_WORKER_VARIABLE = "PHYSMOCAP_BATCH_WORKER"
"""Environment variable set to "1" in every batch worker (pool or Ray): the batch keeps each core busy with one
run already, so a run inside it does not start work on a second core."""


def usable_cores() -> int:
    """Cores this process may run on: its CPU affinity where the system reports one, else every core."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def may_use_two_cores() -> bool:
    """True where this process has at least two cores and is neither a worker of a multiprocessing pool nor a
    batch worker (`BATCH_WORKER_VARIABLE`)."""
    return (usable_cores() >= 2 and multiprocessing.parent_process() is None
            and os.environ.get(BATCH_WORKER_VARIABLE) != "1")
