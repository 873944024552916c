"""Multi-view real benchmark: the monocular pipeline on each of four calibrated, synchronised views, measured
against the triangulation of all four (issue 4, "Multi-view real"; PhysCap Sec. 5.3, Tables 2 and 3).

Data: the Pose2Sim demo (a man balancing on one leg in a lab, 4 portrait views, 60 fps, 100 frames) with its
Qualisys calibration. Steps:
1. MediaPipe on every view (cached in runs/bench_multiview/camXX/cache/, reused while the videos are unchanged).
2. Reference: the arm and leg labels of each view are checked against the other views (MediaPipe swaps left
   and right in view cam02 for about 0.5 s), then the 16 evaluated landmarks are triangulated by
   confidence-weighted DLT, dropping a view that disagrees by more than 40 px. Pelvis = midpoint of the hips, as
   in the result file.
3. The monocular pipeline on each view with that view's calibrated focal length (the principal point stays at
   the image centre and the person's height at the 1.70 m default, as a user would run it), refitted every run.
4. Per view: 3D errors in that view's camera frame (the reference moved there by the calibration, the result by
   its own camera_R/t, then along the calibrated rays of its pixels): root-relative, Procrustes and global MPJPE
   with PCK@150 mm and AUC, pelvis error; e2D input: the result's joints projected by its own camera against the
   view's own detections with the labels the other views agree on (in the JSON also against the raw
   detections); e2D side: the result taken from the input camera's frame into the Qualisys world by that
   camera's calibration, projected into each of the other three views and compared with the reference's
   projections there (in the JSON also with those views' detections); the angle at the person between the
   input and side cameras (PhysCap requires more than pi/15); fit time per frame.

    .venv/bin/python benchmarks/bench_multiview.py [--physics none|physcap|trajopt]

writes benchmarks/results/multiview.json and multiview.md. Each method is one row; running another method keeps
the rows of the others already in the JSON.
"""

from __future__ import annotations

import physmocap  # noqa: F401 - first: pins BLAS to one thread before numpy loads

# isort: split

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, RESULTS, VIDEOS, git_revision, machine_description  # noqa: E402
from multiview import MEDIAPIPE_SWAP_GROUPS, correct_left_right_swaps, triangulate  # noqa: E402
from physmocap import metrics  # noqa: E402
from physmocap.camera import project_camera_points  # noqa: E402
from physmocap.config import Settings  # noqa: E402
from physmocap.errors import InputError  # noqa: E402
from physmocap.evaluation import EVAL_JOINTS  # noqa: E402
from physmocap.landmarks import LANDMARK_INDEX  # noqa: E402
from physmocap.motion import Observations  # noqa: E402
from physmocap.pipeline import detect_stage, run_capture  # noqa: E402
from physmocap.result import load_result  # noqa: E402
from qualisys import QualisysCamera, read_qualisys_calibration  # noqa: E402

DATA = VIDEOS / "pose2sim_demo_singleperson"
CALIBRATION = DATA / "calibration" / "Calib.qca.txt"
RUNS = REPO / "runs" / "bench_multiview"
VIEWS = ("cam01", "cam02", "cam03", "cam04")
METHOD_NAMES = {"none": "kinematic", "physcap": "physcap", "trajopt": "trajopt"}

MIN_CONFIDENCE = 0.3  # detections below this are ignored by the reference and the 2D errors
OUTLIER_THRESHOLD_PX = 40.0  # a view further than this from the others is dropped for that point (typical: 13 px)
TIMING_REPEATS = 3  # fits per view; the median time is reported (the 2-core machine is shared)
MIN_SIDE_ANGLE = np.pi / 15  # PhysCap 5.3.1: side views at least this far (at the person) from the input view

# Body-model joint -> MediaPipe landmark; the reference and every error use these 16 points.
LANDMARK_OF_JOINT = {joint: joint.replace("_toe", "_foot_index") for joint in EVAL_JOINTS}
REFERENCE_POINTS = ("pelvis",) + EVAL_JOINTS  # index 0: the root of root-relative errors
EVALUATED = list(range(1, len(REFERENCE_POINTS)))


