"""Repeated pictures (docs/decisions/repeated-pictures.md): videos whose frames show each picture more than once, as
a video converted to a higher frame rate does.

synthetic  CMU clips with a 3D truth (bench_synthetic's camera and detector noise) at 2 x 30 fps, whose 30 pictures
           a second are each shown twice (--repeat N: N times): the pipeline's offline pieces (fit, centred
           contacts, B.4, PhysCap, trajopt) on every frame observed, on the repeats as they are (each the copy of its
           picture's observation), and on the repeats interpolated (`interpolate_repeated`); error against the
           truth, jitter, skate, frames flagged, trajopt's converged frames.
levels     what picture_change measures between consecutive frames: on every shared video (new pictures, and the
           repeats some of them hold), and on each doubled (below), where the odd frames are known repeats; the
           threshold UNCHANGED_LEVEL is read against these.
videos     every shared video, and the same video with each picture written twice at twice its rate (libx264,
           veryfast, CRF 20, as a converter would), captured by `physmocap capture` with PhysCap (the default) and
           trajopt by the code in --src; repeats found, frames flagged, trajopt's converged frames, jitter, and the
           doubled run's joints (root-relative) against the native run's at the native frames.

    .venv/bin/python benchmarks/bench_repeats.py synthetic [--set validation|test] [--repeat 2]
    .venv/bin/python benchmarks/bench_repeats.py levels [--work DIR]
    .venv/bin/python benchmarks/bench_repeats.py videos [--src OTHER/src] [--work DIR] [--label before|after]

Writes benchmarks/results/repeats_synthetic_SET_xREPEAT.json, repeats_levels.json and repeats_videos_LABEL.json
(and .md).
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import av
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_physics_limits import VALIDATION_CLIPS  # noqa: E402
from bench_synthetic import CLIPS, SECONDS, first_seconds, model_height  # noqa: E402
from common import MOCAP, REPO, RESULTS, VIDEOS, machine_description  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.detect.mediapipe_pose import detect_video  # noqa: E402
from physmocap.detect.repeats import UNCHANGED_LEVEL, interpolate_repeated, person_box, picture_change  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.evaluation import score_against_truth, to_truth_world  # noqa: E402
from physmocap.io.video import iter_frames  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import make_observations, random_camera, resample  # noqa: E402
from physmocap.trajopt import run_trajopt  # noqa: E402

PICTURE_RATE = 30.0  # pictures per second of the synthetic clips
VIDEOS_RUN = ("hybrik_taiji.mp4", "intel_highcam_walk_stand.mp4", "mmhuman3d_single_person_demo.mp4",
              "sam2_soccer_juggling.mp4", "sports2d_demo.mp4", "pose2sim_demo_singleperson/cam01.mp4")
VARIANTS = ("every frame observed", "repeats as they are", "repeats interpolated")


def repeated_observations(obs, repeat: int):
    """The observations of frames showing picture f // repeat * repeat: copies of that frame's, marked repeated."""
    shown = np.arange(obs.num_frames) // repeat * repeat
    return dataclasses.replace(obs, keypoints_2d=obs.keypoints_2d[shown], landmarks_3d=obs.landmarks_3d[shown],
                               repeated=shown != np.arange(obs.num_frames))


