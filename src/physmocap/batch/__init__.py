"""Many inputs in one command: `physmocap batch INPUTS... -o OUT`.

    inputs.py    INPUTS (videos, observations files, folders, lists) -> BatchInput with a unique run name
    task.py      one input's run in a worker -> its record (the row of batch.csv); the finished-run key
    engines.py   where runs execute: a local process pool (default) or Ray (local, or a cluster)
    progress.py  one progress display over the whole batch
    table.py     OUT/batch.csv and OUT/index.html
    runner.py    run_batch: all of it, with resume and a clean Ctrl-C
"""

from .inputs import BatchInput, expand_inputs
from .runner import default_workers, run_batch

__all__ = ["BatchInput", "expand_inputs", "default_workers", "run_batch"]
