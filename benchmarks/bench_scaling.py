"""Speed and memory per stage, and the offline stages' time against clip length.

1. Per stage on the shipped demo clip (96 frames, 640x360), each stage in a fresh process so that its peak
   resident memory is its own: detection, kinematic fit (offline and online), contacts (centred and causal),
   PhysCap physics, outputs (result, BVH, GLB, OpenSim, overlay, viewer, report). ms/frame and peak RSS MB;
   frames per second end to end (capture with physics, all outputs).
2. Offline kinematic fit and physics against clip length: the first 2, 5, 10 and 20 s of CMU 001_01 (forward
   jumps, 23 s) at 30 fps through synthetic observations; seconds and peak RSS per length.

    .venv/bin/python benchmarks/bench_scaling.py [--json OUT.json]
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from common import MOCAP, REPO, RESULTS  # noqa: E402

DEMO = REPO / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4"

# Each stage script prints one JSON line: {"seconds": ..., "frames": ...}; the parent adds the peak memory.
STAGE_SCRIPT = r"""
import json, resource, sys, time, numpy as np
import physmocap
from pathlib import Path
from physmocap.config import Settings
from physmocap.motion import Observations
stage, work = sys.argv[1], Path(sys.argv[2])
obs_path = work / "observations.npz"
start = time.perf_counter()
if stage == "detect":
    from physmocap.detect.mediapipe_pose import detect_video
    obs = detect_video(sys.argv[3]); obs.save(obs_path); frames = obs.num_frames
else:
    obs = Observations.load(obs_path); frames = obs.num_frames
    start = time.perf_counter()
    if stage.startswith("fit"):
        from physmocap.kinematics.stage import fit_motion
        fit_motion(obs, Settings(online=stage == "fit_online"))
    elif stage.startswith("contacts"):
        from physmocap.contacts.predict import predict_contacts
        predict_contacts(obs, "causal" if stage == "contacts_causal" else "centred")
    elif stage in ("physics", "outputs"):
        from physmocap.kinematics.stage import fit_motion
        from physmocap.contacts.predict import predict_contacts
        from physmocap.dynamics.stage import run_physcap
        settings = Settings(online=True).replace("physics", method="physcap")
        motion = fit_motion(obs, settings)
        contacts, stationary, _ = predict_contacts(obs, "causal")
        start = time.perf_counter()
        physics = run_physcap(motion.body, motion.qpos, obs.fps, contacts, stationary, settings.physics)
        if stage == "outputs":
            from physmocap.pipeline import write_outputs
            start = time.perf_counter()
            write_outputs(work / "run", "demo", obs, motion, contacts, stationary, physics, settings, {}, [],
                          Path(sys.argv[3]))
seconds = time.perf_counter() - start
print(json.dumps(dict(seconds=seconds, frames=frames,
                      peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))
"""

LENGTH_SCRIPT = r"""
import physmocap  # first: one BLAS thread
import json, resource, sys, time, dataclasses, numpy as np
from physmocap.config import Settings
from physmocap.contacts.noise import MEDIAPIPE_NOISE
from physmocap.contacts.predict import predict_contacts
from physmocap.dynamics.stage import run_physcap
from physmocap.kinematics.stage import fit_motion
from physmocap.mocap.bvh_reader import load_mocap
from physmocap.mocap.synthetic import make_observations, random_camera, resample
path, seconds_of_clip = sys.argv[1], float(sys.argv[2])
clip = resample(load_mocap(path), 30.0)
n = int(seconds_of_clip * 30)
clip = dataclasses.replace(clip, positions=clip.positions[:n], head_rotation=clip.head_rotation[:n],
                           hand_rotations=clip.hand_rotations[:n])
rng = np.random.default_rng(0)
K, R, t = random_camera(clip, rng)
obs, _ = make_observations(clip, K, R, t, rng, MEDIAPIPE_NOISE)
start = time.perf_counter()
motion = fit_motion(obs, Settings())
fit = time.perf_counter() - start
contacts, stationary, _ = predict_contacts(obs, "centred")
start = time.perf_counter()
run_physcap(motion.body, motion.qpos, obs.fps, contacts, stationary, Settings().physics)
physics = time.perf_counter() - start
print(json.dumps(dict(frames=n, fit_seconds=fit, physics_seconds=physics,
                      peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))
"""


def _run(script: str, *args: str) -> dict:
    out = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", default=str(RESULTS / "scaling.json"))
    args = parser.parse_args(argv)
    stages = {}
    with tempfile.TemporaryDirectory() as work:
        for stage in ("detect", "fit_offline", "fit_online", "contacts_centred", "contacts_causal", "physics",
                      "outputs"):
            row = _run(STAGE_SCRIPT, stage, work, str(DEMO))
            row["ms_per_frame"] = 1000 * row["seconds"] / row["frames"]
            stages[stage] = row
            print(stage, json.dumps(row), flush=True)
    end_to_end = sum(stages[s]["ms_per_frame"] for s in ("detect", "fit_online", "contacts_causal", "physics",
                                                         "outputs"))
    lengths = {}
    for seconds in (2, 5, 10, 20):
        row = _run(LENGTH_SCRIPT, str(MOCAP / "cmu_iclone_cc3_retarget" / "001_01.bvh"), str(seconds))
        lengths[seconds] = row
        print(seconds, "s:", json.dumps(row), flush=True)
    out = dict(stages=stages, end_to_end_frames_per_second=1000 / end_to_end, lengths=lengths)
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