def part_synthetic(clips, repeat: int) -> list[dict]:
    rows = []
    fps = PICTURE_RATE * repeat
    for name in clips:
        clip = first_seconds(resample(load_mocap(MOCAP / name), fps), SECONDS)
        rng = np.random.default_rng(0)
        K, R, t = random_camera(clip, rng)
        obs, truth = make_observations(clip, K, R, t, rng, MEDIAPIPE_NOISE)
        settings = Settings().replace("body", height=model_height(truth["landmarks_world"]))
        repeated = repeated_observations(obs, repeat)
        for variant, seen in zip(VARIANTS, (obs, repeated, interpolate_repeated(repeated)), strict=True):
            offline = fit_motion(seen, settings)
            contacts, stationary, _ = predict_contacts(seen, "centred")
            refined = refine_kinematics(seen, offline, contacts, settings.fit, settings.trajopt)
            motion = refined.motion
            physcap = run_physcap(motion.body, motion.qpos, fps, refined.contacts, stationary, settings.physics,
                                  refined_input=True)
            trajopt = run_trajopt(motion.body, motion.qpos, fps, refined.contacts, settings.trajopt)
            for method, qpos, grf, flagged in (
                    ("B.4", motion.qpos, None, None), ("physcap", physcap.qpos, physcap.grf, physcap.unexplained),
                    ("trajopt", trajopt.qpos, trajopt.grf, trajopt.qp_failures > 0)):
                pose = kin.forward_kinematics(motion.body, qpos)
                points = to_truth_world(pose.points, motion.camera.R, motion.camera.t, truth)
                com = to_truth_world(kin.center_of_mass(motion.body, pose), motion.camera.R, motion.camera.t, truth)
                row = score_against_truth(points, motion.body.point_names, com, truth, motion.body.mass, grf, None)
                row = {k: row[k] for k in ("mpjpe_root_mm", "global_root_mm", "skate_percent")}
                row.update(clip=name.split("/")[-1], variant=variant, method=method, repeat=repeat,
                           jitter=metrics.mean_acceleration(pose.points, fps),
                           flagged_percent=None if flagged is None else 100 * float(np.mean(flagged)),
                           converged_percent=(100 * float(np.mean(trajopt.converged)) if method == "trajopt"
                                              else None))
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def doubled(source: Path, target: Path) -> Path:
    """`source` with each picture written twice at twice its rate (libx264 veryfast, CRF 20); made once."""
    if target.exists():
        return target
    partial = target.with_suffix(".partial.mp4")
    with av.open(str(source)) as video, av.open(str(partial), "w") as out:
        stream = video.streams.video[0]
        encoded = out.add_stream("libx264", rate=2 * stream.average_rate)
        encoded.width, encoded.height = stream.width - stream.width % 2, stream.height - stream.height % 2
        encoded.pix_fmt, encoded.options = "yuv420p", {"preset": "veryfast", "crf": "20"}
        for frame in video.decode(stream):
            picture = frame.to_ndarray(format="rgb24")[:encoded.height, :encoded.width]
            for _ in range(2):
                out.mux(encoded.encode(av.VideoFrame.from_ndarray(picture, format="rgb24")))
        out.mux(encoded.encode())
    partial.rename(target)
    return target


def capture(video: Path, out: Path, physics: str, src: Path) -> dict:
    started = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=str(src))
    command = [str(Path(sys.executable).parent / "physmocap"), "capture", str(video), "-o", str(out), "--physics",
               physics, "--no-overlay"]
    proc = subprocess.run(command, capture_output=True, text=True, env=env, check=False)
    if proc.returncode != 0:
        return dict(exit=proc.returncode, error=proc.stderr[-500:])
    result = dict(np.load(out / "result.npz"))
    return dict(exit=0, seconds=time.perf_counter() - started, result=result)


def root_relative(points: np.ndarray) -> np.ndarray:
    return points - points[:, :1]


