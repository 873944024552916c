"""Synthetic recovery: motion capture seen by a random camera, noisy detector-like observations, full fit.

The detector's errors follow MEDIAPIPE_NOISE, measured on the shared real videos (physmocap.contacts.noise).
Measures how well the kinematic fit recovers the truth, with the true intrinsics (the observations carry
camera_K) and the person's true height (the standing height of the true skeleton under the body model's own
definition, so that the benchmark measures the fit and not how a height is taken). Errors are compared in the
camera frame, which makes them independent of the world frame each side chose.

    .venv/bin/python benchmarks/bench_synthetic.py [--quick] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time

import numpy as np

from common import EVAL_JOINTS, MOCAP, RESULTS
from physmocap.body import kinematics as kin
from physmocap.body.model import JOINT_NAMES, SkeletonLengths, TEMPLATE_RATIOS
from physmocap.config import Settings
from physmocap.kinematics.calibration import measure_lengths
from physmocap.kinematics.stage import fit_motion
from physmocap.mocap.bvh_reader import load_mocap
from physmocap.contacts.noise import MEDIAPIPE_NOISE
from physmocap.mocap.synthetic import NoiseModel, make_observations, random_camera, resample

# Held-out style set: both skeletons, several subjects, walking, dancing, jumping, sport.
CLIPS = (
    "cmu_raw_cgspeed/02_01.bvh", "cmu_raw_cgspeed/131_03.bvh", "cmu_raw_cgspeed/05_06.bvh",
    "cmu_iclone_cc3_retarget/007_03.bvh", "cmu_iclone_cc3_retarget/005_03.bvh",
    "cmu_iclone_cc3_retarget/002_04.bvh", "cmu_iclone_cc3_retarget/006_06.bvh",
    "cmu_iclone_cc3_retarget/005_11.bvh",
)
FPS = 30.0
SECONDS = 8.0


def model_height(landmarks_world: np.ndarray) -> float:
    """Standing height of the true skeleton as the body model defines it (template share for the head top)."""
    hips = 0.5 * (landmarks_world[:, 23] + landmarks_world[:, 24])
    lengths = measure_lengths(landmarks_world - hips[:, None])
    partial = SkeletonLengths(**lengths, head_top=0.0).standing_height
    return partial / (1.0 - TEMPLATE_RATIOS["head_top"])


def first_seconds(clip, seconds):
    n = int(seconds * clip.fps)
    return dataclasses.replace(clip, positions=clip.positions[:n], head_rotation=clip.head_rotation[:n],
                               hand_rotations=clip.hand_rotations[:n])


def evaluate_case(name: str, seed: int, online: bool, noise: NoiseModel, height_error: float = 0.0) -> dict:
    clip = first_seconds(resample(load_mocap(MOCAP / name), FPS), SECONDS)
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, noise)
    height = model_height(truth["landmarks_world"]) * (1.0 + height_error)
    settings = Settings(online=online).replace("body", height=height)
    start = time.perf_counter()
    motion = fit_motion(obs, settings)
    seconds = time.perf_counter() - start
    pred = motion.camera.to_camera(kin.forward_kinematics(motion.body, motion.qpos).points[:, :len(JOINT_NAMES)])
    true = truth["joints_world"] @ truth["camera_R"].T + truth["camera_t"]
    ev = [JOINT_NAMES.index(j) for j in EVAL_JOINTS]
    hips = [JOINT_NAMES.index("left_hip"), JOINT_NAMES.index("right_hip")]
    root_p, root_t = pred[:, hips].mean(1), true[:, hips].mean(1)
    rel = np.linalg.norm((pred[:, ev] - root_p[:, None]) - (true[:, ev] - root_t[:, None]), axis=-1)
    return dict(clip=name.split("/")[-1], seed=seed, online=online, frames=len(pred),
                root_relative_mm=float(rel.mean() * 1000), global_root_mm=float(
                    np.linalg.norm(root_p - root_t, axis=-1).mean() * 1000),
                depth_m=float(np.median(root_t[:, 2])), fit_ms_per_frame=seconds / len(pred) * 1000)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="three clips, one seed")
    parser.add_argument("--json", default=str(RESULTS / "synthetic_kinematics.json"))
    args = parser.parse_args(argv)
    clips = CLIPS[:3] if args.quick else CLIPS
    seeds = (0,) if args.quick else (0, 1)
    rows = []
    for online in (False, True):
        for name in clips:
            for seed in seeds:
                row = evaluate_case(name, seed, online, MEDIAPIPE_NOISE)
                rows.append(row)
                print(f"{'online ' if online else 'offline'} {row['clip']:>10} seed {seed}: root-relative "
                      f"{row['root_relative_mm']:5.1f} mm, global root {row['global_root_mm']:6.1f} mm "
                      f"at {row['depth_m']:.1f} m, fit {row['fit_ms_per_frame']:.1f} ms/frame", flush=True)
    sensitivity = [evaluate_case(CLIPS[3], 0, False, MEDIAPIPE_NOISE, err) for err in (-0.03, 0.03)]
    summary = {}
    for mode in ("offline", "online"):
        sel = [r for r in rows if r["online"] == (mode == "online")]
        summary[mode] = {k: float(np.mean([r[k] for r in sel])) for k in
                         ("root_relative_mm", "global_root_mm", "fit_ms_per_frame")}
    summary["height_error_3pct_global_root_mm"] = [r["global_root_mm"] for r in sensitivity]
    out = dict(rows=rows, summary=summary, fps=FPS, seconds=SECONDS, noise=dataclasses.asdict(MEDIAPIPE_NOISE))
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(args.json, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(summary, indent=2))
    return out


if __name__ == "__main__":
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    main()
