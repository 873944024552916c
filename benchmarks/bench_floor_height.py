"""Floor tilt and body height on the synthetic set with ground truth (issue 17, points 5 and 7).

Floor: per clip, the angle between the estimated floor's normal and the true one (both in the camera frame) for
the offline kinematic floor (kinematics.floor.estimate_floor), the B.4-refined offline floor that both offline
physics methods run on, the online warm-up floor, and the floor the online PhysCap ends on (FloorRefiner), with
the floor confidence the kinematic stage reports.

Height: the clips' skeletons scaled to several standing heights; the global root error (camera frame) of the
offline kinematic fit with the default height (1.70 m), with the automatic estimate (calibration's
estimate_height), and with the true height; and the estimate's error. Real: how metric MediaPipe's 3D landmarks
are against a multi-view triangulation (Pose2Sim demo), which the synthetic set cannot tell (its 3D landmarks
are metric by construction). Detectors: the offline fit with only COCO's 17 landmarks, or a random half.

Validation clips (subjects other than the contact networks' held-out 6 and 131) chose the constants; the test
clips are bench_synthetic's (subjects 6 and 131 only).

    .venv/bin/python benchmarks/bench_floor_height.py [--part floor|height|both] [--set validation|test]
        [--quick] [--fps 10] [--json OUT.json]
    .venv/bin/python benchmarks/bench_floor_height.py --part real-height   # MediaPipe's metric scale, real video
    .venv/bin/python benchmarks/bench_floor_height.py --part detectors     # only COCO's 17 landmarks, or half
    .venv/bin/python benchmarks/bench_floor_height.py --part real-floor --observations OBS.npz ...
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_synthetic import CLIPS as TEST_CLIPS, FPS, SECONDS, first_seconds, model_height  # noqa: E402
from common import MOCAP, RESULTS, machine_description  # noqa: E402
from physmocap.body import kinematics as kin  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.contacts.noise import MEDIAPIPE_NOISE  # noqa: E402
from physmocap.contacts.predict import predict_contacts  # noqa: E402
from physmocap.dynamics.stage import run_physcap  # noqa: E402
from physmocap.io.atomic import write_text  # noqa: E402
from physmocap.kinematics.refine import refine_kinematics  # noqa: E402
from physmocap.kinematics.stage import fit_motion  # noqa: E402
from physmocap.mocap.bvh_reader import load_mocap  # noqa: E402
from physmocap.mocap.synthetic import landmarks_from_clip, make_observations, random_camera, resample  # noqa: E402
from physmocap.motion import Observations  # noqa: E402

VALIDATION_CLIPS = (
    "cmu_raw_cgspeed/02_01.bvh", "cmu_iclone_cc3_retarget/007_04.bvh", "cmu_iclone_cc3_retarget/002_04.bvh",
    "cmu_iclone_cc3_retarget/005_11.bvh", "cmu_iclone_cc3_retarget/002_06.bvh",
    "cmu_iclone_cc3_retarget/001_01.bvh",
)
HEIGHTS = (1.50, 1.60, 1.85)  # m, standing heights the clips are scaled to for the height part


def tilt_degrees(normal: np.ndarray, true_normal: np.ndarray) -> float:
    cosine = abs(float(np.dot(normal, true_normal))) / (np.linalg.norm(normal) * np.linalg.norm(true_normal))
    return float(np.degrees(np.arccos(min(cosine, 1.0))))


def synthetic_case(name: str, seed: int, height: float | None = None, fps: float = FPS):
    """Observations and truth of one clip filmed at `fps` by one random camera; with `height`, the skeleton is first
    scaled (about the floor point below its first pelvis) to that standing height."""
    clip = first_seconds(resample(load_mocap(MOCAP / name), fps), SECONDS)
    if height is not None:
        factor = height / model_height(landmarks_from_clip(clip))
        anchor = clip.positions[0, 0] * np.array([1.0, 1.0, 0.0])
        clip = dataclasses.replace(clip, positions=anchor + factor * (clip.positions - anchor))
    rng = np.random.default_rng(seed)
    K, R, t = random_camera(clip, rng)
    obs, truth = make_observations(clip, K, R, t, rng, MEDIAPIPE_NOISE)
    return obs, truth


def floor_case(name: str, seed: int, fps: float = FPS) -> dict:
    obs, truth = synthetic_case(name, seed, fps=fps)
    true_normal = truth["floor"][:3]
    settings = Settings().replace("body", height=model_height(truth["landmarks_world"]))
    row = dict(clip=name.split("/")[-1], seed=seed)
    start = time.perf_counter()
    offline = fit_motion(obs, settings)
    row["offline"] = tilt_degrees(offline.floor.normal, true_normal)
    row["offline_confidence"] = _confidence(offline.floor)
    contacts = predict_contacts(obs, "centred")[0]
    refined = refine_kinematics(obs, offline, contacts, settings.fit, settings.trajopt)
    row["refined"] = tilt_degrees(refined.motion.floor.normal, true_normal)
    online = fit_motion(obs, settings.replace(None, online=True))
    row["online_warmup"] = tilt_degrees(online.floor.normal, true_normal)
    row["online_confidence"] = _confidence(online.floor)
    causal, stationary = predict_contacts(obs, "causal")[:2]
    physics = run_physcap(online.body, online.qpos, obs.fps, causal, stationary, settings.physics,
                          refine_floor=True, valid=online.valid)
    plane = physics.floor_plane
    row["online_physics"] = (row["online_warmup"] if plane is None
                             else tilt_degrees(online.camera.R @ plane[:3], true_normal))
    row["seconds"] = time.perf_counter() - start
    return row


def _confidence(floor) -> dict:
    return {k: float(getattr(floor, k)) if isinstance(getattr(floor, k), (float, int, np.floating)) else
            getattr(floor, k) for k in ("inlier_fraction", "tilt_spread", "prior_disagreement", "trusted")
            if hasattr(floor, k)}


def global_root_mm(motion, truth) -> float:
    """Mean distance (mm) of the fitted pelvis from the true one, both in the camera frame."""
    pelvis = motion.camera.to_camera(motion.qpos[:, :3])
    true = truth["joints_world"][:, 0] @ truth["camera_R"].T + truth["camera_t"]
    return float(1000 * np.mean(np.linalg.norm(pelvis - true, axis=1)))


def height_case(name: str, seed: int, height: float) -> dict:
    from physmocap.kinematics.calibration import estimate_height

    obs, truth = synthetic_case(name, seed, height)
    true_height = model_height(truth["landmarks_world"])
    estimate = estimate_height(obs)
    row = dict(clip=name.split("/")[-1], seed=seed, true_height=true_height, estimate=estimate.height,
               estimate_spread=estimate.spread)
    for label, h in (("default", Settings().body.height), ("estimate", estimate.height), ("true", true_height)):
        motion = fit_motion(obs, Settings().replace("body", height=h))
        row[f"global_root_{label}_mm"] = global_root_mm(motion, truth)
    return row


COCO_17 = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
           "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
           "right_knee", "left_ankle", "right_ankle")


def detector_case(name: str, seed: int, landmarks: str) -> dict:
    """The offline kinematic fit of one clip when the detector gives all 33 landmarks, only COCO's 17 (the
    others NaN, as in another detector's observations file), or a random half (NaN): root-relative and global
    errors of the 16 evaluated joints, and the share of frames whose fitted head is above its neck."""
    from physmocap.evaluation import score_against_truth, to_truth_world
    from physmocap.landmarks import LANDMARK_NAMES

    obs, truth = synthetic_case(name, seed)
    if landmarks != "all":
        hidden = ([i for i, n in enumerate(LANDMARK_NAMES) if n not in COCO_17] if landmarks == "coco17"
                  else list(np.random.default_rng(seed).choice(len(LANDMARK_NAMES), 16, replace=False)))
        obs.keypoints_2d[:, hidden] = np.nan
        obs.landmarks_3d[:, hidden] = np.nan
        path = RESULTS / "tmp_observations.npz"
        np.savez(path, keypoints_2d=obs.keypoints_2d, landmarks_3d=obs.landmarks_3d, fps=obs.fps,
                 image_size=np.array(obs.image_size), camera_K=obs.camera_K)
        obs = Observations.load(path)  # as a file from another detector is read
        path.unlink()
    settings = Settings().replace("body", height=model_height(truth["landmarks_world"]))
    motion = fit_motion(obs, settings)
    pose = kin.forward_kinematics(motion.body, motion.qpos)
    points = to_truth_world(pose.points, motion.camera.R, motion.camera.t, truth)
    com = to_truth_world(kin.center_of_mass(motion.body, pose), motion.camera.R, motion.camera.t, truth)
    scores = score_against_truth(points, motion.body.point_names, com, truth, motion.body.mass)
    names = motion.body.point_names
    head_up = float(np.mean(points[:, names.index("head"), 2] > points[:, names.index("neck"), 2]))
    return dict(clip=name.split("/")[-1], seed=seed, landmarks=landmarks, mpjpe_root_mm=scores["mpjpe_root_mm"],
                global_root_mm=scores["global_root_mm"], head_above_neck=head_up,
                finite=bool(np.isfinite(motion.qpos).all()))


def real_floor(paths: list[str]) -> dict:
    """The floor's confidence on real observations files (`physmocap detect VIDEO -o OBS.npz`), offline and
    online, default settings: no truth, only whether the feet and the posture agree."""
    rows = {}
    for path in paths:
        obs = Observations.load(path)
        for online in (False, True):
            floor = fit_motion(obs, Settings().replace(None, online=online)).floor
            rows[f"{Path(path).parent.parent.name or path} {'online' if online else 'offline'}"] = floor.confidence()
            print(path, "online" if online else "offline", floor.confidence(), flush=True)
    return rows


def real_height_scale() -> dict:
    """How metric MediaPipe's 3D landmarks are on real video: on the Pose2Sim demo (4 calibrated views), per view
    the median over the core lengths (CORE_LENGTHS) of MediaPipe's length over the triangulated reference's
    (Qualisys metres), and the height the view's estimate gives."""
    from bench_multiview import CALIBRATION, VIEWS, detect_views, triangulate_reference
    from physmocap.evaluation import EVAL_JOINTS
    from physmocap.kinematics.calibration import CORE_LENGTHS, estimate_height, measure_lengths, seen_landmarks
    from physmocap.landmarks import LANDMARK_INDEX, NUM_LANDMARKS
    from qualisys import read_qualisys_calibration

    cameras = read_qualisys_calibration(CALIBRATION)
    observations = detect_views(Settings())
    reference = triangulate_reference(cameras, observations)
    # The reference's points as a (T, 33, 3) landmark array (NaN where it has none) for measure_lengths.
    as_landmarks = np.full((len(reference.points), NUM_LANDMARKS, 3), np.nan)
    for k, joint in enumerate(EVAL_JOINTS):
        as_landmarks[:, LANDMARK_INDEX[joint.replace("_toe", "_foot_index")]] = reference.points[:, 1 + k]
    truth = measure_lengths(as_landmarks)
    rows = {}
    for view, obs in zip(VIEWS, observations, strict=True):
        measured = measure_lengths(seen_landmarks(obs)[obs.valid])
        ratios = {k: measured[k] / truth[k] for k in CORE_LENGTHS if np.isfinite(truth[k]) and np.isfinite(measured[k])}
        estimate = estimate_height(obs)
        rows[view] = dict(scale=float(np.median(list(ratios.values()))), ratios=ratios, estimate=estimate.height,
                          spread=estimate.spread)
        print(f"{view}: MediaPipe / reference lengths {rows[view]['scale']:.3f} "
              f"({', '.join(f'{k} {v:.2f}' for k, v in ratios.items())}); height estimate {estimate.height:.3f} m",
              flush=True)
    return rows


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--part", choices=("floor", "height", "real-height", "real-floor", "detectors", "both"),
                        default="both")
    parser.add_argument("--set", choices=("validation", "test"), default="test")
    parser.add_argument("--quick", action="store_true", help="three clips, one seed")
    parser.add_argument("--observations", nargs="*", default=[], help="real-floor part: observations files")
    parser.add_argument("--landmarks", default="all,coco17,half", help="detectors part: which landmark sets")
    parser.add_argument("--fps", type=float, default=FPS, help="floor part: the rate the clips are filmed at "
                        "(results file floor_SET_<fps>fps.json where not 30)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    clips = VALIDATION_CLIPS if args.set == "validation" else TEST_CLIPS
    clips = clips[:3] if args.quick else clips
    seeds = (0,) if args.quick else (0, 1)
    out: dict = dict(set=args.set, clips=list(clips), seeds=list(seeds), fps=args.fps, machine=machine_description())
    if args.part in ("floor", "both"):
        rows = []
        for name in clips:
            for seed in seeds:
                row = floor_case(name, seed, args.fps)
                rows.append(row)
                print(f"floor {row['clip']:>10} seed {seed}: offline {row['offline']:5.1f}, refined "
                      f"{row['refined']:5.1f}, online warm-up {row['online_warmup']:5.1f}, online physics "
                      f"{row['online_physics']:5.1f} deg; {row['offline_confidence']}", flush=True)
        out["floor_rows"] = rows
        out["floor_summary"] = {k: dict(median=float(np.median([r[k] for r in rows])),
                                        worst=float(np.max([r[k] for r in rows])))
                                for k in ("offline", "refined", "online_warmup", "online_physics")}
        print(json.dumps(out["floor_summary"], indent=1))
    if args.part in ("height", "both"):
        rows = []
        for name in clips:
            for seed in seeds[:1]:  # one camera per clip: three heights and three fits each
                for height in HEIGHTS:
                    row = height_case(name, seed, height)
                    rows.append(row)
                    print(f"height {row['clip']:>10} seed {seed} true {row['true_height']:.3f} estimate "
                          f"{row['estimate']:.3f} +- {row['estimate_spread']:.3f} m; global root default "
                          f"{row['global_root_default_mm']:.0f}, estimate {row['global_root_estimate_mm']:.0f}, "
                          f"true {row['global_root_true_mm']:.0f} mm", flush=True)
        errors = np.array([r["estimate"] - r["true_height"] for r in rows])
        out["height_rows"] = rows
        out["height_summary"] = dict(
            estimate_error_median_abs_m=float(np.median(np.abs(errors))),
            estimate_error_mean_m=float(errors.mean()), estimate_error_sd_m=float(errors.std()),
            estimate_error_worst_m=float(np.abs(errors).max()),
            **{f"global_root_{k}_mm_median": float(np.median([r[f"global_root_{k}_mm"] for r in rows]))
               for k in ("default", "estimate", "true")})
        print(json.dumps(out["height_summary"], indent=1))
    if args.part == "detectors":
        kinds = tuple(args.landmarks.split(","))
        rows = [detector_case(name, 0, landmarks) for name in clips for landmarks in kinds]
        for row in rows:
            print(row, flush=True)
        out["detector_rows"] = rows
        out["detector_summary"] = {k: {m: float(np.mean([r[m] for r in rows if r["landmarks"] == k]))
                                       for m in ("mpjpe_root_mm", "global_root_mm", "head_above_neck")}
                                   for k in kinds}
        print(json.dumps(out["detector_summary"], indent=1))
    if args.part == "real-floor":
        out["real_floor"] = real_floor(args.observations)
    if args.part == "real-height":
        out["real_height"] = real_height_scale()
    rate = "" if args.fps == FPS else f"_{args.fps:g}fps"
    path = Path(args.json) if args.json else RESULTS / f"{args.part.replace('-', '_')}_{args.set}{rate}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
