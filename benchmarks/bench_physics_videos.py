"""Physics on the real videos (issue 17): `physmocap capture VIDEO --physics physcap --no-overlay` on every video in
../shared/data/videos/ (one view of the multi-view set) and on a 10 fps re-encode of sports2d_demo.mp4 (every
third frame, OpenCV), each run once as a user would. Per video: exit code, wall time, frames flagged as
unexplained by the physics (result.npz physics_unexplained), the largest contact force and residual root force
in body weights, whether every number in result.npz is finite, and the physics' jitter (mean joint acceleration)
and foot slide during contact against its own kinematic input (result.npz joints_world_kinematic); jitter and the
median reprojection error and the Procrustes-aligned error against the detector's own metric 3D landmarks (the
accuracies available without a 3D truth) also over the feet-only frames alone (valid, not flagged, and so their
neighbours). --runs FOLDER keeps the run folders, whose caches a second run reuses (then
only contacts, physics and the outputs run again). --online captures with the causal fit (`capture --online`);
give it its own --runs folder, or a copy of an offline one to reuse its detections. --reencoded runs the 10-12 fps
inputs instead, each written again by H.264 at three qualities (REENCODED, CRFS; PyAV's libx264): how far the
encoding alone moves a slow video's ratios to its input (docs/decisions/b4-feet-above-floor.md).

    .venv/bin/python benchmarks/bench_physics_videos.py [--physics physcap] [--online] [--videos NAME ... | --reencoded]

Writes benchmarks/results/physics_videos.json and .md (--reencoded: physics_videos_reencoded.json and .md); runs go
to a temporary folder.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from common import REPO, RESULTS, VIDEOS, read_clip, write_clip  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.body.model import CONTACT_POINTS  # noqa: E402
from physmocap.landmarks import LANDMARK_INDEX  # noqa: E402
from physmocap.motion import Observations  # noqa: E402

VIDEOS_RUN = ("hybrik_taiji.mp4", "intel_highcam_walk_stand.mp4", "mmhuman3d_single_person_demo.mp4",
              "sam2_soccer_juggling.mp4", "sports2d_demo.mp4", "pose2sim_demo_singleperson/cam01.mp4")
GRAVITY = 9.81
# The 10-12 fps inputs (video, every how many frames: its own file's rate or a subsampling's) and the H.264 constant
# rate factors they are written again at (--reencoded): near-lossless, the encoder's default region, visibly lossy.
REENCODED = (("intel_highcam_walk_stand.mp4", 1), ("mmhuman3d_single_person_demo.mp4", 1), ("sports2d_demo.mp4", 3),
             ("hybrik_taiji.mp4", 2), ("sam2_soccer_juggling.mp4", 2))
CRFS = (12, 20, 28)
# The detector's 3D landmarks that are joints of the body (faces and hands left out: the detector's noisiest), with
# the result point each one is fitted to.
LIMB_LANDMARKS = tuple((side + part, side + part) for side in ("left_", "right_")
                       for part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle", "heel")) + (
    ("left_foot_index", "left_toe"), ("right_foot_index", "right_toe"))


def reencode(source: Path, target: Path, keep_every: int, fps: float | None = None) -> float:
    """Every `keep_every`-th frame of `source` written to `target` stating `fps` frames per second (default: the
    source's / keep_every, its true rate; another is a slow-motion file); returns the stated fps."""
    capture = cv2.VideoCapture(str(source))
    fps = fps or capture.get(cv2.CAP_PROP_FPS) / keep_every
    size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    writer = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    index = 0
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        if index % keep_every == 0:
            writer.write(frame)
        index += 1
    capture.release()
    writer.release()
    return fps


def slide_cm(points: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """cm per frame: horizontal motion of each sole point between frames where it is in contact in both."""
    step = 100 * np.linalg.norm(np.diff(points[:, :, :2], axis=0), axis=-1)
    return step[contacts[1:] & contacts[:-1]]


def mean_acceleration(points: np.ndarray, fps: float) -> float:
    """m/s^2: `metrics.mean_acceleration`, NaN for fewer than three frames (a clip too short for jitter)."""
    return metrics.mean_acceleration(points, fps) if len(points) >= 3 else float("nan")


def against_own_capture(slow: Path, full: Path, keep_every: int = 3) -> dict:
    """The re-encode `slow` (every `keep_every`-th frame of the video captured in `full`, run folders) against that
    capture read on the same frames: over the slow run's feet-only frames (metrics.explained_acceleration's), the
    jitter of each motion read at the slow rate (m/s^2) and the slow motions' acceleration error against the full
    capture's physics (mean over joints of the difference of second differences). The full capture sees three times
    the pictures: whatever the slow motions lack of its acceleration is real motion smoothed away, not noise
    removed."""
    a, b = (dict(np.load(folder / "result.npz", allow_pickle=False)) for folder in (slow, full))
    fps = float(a["fps"])
    frames = keep_every * np.arange(len(a["valid"]))
    n = int(np.sum(frames < len(b["valid"])))
    explained = (a["valid"] & ~a["physics_unexplained"].astype(bool))[:n]
    inner = metrics.explained_interior(explained)
    reference = metrics.accelerations(b["joints_world"][frames[:n]], fps)
    out = {}
    for label, points in (("slow_physics", a["joints_world"][:n]), ("slow_input", a["joints_world_kinematic"][:n]),
                          ("full_physics", b["joints_world"][frames[:n]]),
                          ("full_input", b["joints_world_kinematic"][frames[:n]])):
        out[f"{label}_jitter"] = metrics.explained_acceleration(points, fps, explained)
        if label.startswith("slow"):
            error = np.linalg.norm(metrics.accelerations(points, fps) - reference, axis=-1).mean(axis=1)
            out[f"{label}_acceleration_error"] = float(error[inner].mean())
    return out | dict(frames=int(inner.sum()))


def aligned_error_mm(points: np.ndarray, names: list[str], observations: Observations, frames: np.ndarray) -> float:
    """mm: `aligned_to_mm` against the detector's metric 3D landmarks (LIMB_LANDMARKS; frames where one is unseen left
    out): the aligned error that a video without 3D truth allows, against a noisy reference that is the same for the
    physics and its kinematic input (but which the kinematic fit was fitted to: docs/decisions/physics-planted-feet.md)."""
    landmarks = observations.landmarks_3d[:, [LANDMARK_INDEX[a] for a, _ in LIMB_LANDMARKS]]
    seen = frames & np.isfinite(landmarks).all(axis=(1, 2)) & (np.abs(landmarks).sum(axis=(1, 2)) > 0)
    return aligned_to_mm(points, names, landmarks, seen)


def aligned_to_mm(points: np.ndarray, names: list[str], reference: np.ndarray, frames: np.ndarray) -> float:
    """mm: median over `frames` (T,) bool of the per-frame Procrustes-aligned mean distance between the result's
    points (T, P, 3) named `names` at LIMB_LANDMARKS and `reference` (T, len(LIMB_LANDMARKS), 3) m."""
    if not frames.any():
        return float("nan")
    ours = points[frames][:, [names.index(b) for _, b in LIMB_LANDMARKS]]
    aligned, reference = metrics.align_prediction(ours, reference[frames], align="procrustes")
    return 1000 * float(np.median(np.linalg.norm(aligned - reference, axis=-1).mean(axis=1)))


def score(result_path: Path) -> dict:
    result = dict(np.load(result_path, allow_pickle=False))
    names = [str(n) for n in result["joint_names"]]
    feet = [names.index(n) for n in CONTACT_POINTS]
    fps, weight = float(result["fps"]), float(result["body_mass"]) * GRAVITY
    valid = result["valid"].astype(bool)
    final, kinematic = result["joints_world"][valid], result["joints_world_kinematic"][valid]
    contacts = result["contacts"][valid].astype(bool)
    non_finite = sorted(k for k, v in result.items() if np.asarray(v).dtype.kind in "fc" and not np.isfinite(v).all())
    flagged = result.get("physics_unexplained", np.zeros(len(valid), bool))
    physics_slide, kinematic_slide = slide_cm(final[:, feet], contacts), slide_cm(kinematic[:, feet], contacts)
    explained = valid & ~flagged.astype(bool)
    measured = result["reprojection_measured"].astype(bool) if "reprojection_measured" in result else np.isfinite(
        result["reprojection_error"])
    measured &= explained

    def feet_only(points: np.ndarray) -> float:  # m/s^2: jitter where only the feet carry the body
        return metrics.explained_acceleration(points, fps, explained)

    observations = Observations.load(result_path.parent / "cache" / "observations.npz")
    return dict(frames=int(len(valid)), fps=fps, valid_frames=int(valid.sum()), all_finite=not non_finite,
                non_finite_keys=non_finite,
                flagged_frames=int(np.sum(flagged)),
                largest_contact_force_bw=float(np.linalg.norm(result["grf"].sum(axis=1), axis=-1).max() / weight),
                unflagged_over_2bw=int(np.sum(np.linalg.norm(result["grf"].sum(axis=1), axis=-1)[explained]
                                              > 2.0 * weight)),
                largest_residual_force_bw=float(np.linalg.norm(result["residual_root_force"][:, :3], axis=-1).max()
                                                / weight),
                jitter=mean_acceleration(final, fps), kinematic_jitter=mean_acceleration(kinematic, fps),
                feet_only_jitter=feet_only(result["joints_world"]),
                feet_only_kinematic_jitter=feet_only(result["joints_world_kinematic"]),
                feet_only_reprojection_px=float(np.median(result["reprojection_error_final"][measured])),
                feet_only_kinematic_reprojection_px=float(np.median(result["reprojection_error"][measured])),
                feet_only_aligned_mm=aligned_error_mm(result["joints_world"], names, observations, explained),
                feet_only_kinematic_aligned_mm=aligned_error_mm(result["joints_world_kinematic"], names, observations,
                                                                explained),
                slide_median_cm=float(np.median(physics_slide)) if physics_slide.size else float("nan"),
                kinematic_slide_median_cm=float(np.median(kinematic_slide)) if kinematic_slide.size else float("nan"),
                physics_deviation_mm=1000 * float(result["physics_deviation"][valid].mean()),
                **grf_means(result["grf"][explained], weight))


def grf_means(grf: np.ndarray, weight: float) -> dict:
    """% BW over the given frames: the mean magnitude of the net contact force (Rempe et al.'s GRF mean), its mean
    vertical component and horizontal magnitude, and that magnitude after a 9-frame moving average (the horizontal
    force without its frame-to-frame chatter: docs/decisions/physics-grf-chatter.md)."""
    net = 100 * grf.sum(axis=1) / weight
    if len(net) < 9:
        return {}
    averaged = np.stack([np.convolve(net[:, i], np.ones(9) / 9, "valid") for i in range(2)], axis=1)
    return dict(grf_mean_percent_bw=float(np.linalg.norm(net, axis=1).mean()),
                grf_vertical_percent_bw=float(net[:, 2].mean()),
                grf_horizontal_percent_bw=float(np.linalg.norm(net[:, :2], axis=1).mean()),
                grf_horizontal_9_frames_percent_bw=float(np.linalg.norm(averaged, axis=1).mean()))


def run_video(video: Path, out: Path, physics: str, config: str | None = None, online: bool = False) -> dict:
    command = [sys.executable, "-m", "physmocap.cli", "capture", str(video), "-o", str(out), "--physics", physics,
               "--no-overlay"] + (["--config", config] if config else []) + (["--online"] if online else [])
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO / "src")})
    row = dict(video=video.name, exit_code=done.returncode, wall_s=time.perf_counter() - start,
               last_line=(done.stdout.strip().splitlines() or [""])[-1][-200:],
               traceback="Traceback" in done.stderr, stderr_tail=done.stderr.strip()[-300:])
    if done.returncode == 0 and (out / "result.npz").exists():
        row.update(score(out / "result.npz"))
    return row


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--physics", default="physcap")
    chosen = parser.add_mutually_exclusive_group()
    chosen.add_argument("--videos", nargs="*", default=None, help="names under the videos folder (default: all)")
    parser.add_argument("--json", default=str(RESULTS / "physics_videos.json"))
    parser.add_argument("--runs", default=None, help="keep the run folders here (default: a temporary folder)")
    parser.add_argument("--config", default=None, help="a TOML settings file passed to every capture")
    parser.add_argument("--online", action="store_true", help="capture --online (the causal fit and PhysCap)")
    chosen.add_argument("--reencoded", action="store_true",
                        help="the 10-12 fps inputs written again by H.264 at crf 12 / 20 / 28, instead of the videos")
    args = parser.parse_args(argv)
    if args.reencoded and args.json == parser.get_default("json"):
        args.json = str(RESULTS / "physics_videos_reencoded.json")
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        work = Path(args.runs or folder)
        work.mkdir(parents=True, exist_ok=True)  # the re-encode below writes into it first
        videos = [VIDEOS / name for name in (args.videos or VIDEOS_RUN)]
        if args.reencoded:
            videos = []
            for name, every in REENCODED:
                pictures, fps = read_clip(name, every=every)
                for crf in CRFS:
                    videos.append(work / f"{Path(name).stem}_every{every}_crf{crf}.mp4")
                    write_clip(videos[-1], pictures, fps, crf)
        elif args.videos is None:
            slow = work / "sports2d_demo_10fps.mp4"
            reencode(VIDEOS / "sports2d_demo.mp4", slow, 3)
            videos.append(slow)
        for video in videos:
            row = run_video(video, work / video.stem, args.physics, args.config, args.online)
            rows.append(row)
            print(json.dumps(row), flush=True)
    out = dict(physics=args.physics, online=args.online, rows=rows, load_average=os.getloadavg()[0])
    if args.videos is None and not args.reencoded and all(r["exit_code"] == 0 for r in rows
                                                           if "sports2d_demo" in r["video"]):
        out["sports2d_10fps_against_30fps"] = against_own_capture(work / "sports2d_demo_10fps", work / "sports2d_demo")
    RESULTS.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1))
    lines = ["| video | exit | wall s | frames (fps) | flagged | largest contact force BW (unflagged frames over 2 BW) | "
             "largest residual BW | "
             "all finite | jitter m/s² (kinematic input) | feet-only jitter m/s² (input) | feet-only reprojection "
             "px, median (input) | feet-only aligned error to the detector's 3D mm, median (input) | foot slide in contact cm/frame, median (input) | feet-only GRF mean / vertical / "
             "horizontal / horizontal 9-frame % BW |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "frames" in r:
            lines.append(f"| {r['video']} | {r['exit_code']} | {r['wall_s']:.0f} | {r['frames']} ({r['fps']:.0f}) | "
                         f"{r['flagged_frames']} | {r['largest_contact_force_bw']:.2f} ({r['unflagged_over_2bw']}) | "
                         f"{r['largest_residual_force_bw']:.2f} | {r['all_finite']} | {r['jitter']:.1f} "
                         f"({r['kinematic_jitter']:.1f}) | {r['feet_only_jitter']:.1f} "
                         f"({r['feet_only_kinematic_jitter']:.1f}) | {r['feet_only_reprojection_px']:.1f} "
                         f"({r['feet_only_kinematic_reprojection_px']:.1f}) | {r['feet_only_aligned_mm']:.1f} "
                         f"({r['feet_only_kinematic_aligned_mm']:.1f}) | {r['slide_median_cm']:.2f} "
                         f"({r['kinematic_slide_median_cm']:.2f}) | {r.get('grf_mean_percent_bw', np.nan):.0f} / "
                         f"{r.get('grf_vertical_percent_bw', np.nan):.0f} / {r.get('grf_horizontal_percent_bw', np.nan):.0f}"
                         f" / {r.get('grf_horizontal_9_frames_percent_bw', np.nan):.0f} |")
        else:
            lines.append(f"| {r['video']} | {r['exit_code']} | {r['wall_s']:.0f} | {r['last_line']} | | | | | | | | | | |")
    scored = [r for r in rows if np.isfinite(r.get("feet_only_jitter", np.nan))]
    if scored:
        above = sum(r["feet_only_jitter"] > r["feet_only_kinematic_jitter"] for r in scored)
        within = sum(r["feet_only_aligned_mm"] <= 1.05 * r["feet_only_kinematic_aligned_mm"] for r in scored)
        lines += ["", f"Feet-only frames: jitter above the input on {above} of {len(scored)}; aligned error within 5% "
                  f"of the input on {within} of {len(scored)}."]
    if "sports2d_10fps_against_30fps" in out:
        c = out["sports2d_10fps_against_30fps"]
        lines += ["", f"sports2d at 10 fps against its own 30 fps capture read on the same frames ({c['frames']} "
                  f"feet-only frames), jitter m/s²: 10 fps physics {c['slow_physics_jitter']:.2f}, its input "
                  f"{c['slow_input_jitter']:.2f}; 30 fps physics {c['full_physics_jitter']:.2f}, its input "
                  f"{c['full_input_jitter']:.2f}. Acceleration error against the 30 fps physics: 10 fps physics "
                  f"{c['slow_physics_acceleration_error']:.2f}, its input {c['slow_input_acceleration_error']:.2f}."]
    Path(args.json).with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return out


if __name__ == "__main__":
    main()