@dataclasses.dataclass
class Reference:
    """points: (T, 17, 3) Qualisys world, metres, in REFERENCE_POINTS order; detections: (V, T, 16, 3) the views'
    keypoints of EVAL_JOINTS, raw and with left/right labels corrected; error: (T, 16) mean reprojection error
    over the views used, px; swapped: (V,) frames in which each view's arm or leg labels were swapped."""

    points: np.ndarray
    raw_detections: np.ndarray
    detections: np.ndarray
    error: np.ndarray
    swapped: np.ndarray


def detect_views(settings: Settings) -> list[Observations]:
    """MediaPipe detections of every view, from the run folders' caches when present."""
    return [detect_stage(DATA / f"{view}.mp4", RUNS / view, settings)[0] for view in VIEWS]


def triangulate_reference(cameras: list[QualisysCamera], observations: list[Observations]) -> Reference:
    """The reference 3D pose from all views' detections (frames a detector rejected count as unseen)."""
    keypoints = np.stack([obs.keypoints_2d for obs in observations])
    for view, obs in enumerate(observations):
        keypoints[view, ~obs.valid, :, 2] = 0.0
    calibration = ([c.K for c in cameras], [c.R for c in cameras], [c.t for c in cameras])
    body_groups = (MEDIAPIPE_SWAP_GROUPS["arms"], MEDIAPIPE_SWAP_GROUPS["legs"])
    corrected, swapped = correct_left_right_swaps(*calibration, keypoints, MIN_CONFIDENCE, groups=body_groups)
    landmarks = [LANDMARK_INDEX[LANDMARK_OF_JOINT[joint]] for joint in EVAL_JOINTS]
    points, error = triangulate(*calibration, corrected[:, :, landmarks], MIN_CONFIDENCE,
                                distortion_list=[c.distortion for c in cameras],
                                outlier_threshold_px=OUTLIER_THRESHOLD_PX)
    hips = [EVAL_JOINTS.index("left_hip"), EVAL_JOINTS.index("right_hip")]
    pelvis = points[:, hips].mean(axis=1, keepdims=True)
    return Reference(np.concatenate([pelvis, points], axis=1), keypoints[:, :, landmarks], corrected[:, :, landmarks],
                     error, swapped.any(axis=2).sum(axis=1))


def settings_for(camera: QualisysCamera, physics: str) -> Settings:
    """Default settings with the view's calibrated focal length (px) and the physics method."""
    return Settings().replace("camera", focal=camera.focal).replace("physics", method=physics).check()


def run_monocular(view: str, settings: Settings) -> tuple[dict, dict[str, float]]:
    """The pipeline on one view, refitted TIMING_REPEATS times (detections cached): the result arrays and the
    median seconds per stage."""
    stage_seconds = []
    for _ in range(TIMING_REPEATS):
        (RUNS / view / "cache" / "kinematics.npz").unlink(missing_ok=True)
        summary = run_capture(RUNS / view, settings, video=DATA / f"{view}.mp4", overlay=False)
        stage_seconds.append(summary.stage_seconds)
    result = load_result(summary.files["result"])
    if str(result["physics"]) != settings.physics.method:
        raise SystemExit(f"the pipeline ran physics {str(result['physics'])!r}, not {settings.physics.method!r}")
    return result, {stage: float(np.median([s[stage] for s in stage_seconds])) for stage in stage_seconds[0]}


