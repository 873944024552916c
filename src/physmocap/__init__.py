"""physmocap: physics-based monocular 3D human motion capture."""

import os

# The hot loops solve many small systems; BLAS threads only contend for the cores (8 ms instead of 0.1 ms per
# 80x80 triangular solve when the detector keeps the other core busy). Must be set before numpy loads.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
