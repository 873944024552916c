"""Speed of the PhysCap stage alone: frames per second on one core (4 integration steps per frame, the paper's
n), on a real kinematic motion (the shipped demo clip, fitted online) with its predicted contacts. Median over
several runs; the stage is single-threaded (BLAS pinned to one thread by `import physmocap`). Reported twice: by
wall clock, and by the process's CPU time, which on a shared machine is the one-core figure (time spent waiting
for a core while other jobs run is not counted).

    .venv/bin/python benchmarks/bench_physics.py [--repeats 30] [--json OUT.json]
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import REPO, RESULTS  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.detect.mediapipe_pose import detect_video  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402

DEMO = REPO / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4"


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=30)  # runs of 0.1-0.2 s: many, for a stable median
    parser.add_argument("--json", default=str(RESULTS / "physics_speed.json"))
    args = parser.parse_args(argv)
    obs = detect_video(DEMO)
    settings = Settings(online=True)
    motion = fit_motion(obs, settings)
    contacts, stationary, _ = predict_contacts(obs, "causal")
    runs, cpu_seconds = [], []
    for _ in range(args.repeats):
        start = time.process_time()
        runs.append(run_physcap(motion.body, motion.qpos, obs.fps, contacts, stationary, settings.physics,
                                refine_floor=True))  # as online capture runs it
        cpu_seconds.append(time.process_time() - start)
    seconds = statistics.median(r.seconds for r in runs)
    cpu = statistics.median(cpu_seconds)
    out = dict(frames=obs.num_frames, iterations_per_frame=settings.physics.iterations,
               frames_per_second=obs.num_frames / seconds, ms_per_frame=1000 * seconds / obs.num_frames,
               cpu_frames_per_second=obs.num_frames / cpu, cpu_ms_per_frame=1000 * cpu / obs.num_frames,
               load_average=os.getloadavg()[0],
               contact_frames=int(contacts.any(axis=1).sum()),
               qp_failures=int(np.sum([r.qp_failures.sum() for r in runs[:1]])))
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
