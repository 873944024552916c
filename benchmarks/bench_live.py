"""Live capture latency (issue 24): shared videos scaled to 640 px wide, played at their own frame rate as a camera
would deliver them (stream_capture realtime=True), with the drop policy on and off, with and without physics.

Per run: true latency from a frame's arrival (its scheduled time, start + index / fps) to its final pose, median and
95th percentile over the processed frames after the calibration warm-up; frames arrived, processed and dropped (in
all, and after the warm-up); the achieved rate (processed frames per second); the CPU seconds of the process and
the load average (1 min) before and after, as timings on a shared machine depend on it. Runs alternate drop on and
off so that a change of load hits both. The 640-px copies are made once per call in a temporary folder (PyAV
decode with area scaling, libx264 CRF 18).

    .venv/bin/python benchmarks/bench_live.py                        # both videos, physics none and physcap
    .venv/bin/python benchmarks/bench_live.py --videos hybrik_taiji.mp4 --physics physcap --repeats 3
    .venv/bin/python benchmarks/bench_live.py --loops 3                # on a loaded machine: a longer steady state
    .venv/bin/python benchmarks/bench_live.py --fit-thread-costs       # CPU ms of a kept and a dropped frame

Prints a markdown table and writes benchmarks/results/live.json.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from physmocap.config import Settings
from physmocap.io.video import VideoWriter, iter_frames
from physmocap.live import DROPPED_REASON, stream_capture

sys.path.insert(0, str(Path(__file__).parent))
from common import RESULTS, VIDEOS, git_revision, machine_description  # noqa: E402

VIDEO_NAMES = ("hybrik_taiji.mp4", "sports2d_demo.mp4")


def scaled_copy(video: Path, width: int, loops: int, folder: Path) -> Path:
    """`video` scaled down to `width` pixels wide (same rate), played `loops` times over, in `folder`."""
    reader = iter_frames(video, max_width=width)
    out = folder / f"{video.stem}_{width}.mp4"
    with VideoWriter(out, reader.info.fps, *reader.output_size, crf=18) as writer:
        for _ in range(loops):
            for _, frame in reader:
                writer.write(frame)
    return out


def live_run(video: Path, physics: str, drop: bool) -> dict:
    settings = Settings(online=True).replace("physics", method=physics)
    load_before, cpu = os.getloadavg()[0], time.process_time()
    report = stream_capture(str(video), settings, realtime=True, drop_stale_frames=drop)
    reasons = report.observations.invalid_reason
    return dict(
        latency_median_ms=report.latency_median_ms, latency_p95_ms=report.latency_p95_ms,
        frames_arrived=report.frames_arrived, frames_processed=report.frames_processed,
        frames_dropped=report.frames_dropped, dropped_before_detection=report.frames_dropped_before_detection,
        dropped_before_fit=report.frames_dropped_before_fit,
        dropped_after_warmup=int(np.sum(reasons[report.warmup_frames:] == DROPPED_REASON)),
        warmup_frames=report.warmup_frames, achieved_fps=report.frames_per_second, source_fps=report.observations.fps,
        detect_ms_per_detection=report.detect_ms_per_frame, fit_ms_per_frame=report.fit_ms_per_frame,
        contacts_physics_ms_per_frame=report.contacts_physics_ms_per_frame, wall_seconds=report.wall_seconds,
        cpu_seconds=time.process_time() - cpu, load_before=load_before, load_after=os.getloadavg()[0])


def fit_thread_costs(video: Path, frames: int = 200, first_dropped: int = 80) -> list[dict]:
    """CPU ms per frame in the fit thread: the first `frames` detections of `video` replayed through the fit and
    contacts + physics with every other frame from `first_dropped` on dropped, the dropped ones predicted
    (OnlineFitter.skip) or fitted as unseen frames (push(valid=False)); means over the frames from first_dropped."""
    from physmocap.kinematics.online import OnlineFitter
    from physmocap.live import _AfterFit

    obs = stream_capture(str(video), Settings(online=True).replace("physics", method="none"),
                         max_frames=frames).observations
    nothing = np.zeros_like(obs.keypoints_2d[0])
    rows = []
    for physics in ("none", "physcap"):
        settings = Settings(online=True).replace("physics", method=physics)
        for skip in (True, False):
            fitter, after = OnlineFitter(settings, obs.fps, obs.image_size), _AfterFit(settings, obs.fps)
            keypoints, reasons = [], []
            cost: dict[str, list[float]] = {"fit": [], "fit_dropped": [], "after": [], "after_dropped": []}
            for t in range(obs.num_frames):
                dropped = t >= first_dropped and t % 2 == 1
                keypoints.append(nothing if dropped else obs.keypoints_2d[t])
                reasons.append(DROPPED_REASON if dropped else str(obs.invalid_reason[t]))
                start = time.process_time()
                if dropped:
                    poses = fitter.skip() if skip else fitter.push(nothing, nothing, False)
                else:
                    poses = fitter.push(obs.keypoints_2d[t], obs.landmarks_3d[t], bool(obs.valid[t]))
                fitted = time.process_time()
                for index, q in poses:
                    after.push(index, q, fitter.body, keypoints, reasons)
                if t >= first_dropped:
                    cost["fit_dropped" if dropped else "fit"].append(fitted - start)
                    cost["after_dropped" if dropped else "after"].append(time.process_time() - fitted)
            rows.append(dict(physics=physics, dropped_frames="skip" if skip else "push(valid=False)",
                             **{f"{k}_ms": float(np.mean(v) * 1000) for k, v in cost.items()}))
            print(rows[-1])
    return rows


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--videos", nargs="+", default=list(VIDEO_NAMES), help="files in the shared videos folder")
    parser.add_argument("--width", type=int, default=640, help="pixels; the copies' width")
    parser.add_argument("--physics", nargs="+", choices=("none", "physcap"), default=["none", "physcap"])
    parser.add_argument("--repeats", type=int, default=1, help="runs per case; the table gives their medians")
    parser.add_argument("--loops", type=int, default=1,
                        help="play each video this many times over in one run: a longer steady state where the "
                             "pipeline processes few frames (the 3-s calibration warm-up waits for 3 s of detected "
                             "frames; the person jumps back at each loop)")
    parser.add_argument("--json", default=str(RESULTS / "live.json"))
    parser.add_argument("--fit-thread-costs", action="store_true",
                        help="instead: CPU ms per kept and dropped frame in the fit thread (the first video)")
    args = parser.parse_args(argv)
    if args.fit_thread_costs:
        with tempfile.TemporaryDirectory(prefix="bench_live_") as folder:
            return {"fit_thread_costs": fit_thread_costs(scaled_copy(VIDEOS / args.videos[0], args.width, 1,
                                                                      Path(folder)))}
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_live_") as folder:
        for name in args.videos:
            video = scaled_copy(VIDEOS / name, args.width, args.loops, Path(folder))
            for physics in args.physics:
                runs: dict[bool, list[dict]] = {True: [], False: []}
                for _ in range(args.repeats):
                    for drop in (True, False):
                        runs[drop].append(live_run(video, physics, drop))
                for drop in (True, False):
                    median = {key: statistics.median(r[key] for r in runs[drop]) for key in runs[drop][0]}
                    rows.append(dict(video=name, width=args.width, loops=args.loops, physics=physics,
                                     drop_stale_frames=drop,
                                     median=median, runs=runs[drop]))
    print(f"| video ({args.width} px) | physics | drop policy | true latency median / p95 ms | frames arrived / "
          "processed / dropped (after warm-up) | achieved fps / source fps | detect ms | fit + contacts/physics ms "
          "| CPU s | load |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        m = row["median"]
        print(f"| {row['video']} | {row['physics']} | {'on' if row['drop_stale_frames'] else 'off'} "
              f"| {m['latency_median_ms']:.0f} / {m['latency_p95_ms']:.0f} "
              f"| {m['frames_arrived']:.0f} / {m['frames_processed']:.0f} / {m['frames_dropped']:.0f} "
              f"({m['dropped_after_warmup']:.0f}) | {m['achieved_fps']:.1f} / {m['source_fps']:.1f} "
              f"| {m['detect_ms_per_detection']:.1f} | {m['fit_ms_per_frame']:.1f} + "
              f"{m['contacts_physics_ms_per_frame']:.1f} | {m['cpu_seconds']:.1f} "
              f"| {m['load_before']:.1f} → {m['load_after']:.1f} |")
    out = dict(machine=machine_description(), revision=git_revision(), repeats=args.repeats, rows=rows)
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
