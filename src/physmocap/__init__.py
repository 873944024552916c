"""physmocap: physics-based monocular 3D human motion capture.

    import physmocap
    result = physmocap.capture("video.mp4", physics="trajopt")   # a Result; the run folder is runs/video
    result.joint("left_ankle")                                   # (T, 3) metres, Z up, floor z = 0
    physmocap.export(result, to="glb")

See physmocap.api for the arguments and docs/architecture.md for how a capture flows through the stages.
"""

import os
import sys

# The hot loops solve many small systems; BLAS threads only contend for the cores (8 ms instead of 0.1 ms per
# 80x80 triangular solve when the detector keeps the other core busy), and they round differently, so a program
# that loaded numpy first got other results than the command line (6 mm of joint position on the demo clip).
# The variables act only before numpy loads; after it, threadpoolctl sets the loaded BLAS. A variable the user set
# wins in both cases.
_BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
if "numpy" in sys.modules and not any(_var in os.environ for _var in _BLAS_THREAD_VARIABLES):
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
for _var in _BLAS_THREAD_VARIABLES:
    os.environ.setdefault(_var, "1")

# The submodule physmocap.export is loaded first: loading it later would rebind the name `export` to the module,
# hiding the API function.
from . import export as _export_module  # noqa: E402, F401 - after the BLAS threads are set
from .api import Result, capture, export, load_result  # noqa: E402

__version__ = "0.1.0"
__all__ = ["Result", "capture", "export", "load_result", "__version__"]