def part_videos(src: Path, work: Path) -> list[dict]:
    rows = []
    for name in VIDEOS_RUN:
        native = VIDEOS / name
        twice = doubled(native, work / f"{Path(name).stem}_doubled.mp4")
        for physics in ("physcap", "trajopt"):
            runs = {kind: capture(path, work / "runs" / f"{Path(name).stem}_{kind}_{physics}", physics, src)
                    for kind, path in (("native", native), ("doubled", twice))}
            row = dict(video=name, physics=physics, exit={k: r["exit"] for k, r in runs.items()})
            if all(r["exit"] == 0 for r in runs.values()):
                a, b = runs["native"]["result"], runs["doubled"]["result"]
                frames = min(len(a["valid"]), len(b["valid"]) // 2)
                both = a["valid"][:frames] & b["valid"][: 2 * frames : 2]
                distance = np.linalg.norm(root_relative(a["joints_world"][:frames][both])
                                          - root_relative(b["joints_world"][: 2 * frames : 2][both]), axis=-1)
                second = b["valid"][1::2]
                found = b.get("repeated_picture", np.zeros(len(b["valid"]), bool))
                for kind, r in (("native", a), ("doubled", b)):
                    valid = r["valid"]
                    row[kind] = dict(
                        flagged_percent=100 * float(np.mean(r["physics_unexplained"][valid])),
                        fallback_percent=100 * float(np.mean(r["physics_fallback"][valid])),
                        jitter=metrics.explained_acceleration(r["joints_world"], float(r["fps"]), valid),
                        seconds=runs[kind]["seconds"])
                row.update(repeats_found_percent=100 * float(np.mean(found[1::2][: len(second)][second])),
                           new_pictures_marked=int(found[0::2].sum()),
                           root_relative_mm=1000 * float(distance.mean()))
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def changes(video: Path) -> np.ndarray:
    """picture_change of each frame (T,) from the frame before it, in the box of its detected person (nan where
    either frame has no person)."""
    obs = detect_video(video)
    out, previous = np.full(obs.num_frames, np.nan), None
    for index, frame in iter_frames(video):
        if previous is not None and obs.valid[index] and obs.valid[index - 1]:
            out[index] = picture_change(previous, frame, person_box(obs.keypoints_2d[index], obs.image_size))
        previous = frame
    return out


def part_levels(work: Path) -> list[dict]:
    rows = []
    for name in VIDEOS_RUN:
        native = changes(VIDEOS / name)
        twice = changes(doubled(VIDEOS / name, work / f"{Path(name).stem}_doubled.mp4"))
        for kind, values in (("new pictures (native)", native), ("new pictures (doubled, even frames)", twice[0::2]),
                             ("repeats (doubled, odd frames)", twice[1::2])):
            values = values[np.isfinite(values)]
            row = dict(video=name, frames=kind, count=int(len(values)),
                       below_level=int(np.sum(values < UNCHANGED_LEVEL)),
                       **{f"p{q}": float(np.percentile(values, q)) for q in (0, 1, 5, 50, 95, 99, 100)})
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def markdown_levels(rows: list[dict]) -> str:
    lines = [f"| video | frames | count | below {UNCHANGED_LEVEL} | min | 1st % | 5th % | median | 95th % | 99th % | max |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['video']} | {r['frames']} | {r['count']} | {r['below_level']} | " + " | ".join(
            f"{r[f'p{q}']:.3f}" for q in (0, 1, 5, 50, 95, 99, 100)) + " |")
    return "\n".join(lines)


def markdown_synthetic(rows: list[dict]) -> str:
    lines = ["| clip | method | variant | root-rel. mm | global root mm | skate % | jitter m/s² | flagged % | "
             "trajopt converged % |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['clip']} | {r['method']} | {r['variant']} | {r['mpjpe_root_mm']:.1f} | "
                     f"{r['global_root_mm']:.1f} | {r['skate_percent']:.1f} | {r['jitter']:.2f} | "
                     f"{'' if r['flagged_percent'] is None else format(r['flagged_percent'], '.1f')} | "
                     f"{'' if r['converged_percent'] is None else format(r['converged_percent'], '.1f')} |")
    return "\n".join(lines)


def markdown_videos(rows: list[dict]) -> str:
    lines = ["| video | physics | repeats found % (new pictures marked) | flagged % native / doubled | "
             "jitter m/s² native / doubled | doubled against native, root-relative mm |", "|---|---|---|---|---|---|"]
    for r in rows:
        if "native" not in r:
            lines.append(f"| {r['video']} | {r['physics']} | exit {r['exit']} | | | |")
            continue
        n, d = r["native"], r["doubled"]
        lines.append(f"| {r['video']} | {r['physics']} | {r['repeats_found_percent']:.1f} ({r['new_pictures_marked']}) "
                     f"| {n['flagged_percent']:.1f} / {d['flagged_percent']:.1f} | {n['jitter']:.2f} / "
                     f"{d['jitter']:.2f} | {r['root_relative_mm']:.1f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("part", choices=("synthetic", "levels", "videos"))
    parser.add_argument("--set", choices=("validation", "test"), default="validation")
    parser.add_argument("--repeat", type=int, default=2, help="synthetic: times each picture is shown")
    parser.add_argument("--src", type=Path, default=REPO / "src", help="videos: the code that captures")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "physmocap_bench_repeats")
    parser.add_argument("--label", default="this", help="videos: the name of the results file")
    args = parser.parse_args(argv)
    header = f"Machine: {machine_description()}; load average {os.getloadavg()[0]:.1f}.\n\n"
    if args.part == "synthetic":
        clips = VALIDATION_CLIPS[:2] if args.set == "validation" else CLIPS
        rows = part_synthetic(clips, args.repeat)
        stem, text = f"repeats_synthetic_{args.set}_x{args.repeat}", markdown_synthetic(rows)
    elif args.part == "levels":
        args.work.mkdir(parents=True, exist_ok=True)
        rows = part_levels(args.work)
        stem, text = "repeats_levels", markdown_levels(rows)
    else:
        args.work.mkdir(parents=True, exist_ok=True)
        rows = part_videos(args.src.resolve(), args.work)
        stem, text = f"repeats_videos_{args.label}", markdown_videos(rows)
    (RESULTS / f"{stem}.json").write_text(json.dumps(rows, indent=1))
    (RESULTS / f"{stem}.md").write_text(header + text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
