"""The video's clock against gravity (kinematics.clock): does the check find a slow-motion video, and does it stay
quiet on videos whose rate is right?

Synthetic: motion-capture clips with jumps or running (validation: CMU subjects 2, 9, 13, 16; test: the synthetic
set's clips of subjects 6 and 131, 131_03 a hop), the first 8 s observed by a random camera at the true rate
with MediaPipe-like noise, then labelled with a stated rate: the true one (a right file), or 2, 2.5 or 3 times
slower (slow motion; 25 fps footage stated as 10 is issue 17's parkour case). The offline kinematic fit and the
centred contacts, as `--physics none` gives them, then check_clock: arcs found, the fastest fall, the rate that
makes it g, the warning.

Physics: what `--fps` buys. The validation jumps filmed at 25 fps and stated as 10 (the file) or 25 (`--fps 25`):
the default offline capture (fit, contacts, B.4, PhysCap) scored frame by frame against the truth (root-relative
and Procrustes error, frames flagged unexplained, the vertical contact force against the truth's implied one).

Videos: every shared video captured as a user would (`physmocap capture --no-overlay`, default physics) at its
own rate, and the same frames written to a file that states 2.5 times fewer per second; summary.json's
video_clock.

    .venv/bin/python benchmarks/bench_video_clock.py [--part synthetic|physics|videos|all] [--set validation|test]
        [--json OUT.json]
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_physics_limits import true_vertical_force  # noqa: E402
from bench_physics_videos import reencode, run_video  # noqa: E402
from bench_synthetic import CLIPS as TEST_CLIPS, SECONDS, first_seconds, model_height  # noqa: E402
from common import MOCAP, RESULTS, VIDEOS, machine_description  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.body.model import CONTACT_POINTS  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.contacts.footlock import lock_feet  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.evaluation import score_against_truth, to_truth_world  # noqa: E402
from physmocap.io.atomic import write_text  # noqa: E402
from physmocap.kinematics.clock import check_clock  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.metrics import GRAVITY  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import make_observations, random_camera, resample  # noqa: E402

VALIDATION_CLIPS = ("cmu_iclone_cc3_retarget/002_04.bvh", "cmu_daz_cgspeed/13_39.bvh", "cmu_daz_cgspeed/13_11.bvh",
                    "cmu_daz_cgspeed/09_01.bvh", "cmu_raw_subject16/16_01.bvh")
# (true rate, stated rate), frames/s: a right file, then slow motion by 2, 2.5 (issue 17's 25 stated as 10) and 3
RATES = ((30.0, 30.0), (30.0, 15.0), (25.0, 10.0), (30.0, 10.0))
VIDEO_SLOWDOWN = 2.5
VIDEOS_RUN = ("hybrik_taiji.mp4", "intel_highcam_walk_stand.mp4", "mmhuman3d_single_person_demo.mp4",
              "sam2_soccer_juggling.mp4", "sports2d_demo.mp4", "pose2sim_demo_singleperson/cam01.mp4")


def stated_case(name: str, true_fps: float, stated_fps: float, seed: int = 0):
    """The clip observed at true_fps and labelled stated_fps: observations, truth, settings, the offline fit and
    its contacts (centred, foot-locked) and stationary flags."""
    clip = first_seconds(resample(load_mocap(MOCAP / name), true_fps), SECONDS)
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, MEDIAPIPE_NOISE)
    obs = dataclasses.replace(obs, fps=stated_fps)
    settings = Settings().replace("body", height=model_height(truth["landmarks_world"]))
    motion = fit_motion(obs, settings)
    predicted, stationary, _ = predict_contacts(obs, "centred")
    return obs, truth, settings, motion, lock_feet(predicted, motion.body, motion.qpos, settings.physics), stationary


def synthetic_row(name: str, true_fps: float, stated_fps: float) -> dict:
    """One clip observed at true_fps and labelled stated_fps: the check on its offline fit and centred contacts."""
    _, _, _, motion, contacts, _ = stated_case(name, true_fps, stated_fps)
    pose = kin.forward_kinematics(motion.body, motion.qpos)
    soles = pose.points[:, motion.body.point_index(CONTACT_POINTS), 2]
    check = check_clock(kin.center_of_mass(motion.body, pose)[:, 2], soles, contacts, motion.valid, stated_fps, name)
    return dict(clip=name, true_fps=true_fps, stated_fps=stated_fps, arcs=check.arcs, fall=check.fall,
                consistent_fps=check.consistent_fps, warned=bool(check.warning))


def physics_row(name: str, stated_fps: float, true_fps: float = 25.0) -> dict:
    """The default offline capture of the clip filmed at true_fps, stated as stated_fps, against the truth frame by
    frame (the truth keeps its true rate: forces read at true times)."""
    obs, truth, settings, motion, contacts, stationary = stated_case(name, true_fps, stated_fps)
    refined = refine_kinematics(obs, motion, contacts, settings.fit, settings.trajopt)
    body, camera = refined.motion.body, refined.motion.camera
    physics = run_physcap(body, refined.motion.qpos, stated_fps, refined.contacts, stationary, settings.physics,
                          valid=refined.motion.valid, refined_input=True)
    pose = kin.forward_kinematics(body, physics.qpos)
    points = to_truth_world(pose.points, camera.R, camera.t, truth)
    com = to_truth_world(kin.center_of_mass(body, pose), camera.R, camera.t, truth)
    scores = score_against_truth(points, body.point_names, com, truth, body.mass, physics.grf, physics.residual)
    vertical = physics.grf[..., 2].sum(axis=1) / (body.mass * GRAVITY)
    return dict(clip=name, true_fps=true_fps, stated_fps=stated_fps, mpjpe_root_mm=scores["mpjpe_root_mm"],
                mpjpe_procrustes_mm=scores["mpjpe_procrustes_mm"], grf_mean_percent_bw=scores["grf_mean_percent_bw"],
                flagged_percent=100 * float(physics.unexplained.mean()),
                vertical_force_error_bw=float(np.sqrt(np.mean((vertical - true_vertical_force(body, truth)) ** 2))))


def video_row(video: Path, out: Path, stated_fps: float | None = None) -> dict:
    """`video` captured as a user would (bench_physics_videos.run_video; restated at stated_fps first when given):
    summary.json's video_clock."""
    if stated_fps is not None:
        restated = out.with_suffix(".mp4")
        reencode(video, restated, 1, stated_fps)
        video = restated
    captured = run_video(video, out, "physcap")
    row = dict(video=captured["video"], exit_code=captured["exit_code"])
    if row["exit_code"] == 0:
        summary = json.loads((out / "summary.json").read_text())
        clock = summary["video_clock"]
        row.update(fps=summary["fps"], arcs=clock["arcs"], fall=clock["fall"], consistent_fps=clock["consistent_fps"],
                   warned=bool(clock["warning"]))
    return row


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", choices=("synthetic", "physics", "videos", "all"), default="all")
    parser.add_argument("--set", choices=("validation", "test"), default="test")
    parser.add_argument("--json", default=str(RESULTS / "video_clock.json"))
    args = parser.parse_args(argv)
    out: dict = dict(machine=machine_description())
    if args.part in ("synthetic", "all"):
        clips = VALIDATION_CLIPS if args.set == "validation" else TEST_CLIPS
        rows = []
        for name in clips:
            for true_fps, stated_fps in RATES:
                rows.append(synthetic_row(name, true_fps, stated_fps))
                print("synthetic", rows[-1], flush=True)
        out[f"synthetic_{args.set}"] = rows
    if args.part in ("physics", "all"):
        out["physics"] = []
        for name in VALIDATION_CLIPS:
            if name.endswith("09_01.bvh"):  # running: its strides are no arcs once slowed (see synthetic)
                continue
            for stated in (10.0, 25.0):
                out["physics"].append(physics_row(name, stated))
                print("physics", out["physics"][-1], flush=True)
    if args.part in ("videos", "all"):
        rows = []
        with tempfile.TemporaryDirectory() as folder:
            for name in VIDEOS_RUN:
                video = VIDEOS / name
                fps = cv2.VideoCapture(str(video)).get(cv2.CAP_PROP_FPS)
                for stated in (None, fps / VIDEO_SLOWDOWN):
                    tag = "own" if stated is None else "slowed"
                    rows.append(dict(video_row(video, Path(folder) / f"{Path(name).stem}_{tag}", stated),
                                     source=name, file_fps=fps, stated=tag))
                    print("videos", rows[-1], flush=True)
        out["videos"] = rows
    write_text(args.json, json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
