"""Kinematic capture on the shared real videos: speed and fit quality.

Per video: detection ms/frame; fit ms/frame offline and online (median of several runs on cached detections);
median reprojection error in pixels and in % of the person's height in pixels; bone-length constancy (std over
time of every bone, fitted vs the detector's own 3D); mean joint acceleration before and after fitting (in the
image, px/s^2, detections vs reprojected fit; and root-relative 3D, m/s^2, the detector's metric landmarks vs the
fit); and the live pipeline (detector and causal fit concurrently, as `capture --online` runs) frames per second
(frames fed as fast as it goes) and latency (frames arriving at the video's rate), on the video as given and on
a 640-pixel-wide copy; and the whole live pipeline with contacts and PhysCap physics (`physmocap live`) on the
640-pixel copy.

    .venv/bin/python benchmarks/bench_kinematics.py [--repeats 3] [--json OUT.json]
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import functools
import json
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import RESULTS, VIDEOS, median_time  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.detect.mediapipe_pose import detect_video  # noqa: E402
from physmocap.io.video import trim_video  # noqa: E402
from physmocap.kinematics.fit import MARKER_LANDMARKS, MARKERS  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.live import stream_capture  # noqa: E402
from physmocap.motion import Observations  # noqa: E402
from physmocap.pipeline import contacts_stage  # noqa: E402
from physmocap.result import build_result, person_height_pixels  # noqa: E402
from physmocap.viz.report import run_metrics  # noqa: E402

VIDEO_NAMES = ("hybrik_taiji.mp4", "sports2d_demo.mp4")
CACHE = Path(__file__).resolve().parents[1] / "runs" / "bench_kinematics"
# Bones between detector landmarks that are also body-model points.
BONES = (("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"), ("right_shoulder", "right_elbow"),
         ("right_elbow", "right_wrist"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
         ("right_hip", "right_knee"), ("right_knee", "right_ankle"), ("left_shoulder", "right_shoulder"),
         ("left_hip", "right_hip"))


def detections(video: Path) -> Observations:
    cached = CACHE / f"{video.stem}.observations.npz"
    if cached.is_file():
        return Observations.load(cached)
    obs = detect_video(video)
    obs.save(cached)
    return obs


def _flat(points_2d: np.ndarray) -> np.ndarray:
    """Image points (T, J, 2) as 3D points on the image plane, for the 3D metrics."""
    return np.concatenate([points_2d, np.zeros(points_2d.shape[:-1] + (1,))], axis=-1)


def quality(obs: Observations, motion) -> dict:
    body = motion.body
    valid = obs.valid
    marker_points = body.point_index([b for _, b in MARKERS])
    names = [b for _, b in MARKERS]
    pts = kin.forward_kinematics(body, motion.qpos).points[:, marker_points]
    error = motion.reprojection_error
    height_px = motion.camera.focal * body.height / np.maximum(motion.camera.to_camera(motion.qpos[:, :3])[:, 2],
                                                               1e-6)
    edges = [(names.index(a), names.index(b)) for a, b in BONES]
    detector_3d = obs.landmarks_3d[:, MARKER_LANDMARKS] * motion.calibration.landmark_scale
    fitted_rel = pts - pts[:, [names.index("left_hip"), names.index("right_hip")]].mean(1, keepdims=True)
    # longest run of valid frames, so that accelerations never span a gap
    runs = np.split(np.arange(len(valid)), np.flatnonzero(np.diff(valid.astype(int))) + 1)
    run = max((r for r in runs if valid[r[0]]), key=len)
    kp = obs.keypoints_2d[:, MARKER_LANDMARKS]
    confident = (kp[run, :, 2] > 0.5).all(axis=0)  # landmarks seen throughout the run
    reprojected = motion.camera.project(pts)
    return dict(
        reprojection_px=float(np.nanmedian(error)),
        reprojection_percent_height=float(np.nanmedian(100 * error / height_px)),
        bone_std_fitted_mm=float(1000 * metrics.bone_length_std(pts[valid], edges).max()),
        bone_std_detector_mm=float(1000 * metrics.bone_length_std(detector_3d[valid], edges).max()),
        acceleration_2d_detected=float(metrics.mean_acceleration(_flat(kp[run][:, confident, :2]), obs.fps)),
        acceleration_2d_fitted=float(metrics.mean_acceleration(_flat(reprojected[run][:, confident]), obs.fps)),
        acceleration_3d_detected=float(metrics.mean_acceleration(detector_3d[run], obs.fps)),
        acceleration_3d_fitted=float(metrics.mean_acceleration(fitted_rel[run], obs.fps)),
        valid_frames=int(valid.sum()), frames=int(len(valid)),
        person_height_px=float(np.median(person_height_pixels(motion)[valid])),
    )


def no_truth_metrics(obs: Observations, motion) -> dict:
    """The run report's metrics (no ground truth): floor contact errors against the estimated floor and the
    detected contacts (centred network), forces the motion implies, jitter, balance, reprojection."""
    contacts, stationary = contacts_stage(obs, Settings())
    result = build_result(obs, motion, {}, {}, contacts, stationary)
    return {m.key: m.final for m in run_metrics(result)}


def live(video: Path, repeats: int, physics: str = "none") -> dict:
    """Throughput with frames fed as fast as the pipeline takes them; latency with frames arriving at the
    video's own rate, as from a camera (fed faster, frames would wait in the queue and inflate it)."""
    settings = Settings(online=True).replace("physics", method=physics)
    runs = [stream_capture(str(video), settings) for _ in range(repeats)]
    paced = [stream_capture(str(video), settings, realtime=True) for _ in range(repeats)]
    return dict(fps=statistics.median(r.frames_per_second for r in runs),
                latency_median_ms=statistics.median(r.latency_median_ms for r in paced),
                latency_p95_ms=statistics.median(r.latency_p95_ms for r in paced),
                detect_ms=statistics.median(r.detect_ms_per_frame for r in runs),
                fit_ms=statistics.median(r.fit_ms_per_frame for r in runs),
                contacts_physics_ms=statistics.median(r.contacts_physics_ms_per_frame for r in runs),
                warmup_frames=runs[0].warmup_frames)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", default=str(RESULTS / "kinematics_real.json"))
    args = parser.parse_args(argv)
    CACHE.mkdir(parents=True, exist_ok=True)
    out = {}
    for name in VIDEO_NAMES:
        video = VIDEOS / name
        obs = detections(video)
        row = dict(detect_ms_per_frame=obs.seconds_per_frame * 1000)
        for mode in ("offline", "online"):
            seconds, motion = median_time(functools.partial(fit_motion, obs, Settings(online=mode == "online")),
                                          args.repeats)
            row[f"fit_ms_per_frame_{mode}"] = seconds / obs.num_frames * 1000
            row[mode] = quality(obs, motion)
            row[mode]["report"] = no_truth_metrics(obs, motion)
        row["live_native"] = live(video, args.repeats)
        small = CACHE / f"{video.stem}_640.mp4"
        if not small.is_file():
            trim_video(video, small, 0.0, 1e6, 640)
        row["live_640"] = live(small, args.repeats)
        row["live_640_physcap"] = live(small, args.repeats, physics="physcap")
        out[name] = row
        print(name, json.dumps(row, indent=1), flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
