"""PhysCap physics on the shared real videos, measured without ground truth by the run report's metrics.

For each video of bench_kinematics.py (its cached detections), `physmocap capture --physics physcap` is run
from the observations, online (the causal fit, causal contacts, the floor refined as frames arrive: the paper's
setting) and offline (the whole-clip fit, centred contacts); the report's metrics (`physmocap evaluate`) of the
kinematic input and of the physics result are kept side by side: jitter, floor contact errors against the
run's floor and its detected contacts, implied and solved forces, residual root force, balance, reprojection.

    .venv/bin/python benchmarks/bench_physics_real.py

Writes benchmarks/results/physics_real.json.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from bench_kinematics import CACHE, VIDEO_NAMES, detections  # noqa: E402
from common import RESULTS, VIDEOS  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.pipeline import run_capture  # noqa: E402
from physmocap.result import load_result  # noqa: E402
from physmocap.viz.report import run_metrics  # noqa: E402


def measure(observations: Path, online: bool, work: Path) -> dict:
    """Report metrics of the kinematic input and of the PhysCap result of one run."""
    settings = Settings(online=online).replace("physics", method="physcap")
    summary = run_capture(work, settings, observations=observations, overlay=False)
    metrics = run_metrics(load_result(work / "result.npz"))
    return dict(kinematic={m.key: m.kinematic for m in metrics if m.kinematic is not None},
                physcap={m.key: m.final for m in metrics if m.final is not None},
                physics_seconds=summary.stage_seconds.get("physics"), frames=summary.frames)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default=str(RESULTS / "physics_real.json"))
    args = parser.parse_args(argv)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in VIDEO_NAMES:
            video = VIDEOS / name
            detections(video)  # cached by bench_kinematics, or detected now
            observations = CACHE / f"{video.stem}.observations.npz"
            out[name] = {mode: measure(observations, mode == "online", Path(tmp) / f"{video.stem}_{mode}")
                         for mode in ("online", "offline")}
            print(json.dumps({name: out[name]}, indent=1), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