def to_camera(points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(..., 3) world points -> camera frame, x_cam = R x + t."""
    return points @ R.T + t


LIMBS = tuple((f"{side}_{a}", f"{side}_{b}") for side in ("left", "right") for a, b in (
    ("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle")))


def limb_length_ratio(predicted: np.ndarray, truth: np.ndarray) -> float:
    """Mean length of the upper and lower arms and legs, predicted over reference: the body's scale error, which
    the monocular depth inherits. predicted, truth: (T, 17, 3) in REFERENCE_POINTS order."""
    pairs = np.array([[REFERENCE_POINTS.index(a), REFERENCE_POINTS.index(b)] for a, b in LIMBS])

    def mean_length(points: np.ndarray) -> float:
        return float(np.linalg.norm(points[:, pairs[:, 0]] - points[:, pairs[:, 1]], axis=-1).mean())

    return mean_length(predicted) / mean_length(truth)


def viewing_angle(person: np.ndarray, first: QualisysCamera, second: QualisysCamera) -> float:
    """Angle at the (3,) person position between the directions to two camera centres, radians."""
    a, b = first.centre - person, second.centre - person
    return float(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))


def floor_against_lab(camera: QualisysCamera, result: dict) -> dict:
    """The result's floor against the lab's (the Qualisys world's z = 0, in the calibrated camera's frame): the
    angle between the two normals, how far down each has the camera looking and its height above each floor
    (the depth scale's error shows there), and whether the run trusted its floor."""
    up_true, up_ours = camera.R[:, 2], result["camera_R"][:, 2]  # the floor's normal in the camera frame
    looks_down = (float(np.degrees(np.arcsin(-up[2]))) for up in (up_true, up_ours))  # camera z: forward
    return dict(floor_tilt_error_deg=float(np.degrees(np.arccos(np.clip(up_true @ up_ours, -1.0, 1.0)))),
                camera_looks_down_true_deg=next(looks_down), camera_looks_down_deg=next(looks_down),
                camera_height_true_m=float(-up_true @ camera.t), camera_height_m=float(-up_ours @ result["camera_t"]),
                floor_trusted=bool(result["floor_trusted"]))


def evaluate_view(view: int, cameras: list[QualisysCamera], reference: Reference, result: dict,
                  stage_seconds: dict[str, float]) -> dict:
    """All numbers of one input view; distances in mm, pixels in px, angles in degrees."""
    camera = cameras[view]
    names = [str(n) for n in result["joint_names"]]
    predicted_world = result["joints_world"][:, [names.index(n) for n in REFERENCE_POINTS]]
    frames = result["valid"] & np.isfinite(reference.points).all(axis=(1, 2))
    # The result's camera has the principal point at the image centre, the calibrated one does not (up to 31 px
    # away here). Each predicted point goes along the calibrated ray of the pixel where the result sees it, at the
    # same depth: x_calibrated = K_calibrated^-1 K_result x_result. Without this, the side views would charge
    # the monocular result for the principal point (about 6 cm at 3.4 m) on top of its depth and lean errors.
    to_calibrated_rays = np.linalg.solve(camera.K, result["camera_K"])
    predicted = to_camera(predicted_world, result["camera_R"], result["camera_t"])[frames] @ to_calibrated_rays.T
    truth = to_camera(reference.points, camera.R, camera.t)[frames]  # the same camera, calibrated

    row: dict[str, object] = {"camera": VIEWS[view], "focal_px": camera.focal, "frames": int(frames.sum()),
                              "reference_distance_m": float(np.median(truth[:, 0, 2]))}
    for label, align in (("root_relative", "root"), ("procrustes", "procrustes"), ("global", "none")):
        row[f"mpjpe_{label}_mm"] = 1000 * metrics.mpjpe(predicted, truth, align, joints=EVALUATED)
        row[f"pck150_{label}"] = metrics.pck(predicted, truth, align=align, joints=EVALUATED)
        row[f"auc_{label}"] = metrics.auc(predicted, truth, align=align, joints=EVALUATED)
    row["limb_length_ratio"] = limb_length_ratio(predicted, truth)
    root_error = predicted[:, 0] - truth[:, 0]
    row["root_error_mm"] = 1000 * float(np.linalg.norm(root_error, axis=-1).mean())
    row["root_depth_error_mm"] = 1000 * float(np.abs(root_error[:, 2]).mean())
    row["root_depth_bias_mm"] = 1000 * float(root_error[:, 2].mean())

    # Against the view's own detections with the labels the other views agree on (PhysCap compares with true 2D
    # joints; where a view's raw labels are swapped, a perfect result would be charged the swap), and against the
    # raw detections the fit saw.
    projection = (predicted_world[frames][:, EVALUATED], result["camera_K"], result["camera_R"], result["camera_t"])
    row["e2d_input_px"], row["e2d_input_sd_px"] = metrics.reprojection_error(
        *projection, reference.detections[view][frames], MIN_CONFIDENCE)
    row["e2d_input_vs_raw_detections_px"], row["e2d_input_vs_raw_detections_sd_px"] = metrics.reprojection_error(
        *projection, reference.raw_detections[view][frames], MIN_CONFIDENCE)

    # The input camera's calibration takes its camera frame into the Qualisys world.
    predicted_qualisys = (predicted[:, EVALUATED] - camera.t) @ camera.R
    sides = []
    for side in range(len(cameras)):
        if side == view:
            continue
        other = cameras[side]
        reference_pixels = project_camera_points(other.K, to_camera(reference.points[frames][:, EVALUATED],
                                                                    other.R, other.t))
        e_side, sd_side = metrics.reprojection_error(predicted_qualisys, other.K, other.R, other.t, reference_pixels)
        e_det, sd_det = metrics.reprojection_error(predicted_qualisys, other.K, other.R, other.t,
                                                   reference.detections[side][frames], MIN_CONFIDENCE)
        angle = viewing_angle(np.median(reference.points[frames][:, 0], axis=0), camera, other)
        sides.append({"camera": VIEWS[side], "angle_deg": float(np.degrees(angle)),
                      "angle_ok": bool(angle > MIN_SIDE_ANGLE), "e2d_side_px": e_side, "e2d_side_sd_px": sd_side,
                      "e2d_side_vs_detections_px": e_det, "e2d_side_vs_detections_sd_px": sd_det})
    row["sides"] = sides
    for key in ("e2d_side_px", "e2d_side_sd_px", "e2d_side_vs_detections_px", "e2d_side_vs_detections_sd_px"):
        row[key] = float(np.mean([s[key] for s in sides]))
    frames_total = len(result["valid"])
    row.update(floor_against_lab(camera, result))
    row["ms_per_frame"] = {stage: 1000 * seconds / frames_total for stage, seconds in stage_seconds.items()
                           if stage not in ("detect", "outputs")}
    row["fit_ms_per_frame"] = row["ms_per_frame"]["kinematics"]
    return row


MEAN_KEYS = ("mpjpe_root_relative_mm", "pck150_root_relative", "auc_root_relative", "mpjpe_procrustes_mm",
             "pck150_procrustes", "auc_procrustes", "mpjpe_global_mm", "pck150_global", "auc_global", "root_error_mm",
             "root_depth_error_mm", "root_depth_bias_mm", "limb_length_ratio", "e2d_input_px", "e2d_input_sd_px",
             "e2d_input_vs_raw_detections_px", "e2d_input_vs_raw_detections_sd_px", "e2d_side_px", "e2d_side_sd_px",
             "e2d_side_vs_detections_px", "e2d_side_vs_detections_sd_px", "fit_ms_per_frame")


def reference_summary(cameras: list[QualisysCamera], reference: Reference) -> dict:
    """How well the reference agrees with each view's (label-corrected) detections, px."""
    views = {}
    for view, camera in enumerate(cameras):
        seen = np.isfinite(reference.points[:, 1:]).all(axis=-1)
        detections = np.where(seen[..., None], reference.detections[view], 0.0)  # unseen points: confidence 0
        points = np.where(seen[..., None], reference.points[:, 1:], 0.0)
        mean, sd = metrics.reprojection_error(points, camera.K, camera.R, camera.t, detections, MIN_CONFIDENCE)
        used = seen & (detections[..., 2] > MIN_CONFIDENCE)
        offset = (camera.camera().project(points) - detections[..., :2])[used].mean(axis=0)
        views[VIEWS[view]] = {"reprojection_px": mean, "reprojection_sd_px": sd, "mean_offset_px": offset.tolist(),
                              "frames_with_swapped_labels": int(reference.swapped[view])}
    return {"views": views, "median_point_error_px": float(np.nanmedian(reference.error)),
            "frames": int(np.isfinite(reference.points).all(axis=(1, 2)).sum())}


def markdown(report: dict) -> str:
    """The results file: tables with the methods as rows."""
    methods = report["methods"]
    out = [
        "# Multi-view real benchmark (Pose2Sim demo, 4 calibrated views)", "",
        f"Command: `{report['command']}` (one method per run; rows of other methods are kept). "
        f"Git {report['git']}; {report['machine']}; {report['date']}; load average {report['load_average']:.1f} "
        "at the start (timings are slower when other work shares the cores).", "",
        "Reference: MediaPipe detections of all four views, left/right labels made consistent across views, "
        "triangulated by confidence-weighted DLT (a view more than "
        f"{OUTLIER_THRESHOLD_PX:.0f} px off is dropped for that point); 16 joints (shoulders, elbows, wrists, hips, "
        "knees, ankles, heels, toes), pelvis = midpoint of the hips. Each row is the monocular pipeline run on one "
        "view at a time with that view's calibrated focal length, averaged over the four views. 3D errors are in "
        "the input camera's frame. e2D input: against the view's own detections, left/right labels as the other "
        "views agree. e2D side: the result taken into the calibrated world through the input camera's "
        "extrinsics and projected into the other three views, against the reference's projections there. Image "
        "size 1080 (or 1088) x 1920 px.", "",
        "## 3D joint error against the reference (PhysCap Table 2 layout), mean of the four input views", "",
        "| method | root-rel. MPJPE mm | PCK@150 % | AUC % | Procrustes MPJPE mm | PCK % | AUC % "
        "| global MPJPE mm | PCK % | AUC % | pelvis error mm | pelvis depth error mm |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, method in methods.items():
        m = method["mean"]
        out.append(f"| {name} | {m['mpjpe_root_relative_mm']:.1f} | {m['pck150_root_relative']:.1f} | "
                   f"{m['auc_root_relative']:.1f} | {m['mpjpe_procrustes_mm']:.1f} | {m['pck150_procrustes']:.1f} | "
                   f"{m['auc_procrustes']:.1f} | {m['mpjpe_global_mm']:.1f} | {m['pck150_global']:.1f} | "
                   f"{m['auc_global']:.1f} | {m['root_error_mm']:.1f} | {m['root_depth_error_mm']:.1f} |")
    out += ["", "## 2D reprojection (PhysCap Table 3 layout), mean of the four input views", "",
            "| method | e2D input px | sigma input | e2D input vs raw detections px (sigma) | e2D side px | sigma side "
            "| fit ms/frame |", "|---|---|---|---|---|---|---|"]
    for name, method in methods.items():
        m = method["mean"]
        out.append(f"| {name} | {m['e2d_input_px']:.1f} | {m['e2d_input_sd_px']:.1f} | "
                   f"{m['e2d_input_vs_raw_detections_px']:.1f} ({m['e2d_input_vs_raw_detections_sd_px']:.1f}) | "
                   f"{m['e2d_side_px']:.1f} | {m['e2d_side_sd_px']:.1f} | {m['fit_ms_per_frame']:.1f} |")
    out += ["", "## Per input view", "",
            "| method | view | focal px | distance m | root-rel. mm | Procrustes mm | global mm | pelvis mm "
            "| pelvis depth bias mm | limb length ratio | e2D input px (sigma) | e2D side px (sigma) "
            "| side views: angle deg, e2D px | fit ms/frame |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, method in methods.items():
        for row in method["views"].values():
            sides = ", ".join(f"{s['camera']} {s['angle_deg']:.0f}: {s['e2d_side_px']:.0f}" for s in row["sides"])
            out.append(
                f"| {name} | {row['camera']} | {row['focal_px']:.0f} | {row['reference_distance_m']:.2f} | "
                f"{row['mpjpe_root_relative_mm']:.1f} | {row['mpjpe_procrustes_mm']:.1f} | "
                f"{row['mpjpe_global_mm']:.1f} | {row['root_error_mm']:.1f} | {row['root_depth_bias_mm']:+.0f} | "
                f"{row['limb_length_ratio']:.2f} | {row['e2d_input_px']:.1f} ({row['e2d_input_sd_px']:.1f}) | "
                f"{row['e2d_side_px']:.1f} ({row['e2d_side_sd_px']:.1f}) | {sides} | {row['fit_ms_per_frame']:.1f} |")
    out += ["", "## The floor against the lab's (the calibration's z = 0)", "",
            "| method | view | floor tilt error deg | camera looks down deg (true) | camera height m (true) | "
            "floor trusted |", "|---|---|---|---|---|---|"]
    for name, method in methods.items():
        for row in method["views"].values():
            if "floor_tilt_error_deg" in row:  # rows of runs before this part kept none
                out.append(f"| {name} | {row['camera']} | {row['floor_tilt_error_deg']:.1f} | "
                           f"{row['camera_looks_down_deg']:.1f} ({row['camera_looks_down_true_deg']:.1f}) | "
                           f"{row['camera_height_m']:.2f} ({row['camera_height_true_m']:.2f}) | "
                           f"{row['floor_trusted']} |")
    ref = report["reference"]
    out += ["", "## The reference itself", "",
            f"{ref['frames']} frames; median reprojection error of a triangulated point "
            f"{ref['median_point_error_px']:.1f} px, the floor of any e2D measured against detections. Most of it "
            "is a shift of each view's landmarks as a whole (mean offset below), the same for every joint; the "
            "calibration itself projects the world origin onto the same force-plate corner in all four views "
            "within about 10 px, and refining the camera rotations on the landmarks moves it 15-25 px off that "
            "corner, so the landmarks are not used to correct the calibration.", "",
            "| view | reprojection px (sigma) | mean offset projected - detected (x, y) px "
            "| frames with arm or leg labels swapped |", "|---|---|---|---|"]
    for view, numbers in ref["views"].items():
        dx, dy = numbers["mean_offset_px"]
        out.append(f"| {view} | {numbers['reprojection_px']:.1f} ({numbers['reprojection_sd_px']:.1f}) | "
                   f"({dx:+.1f}, {dy:+.1f}) | {numbers['frames_with_swapped_labels']} |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--physics", choices=tuple(METHOD_NAMES), default="none",
                        help="physics after the kinematic fit; each method is one row of the tables")
    parser.add_argument("--json", type=Path, default=RESULTS / "multiview.json")
    parser.add_argument("--markdown", type=Path, default=RESULTS / "multiview.md")
    args = parser.parse_args(argv)

    started = time.perf_counter()
    load_average = os.getloadavg()[0]  # other work on the machine slows the timings
    cameras = read_qualisys_calibration(CALIBRATION)
    try:
        settings = [settings_for(camera, args.physics) for camera in cameras]
    except InputError as exc:
        raise SystemExit(f"--physics {args.physics}: {exc}") from None
    reference = triangulate_reference(cameras, detect_views(settings[0]))
    print(f"reference: {time.perf_counter() - started:.1f} s", flush=True)

    rows = {}
    for view in range(len(cameras)):
        result, stage_seconds = run_monocular(VIEWS[view], settings[view])
        rows[VIEWS[view]] = row = evaluate_view(view, cameras, reference, result, stage_seconds)
        print(f"{VIEWS[view]}: root-relative {row['mpjpe_root_relative_mm']:.1f} mm, Procrustes "
              f"{row['mpjpe_procrustes_mm']:.1f} mm, global {row['mpjpe_global_mm']:.1f} mm, e2D input "
              f"{row['e2d_input_px']:.1f} px, side {row['e2d_side_px']:.1f} px, fit {row['fit_ms_per_frame']:.1f} "
              "ms/frame", flush=True)

    report = json.loads(args.json.read_text()) if args.json.is_file() else {"methods": {}}
    report.update(command=f".venv/bin/python benchmarks/bench_multiview.py --physics {args.physics}",
                  git=git_revision(), machine=machine_description(), date=time.strftime("%Y-%m-%d"),
                  load_average=load_average,
                  reference=reference_summary(cameras, reference), min_confidence=MIN_CONFIDENCE,
                  outlier_threshold_px=OUTLIER_THRESHOLD_PX)
    report["methods"][METHOD_NAMES[args.physics]] = {
        "physics": args.physics, "settings": settings[0].replace("camera", focal=None).as_dict(),  # focal: per view
        "views": rows, "mean": {key: float(np.mean([row[key] for row in rows.values()])) for key in MEAN_KEYS}}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    args.markdown.write_text(markdown(report))
    print(f"wrote {args.json} and {args.markdown} in {time.perf_counter() - started:.0f} s")
    return report


if __name__ == "__main__":
    main()
