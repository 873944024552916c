"""Measure MediaPipe Pose's errors on the shared real videos and print them as a `NoiseModel`.

The numbers in `physmocap.contacts.noise.MEDIAPIPE_NOISE` come from this script. Usage:

    .venv/bin/python scripts/measure_mediapipe_noise.py [--cache runs/contacts/detections] [--json OUT.json]

Detections (MediaPipe Pose, model_complexity 1, smoothing on, frames scaled to 640 px wide: the pipeline's
settings) are cached in --cache. What is measured, and how:

- Person height in pixels (the unit of every 2D error, as in `NoiseModel`): per video, the 90th percentile over
  frames of (lowest heel or toe y - highest eye y) / 0.936 (eye height is 93.6 % of stature, de Leva 1996).
- White 2D jitter (keypoint_sd): second differences d2 = x[t+1] - 2 x[t] + x[t-1] of every keypoint coordinate,
  over triples of frames where the keypoint's confidence is at least 0.5, in person heights; for white noise of
  SD s, d2 has SD sqrt(6) s. The robust SD (1.4826 x median absolute deviation) ignores fast true motion.
  Pooled over all videos and landmarks; per landmark the same gives the spread of `landmark_scale`.
- Total 2D error and its slowly varying part (keypoint_drift_sd, keypoint_drift_seconds): on the four
  calibrated, synchronised Pose2Sim views, each keypoint is triangulated from the four views (linear DLT) and
  reprojected; the residuals, scaled by sqrt(8 / 5) for the three degrees of freedom the triangulation absorbs
  out of eight measurements, are the detector's total error (robust SD per landmark from the median residual
  length). Residuals over 0.1 person heights are gross errors (counted, left out). The rest splits into a
  static part (each view's and landmark's median over time: joint-definition bias and the calibration's own
  inconsistency, which move no keypoint between frames) and a time-varying part; the drift is the varying part
  less the white part, drift_sd = sqrt(varying^2 - white^2), with the time scale where the varying part's
  autocorrelation falls to 1/e. Cross-check: the spread of the heel and toe keypoints of feet that the hand
  labels (benchmarks/labels/contacts_real.toml) mark as planted for 8 frames or more.
- Confidence (confidence_mean, confidence_sd): mean and SD of the visibility of keypoints with visibility >= 0.5.
- Dropouts: an episode is a run of frames where a keypoint's visibility is under 0.5; dropout_per_second is the
  number of episodes per keypoint per second of video, dropout_seconds their mean length, dropout_confidence twice
  the mean visibility inside them (the model draws it uniform in [0, dropout_confidence]). dropout_keypoint_sd and
  dropout_landmark_sd are the white jitter (as above, 2D and 3D) of keypoints inside episodes, less the white
  jitter outside, in quadrature.
- Left/right foot confusions: between consecutive valid frames, the three left foot keypoints (ankle, heel, toe)
  and the three right ones are matched to the previous frame's; a swap is counted where the crossed match is
  shorter than half the straight one and the feet are at least 0.1 person heights apart (legs passing each other
  are not swaps). foot_swaps_per_second counts swap starts per second; foot_swap_seconds is the mean time until
  the feet swap back (capped at 1 s).
- 3D landmarks: white jitter (landmark_sd) as for 2D, in metres, on landmarks_3d, for x, y (image plane) and z
  (depth) separately. Total error on the Pose2Sim views: the triangulated 3D points, hip-centred and rotated into
  each camera's axes, against that view's landmarks_3d after a least-squares scale (MediaPipe's 3D is metric only
  roughly); split into static and varying parts as in 2D (errors over 3 robust SDs left out);
  landmark_drift_sd = sqrt(varying^2 - white^2) over x and y. Depth: per frame the least-squares factor
  between the landmarks' and the triangulation's z (hip-centred): depth_scale_sd is the RMS of (factor - 1),
  depth_scale_seconds the 1/e time of its autocorrelation.
- Correlation along the body (keypoint_drift_length, landmark_drift_length): the time-varying parts of two
  landmarks' errors (gross errors left out as above; pooled over views, frames and the image's x and y) correlate
  the more the nearer the landmarks are along the skeleton (`skeleton_distances` of the triangulated points, in
  person heights). The length is the least-squares fit of exp(-distance / length) to the correlations of every
  pair; in 3D the hips are left out, which hip-centring makes mirror each other.
"""

from __future__ import annotations

import argparse
import json
import xml.etree.ElementTree as ET
from dataclasses import asdict
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import numpy as np
from scipy.optimize import minimize_scalar

from physmocap.contacts.real_videos import REAL_VIDEOS, cached_detection, load_real_labels
from physmocap.landmarks import LANDMARK_INDEX, LANDMARK_NAMES, NUM_LANDMARKS
from physmocap.mocap.synthetic import NoiseModel, skeleton_distances
from physmocap.motion import Observations

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
VIDEOS = SHARED / "data" / "videos"
LABELS = REPO / "benchmarks" / "labels" / "contacts_real.toml"
MIN_PLANTED_FRAMES = 8
POSE2SIM_CALIBRATION = VIDEOS / "pose2sim_demo_singleperson" / "calibration" / "Calib.qca.txt"
SEEN = 0.5  # visibility at and above which a keypoint counts as seen
EYE_HEIGHT_FRACTION = 0.936
ROBUST_SD = 1.4826  # SD / MAD of a Gaussian
RAYLEIGH_MEDIAN = 1.1774  # median length / per-coordinate SD of a 2D Gaussian error
GROSS_ERROR = 0.1  # person heights: a 2D error beyond this is a gross failure (a swap, a limb mistaken)
FEET = ("ankle", "heel", "foot_index")
MIN_FEET_APART = 0.1  # person heights
MAX_SWAP_SECONDS = 1.0


def robust_sd(values: np.ndarray) -> float:
    values = values[np.isfinite(values)]
    return float(ROBUST_SD * np.median(np.abs(values - np.median(values))))


def person_height_pixels(obs: Observations) -> float:
    """Person height in pixels: 90th percentile of (lowest foot point - highest eye) / EYE_HEIGHT_FRACTION."""
    xy = obs.keypoints_2d[obs.valid, :, :2]
    feet = [LANDMARK_INDEX[f"{side}_{part}"] for side in ("left", "right") for part in ("heel", "foot_index")]
    eyes = [LANDMARK_INDEX["left_eye"], LANDMARK_INDEX["right_eye"]]
    return float(np.percentile(xy[:, feet, 1].max(axis=1) - xy[:, eyes, 1].min(axis=1), 90) / EYE_HEIGHT_FRACTION)


def second_differences(values: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """d2 (T-2, K, C) of values (T, K, C), nan where any of the three frames is not usable (T, K)."""
    d2 = values[2:] - 2.0 * values[1:-1] + values[:-2]
    ok = usable[2:] & usable[1:-1] & usable[:-2]
    return np.where(ok[..., None], d2, np.nan)


def autocorrelation_seconds(series: np.ndarray, fps: float) -> float:
    """Lag (s) where the mean autocorrelation of the columns of series (T, N) first falls under 1/e."""
    centred = series - np.nanmean(series, axis=0)
    centred = np.nan_to_num(centred)
    variance = (centred**2).sum()
    for lag in range(1, len(series)):
        if (centred[lag:] * centred[:-lag]).sum() / variance < np.exp(-1.0):
            return lag / fps
    return len(series) / fps


def episodes(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) frame ranges of the runs of True in a 1D mask."""
    padded = np.concatenate([[False], mask, [False]]).astype(int)
    changes = np.flatnonzero(np.diff(padded))
    return list(zip(changes[::2], changes[1::2]))


def foot_swaps(obs: Observations, height: float) -> list[float]:
    """Durations (s) of the left/right foot swap episodes found by frame-to-frame matching."""
    left = [LANDMARK_INDEX[f"left_{p}"] for p in FEET]
    right = [LANDMARK_INDEX[f"right_{p}"] for p in FEET]
    xy = obs.keypoints_2d[..., :2] / height
    swapped, start, durations = False, 0, []
    for t in range(1, obs.num_frames):
        if not (obs.valid[t] and obs.valid[t - 1]):
            continue
        straight = np.linalg.norm(xy[t, left] - xy[t - 1, left], axis=1).sum() + np.linalg.norm(
            xy[t, right] - xy[t - 1, right], axis=1).sum()
        crossed = np.linalg.norm(xy[t, left] - xy[t - 1, right], axis=1).sum() + np.linalg.norm(
            xy[t, right] - xy[t - 1, left], axis=1).sum()
        apart = np.linalg.norm(xy[t, left].mean(axis=0) - xy[t, right].mean(axis=0))
        if crossed < 0.5 * straight and apart > MIN_FEET_APART:
            if not swapped:
                swapped, start = True, t
            else:
                swapped = False
                durations.append((t - start) / obs.fps)
        elif swapped and (t - start) / obs.fps >= MAX_SWAP_SECONDS:
            swapped = False
            durations.append(MAX_SWAP_SECONDS)
    if swapped:
        durations.append(min((obs.num_frames - start) / obs.fps, MAX_SWAP_SECONDS))
    return durations


# ------------------------------------------------------------------------------------------------------------
# Pose2Sim multi-view reference


def pose2sim_cameras() -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """K (3, 3), R (3, 3), t (3,) (world -> camera, metres) of the four Pose2Sim views, from the Qualisys file.

    Qualisys stores intrinsics in 1/64 sensor pixels relative to the sensor origin (fov_video gives the video's
    crop) and, per camera, its position (mm) and a rotation whose rows, with y and z negated, are the OpenCV
    camera axes in world coordinates; this reading reprojects the four views' keypoints with a median residual
    of about 15 px (of a person about 1100 px tall), the seven other sign conventions with 80-320 px.
    """
    cameras = []
    for tag in ET.parse(POSE2SIM_CALIBRATION).getroot().findall("cameras/camera"):
        intrinsic, transform, fov = tag.find("intrinsic").attrib, tag.find("transform").attrib, tag.find("fov_video").attrib
        K = np.array([
            [float(intrinsic["focalLengthU"]) / 64, 0.0, float(intrinsic["centerPointU"]) / 64 - float(fov["left"])],
            [0.0, float(intrinsic["focalLengthV"]) / 64, float(intrinsic["centerPointV"]) / 64 - float(fov["top"])],
            [0.0, 0.0, 1.0],
        ])
        rotation = np.array([[float(transform[f"r{a}{b}"]) for b in "123"] for a in "123"])
        position = np.array([float(transform[axis]) for axis in "xyz"]) / 1000.0
        R = np.diag([1.0, -1.0, -1.0]) @ rotation
        cameras.append((K, R, -R @ position))
    return cameras


def triangulate(projections: list[np.ndarray], pixels: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation. projections: V of (3, 4). pixels: (V, T, K, 2). Returns (T, K, 3)."""
    rows = []
    for P, xy in zip(projections, pixels):
        rows.append(xy[..., 0:1] * P[2] - P[0])
        rows.append(xy[..., 1:2] * P[2] - P[1])
    A = np.stack(rows, axis=-2)  # (T, K, 2V, 4)
    solution = np.linalg.svd(A)[2][..., -1, :]
    return solution[..., :3] / solution[..., 3:]


def multiview_errors(views: list[Observations]) -> dict[str, object]:
    """Total 2D and 3D errors of the four Pose2Sim views against their triangulation (see the module doc)."""
    cameras = pose2sim_cameras()
    projections = [K @ np.hstack([R, t[:, None]]) for K, R, t in cameras]
    pixels = np.stack([v.keypoints_2d[..., :2] for v in views])
    points = triangulate(projections, pixels)
    fps = views[0].fps
    hips = 0.5 * (points[:, LANDMARK_INDEX["left_hip"]] + points[:, LANDMARK_INDEX["right_hip"]])
    stature = np.percentile(np.linalg.norm(points[:, LANDMARK_INDEX["left_eye"]] - 0.5 * (
        points[:, LANDMARK_INDEX["left_heel"]] + points[:, LANDMARK_INDEX["right_heel"]]), axis=-1), 90) / EYE_HEIGHT_FRACTION
    residuals_2d, errors_3d, depth_factors = [], [], []
    for (K, R, t), view in zip(cameras, views):
        camera_points = points @ R.T + t
        reprojected = (camera_points @ K.T)[..., :2] / camera_points[..., 2:]
        person_pixels = K[1, 1] * stature / (hips @ R.T + t)[:, 2]
        residuals_2d.append((view.keypoints_2d[..., :2] - reprojected) / person_pixels[:, None, None])
        truth = (points - hips[:, None]) @ R.T
        seen = view.landmarks_3d
        scale = (seen[..., :2] * truth[..., :2]).sum() / (seen[..., :2] ** 2).sum()
        errors_3d.append(scale * seen - truth)
        depth_factors.append((scale * seen[..., 2] * truth[..., 2]).sum(axis=1) / (truth[..., 2] ** 2).sum(axis=1))
    residuals_2d = np.stack(residuals_2d) * np.sqrt(8.0 / 5.0)  # (V, T, K, 2)
    errors_3d = np.stack(errors_3d)
    depth_factors = np.stack(depth_factors)  # (V, T)
    # Robust SDs per coordinate: the median of a 2D Gaussian error's length is 1.1774 SD.
    norms = np.linalg.norm(residuals_2d, axis=-1)
    total_2d_per_landmark = np.median(norms, axis=(0, 1)) / RAYLEIGH_MEDIAN
    gross = norms > GROSS_ERROR
    kept_2d = np.where(gross[..., None], np.nan, residuals_2d)
    static_2d, varying_2d = split_static(kept_2d)
    total_3d_xy = robust_sd(errors_3d[..., :2])
    kept_3d = np.where(np.abs(errors_3d) > 3 * total_3d_xy, np.nan, errors_3d)
    static_3d, varying_3d = split_static(kept_3d)
    distances = skeleton_distances(points, stature)
    return dict(
        stature_m=float(stature),
        total_2d=float(np.median(total_2d_per_landmark)),
        total_2d_per_landmark=total_2d_per_landmark,
        gross_2d_fraction=float(np.mean(gross)),
        static_2d=robust_sd(static_2d),
        varying_2d=robust_sd(varying_2d),
        drift_length_2d=correlation_length((kept_2d - static_2d)[..., :2], distances),
        varying_seconds_2d=autocorrelation_seconds(varying_2d.transpose(1, 0, 2, 3).reshape(len(points), -1), fps),
        total_3d_xy=total_3d_xy,
        total_3d_z=robust_sd(errors_3d[..., 2]),
        static_3d_xy=robust_sd(static_3d[..., :2]),
        varying_3d_xy=robust_sd(varying_3d[..., :2]),
        varying_3d_z=robust_sd(varying_3d[..., 2]),
        drift_length_3d=correlation_length((kept_3d - static_3d)[..., :2], distances, ("left_hip", "right_hip")),
        varying_seconds_3d=autocorrelation_seconds(varying_3d.transpose(1, 0, 2, 3).reshape(len(points), -1), fps),
        depth_factor_median=float(np.median(depth_factors)),
        depth_scale_sd=robust_sd(depth_factors - np.median(depth_factors, axis=1, keepdims=True)),
        depth_scale_seconds=autocorrelation_seconds(np.clip(depth_factors.T, 0.0, 2.0), fps),
        median_reprojection_px=float(np.median(norms) / np.sqrt(8.0 / 5.0)),
    )


def correlation_length(varying: np.ndarray, distances: np.ndarray, left_out: tuple[str, ...] = ()) -> float:
    """Person heights: the length L for which exp(-distance / L) fits (least squares) the correlations between
    landmarks' errors `varying` (V, T, K, C, nan where left out) over the pairs of landmarks `distances` (K, K)
    apart (landmarks named in `left_out` excluded)."""
    samples = varying.transpose(2, 0, 1, 3).reshape(varying.shape[2], -1)
    kept = [k for k, name in enumerate(LANDMARK_NAMES) if name not in left_out]
    pairs = [(i, j) for n, i in enumerate(kept) for j in kept[n + 1:]]
    correlation, distance = [], []
    for i, j in pairs:
        both = np.isfinite(samples[i]) & np.isfinite(samples[j])
        correlation.append(np.corrcoef(samples[i, both], samples[j, both])[0, 1])
        distance.append(distances[i, j])
    correlation, distance = np.array(correlation), np.array(distance)
    misfit = lambda length: float(np.mean((correlation - np.exp(-distance / length)) ** 2))  # noqa: E731
    return float(minimize_scalar(misfit, bounds=(1e-3, 1.0), method="bounded").x)


def split_static(errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split errors (V, T, K, C) (nan where left out) into each view's and landmark's median over time (the
    static bias, (V, 1, K, C)) and the rest (time-varying, with nan as 0 so that autocorrelations can run)."""
    static = np.nanmedian(errors, axis=1, keepdims=True)
    return static, np.nan_to_num(errors - static)


def planted_foot_spread(detections: dict[str, Observations]) -> dict[str, float]:
    """Spread of the foot keypoints while the foot is planted, from the hand labels: within every run of at least
    MIN_PLANTED_FRAMES consecutive labelled contact frames of a site, the deviation of its keypoint (heel or
    foot index) from the run's median, in person heights. A planted foot does not move, so this is the
    detector's time-varying error during real motion (foot swaps included, hence the robust SD)."""
    labels = load_real_labels(LABELS)
    keypoints = [LANDMARK_INDEX[name] for name in ("left_heel", "left_foot_index", "right_heel", "right_foot_index")]
    deviations = []
    for name, label in labels.items():
        obs = detections[name]
        height = person_height_pixels(obs)
        for column, keypoint in enumerate(keypoints):
            frames = label.frames[label.contacts[:, column] == 1]
            for run in np.split(frames, np.flatnonzero(np.diff(frames) != 1) + 1):
                if len(run) >= MIN_PLANTED_FRAMES and obs.valid[run].all():
                    xy = obs.keypoints_2d[run, keypoint, :2] / height
                    deviations.append(xy - np.median(xy, axis=0))
    spread = np.concatenate(deviations)
    return dict(runs=len(deviations), frames=len(spread), robust_sd=robust_sd(spread),
                beyond_0_1=float(np.mean(np.linalg.norm(spread, axis=1) > GROSS_ERROR)))


def measure(cache_dir: Path) -> tuple[NoiseModel, dict[str, object]]:
    """Measure every kind of error on the shared videos. Returns the fitted NoiseModel and the raw numbers."""
    detections = {video.name: cached_detection(video, VIDEOS, cache_dir) for video in REAL_VIDEOS}
    d2_2d, d2_2d_dropout, d2_3d, d2_3d_dropout, visible, swap_durations = [], [], [], [], [], []
    dropout_lengths, dropout_visibility = [], []
    seconds_total = 0.0
    per_video = {}
    for name, obs in detections.items():
        height = person_height_pixels(obs)
        confidence = obs.keypoints_2d[..., 2]
        seen = (confidence >= SEEN) & obs.valid[:, None]
        low = (confidence < SEEN) & obs.valid[:, None]
        d2_2d.append((second_differences(obs.keypoints_2d[..., :2] / height, seen)).reshape(-1, NUM_LANDMARKS, 2))
        d2_2d_dropout.append(second_differences(obs.keypoints_2d[..., :2] / height, low).reshape(-1, 2))
        d2_3d.append(second_differences(obs.landmarks_3d, seen))
        d2_3d_dropout.append(second_differences(obs.landmarks_3d, low).reshape(-1, 3))
        visible.append(confidence[seen])
        for k in range(NUM_LANDMARKS):
            for start, end in episodes(low[:, k]):
                dropout_lengths.append((end - start) / obs.fps)
                dropout_visibility.append(confidence[start:end, k].mean())
        seconds_total += obs.valid.sum() / obs.fps
        durations = foot_swaps(obs, height)
        swap_durations += durations
        per_video[name] = dict(fps=obs.fps, frames=obs.num_frames, valid=int(obs.valid.sum()),
                               person_height_px=round(height, 1), foot_swaps=len(durations),
                               white_2d=robust_sd(d2_2d[-1]) / np.sqrt(6.0))
    sqrt6 = np.sqrt(6.0)
    all_2d = np.concatenate(d2_2d)
    white_2d = robust_sd(all_2d) / sqrt6
    white_2d_per_landmark = np.array([robust_sd(all_2d[:, k]) for k in range(NUM_LANDMARKS)]) / sqrt6
    white_2d_dropout = robust_sd(np.concatenate(d2_2d_dropout)) / sqrt6
    all_3d = np.concatenate(d2_3d)
    white_3d_xy = robust_sd(all_3d[..., :2]) / sqrt6
    white_3d_z = robust_sd(all_3d[..., 2]) / sqrt6
    white_3d_dropout = robust_sd(np.concatenate(d2_3d_dropout)) / sqrt6
    visible = np.concatenate(visible)
    multiview = multiview_errors([detections[f"pose2sim_cam0{k}"] for k in range(1, 5)])

    scale = multiview["total_2d_per_landmark"] / multiview["total_2d_per_landmark"].mean()
    noise = NoiseModel(
        keypoint_sd=round(white_2d, 4),
        keypoint_drift_sd=round(float(np.sqrt(max(multiview["varying_2d"] ** 2 - white_2d**2, 0.0))), 4),
        keypoint_drift_seconds=round(multiview["varying_seconds_2d"], 3),
        keypoint_drift_length=round(multiview["drift_length_2d"], 3),
        landmark_sd=round(white_3d_xy, 4),
        landmark_drift_sd=round(float(np.sqrt(max(multiview["varying_3d_xy"] ** 2 - white_3d_xy**2, 0.0))), 4),
        landmark_drift_seconds=round(multiview["varying_seconds_3d"], 3),
        landmark_drift_length=round(multiview["drift_length_3d"], 3),
        depth_scale_sd=round(multiview["depth_scale_sd"], 3),
        depth_scale_seconds=round(multiview["depth_scale_seconds"], 3),
        confidence_mean=round(float(visible.mean()), 3),
        confidence_sd=round(float(visible.std()), 3),
        dropout_per_second=round(len(dropout_lengths) / (NUM_LANDMARKS * seconds_total), 4),
        dropout_seconds=round(float(np.mean(dropout_lengths)), 3) if dropout_lengths else 0.0,
        dropout_confidence=round(2.0 * float(np.mean(dropout_visibility)), 3) if dropout_visibility else 0.0,
        dropout_keypoint_sd=round(float(np.sqrt(max(white_2d_dropout**2 - white_2d**2, 0.0))), 4),
        dropout_landmark_sd=round(float(np.sqrt(max(white_3d_dropout**2 - white_3d_xy**2, 0.0))), 4),
        foot_swaps_per_second=round(len(swap_durations) / seconds_total, 4),
        foot_swap_seconds=round(float(np.mean(swap_durations)), 3) if swap_durations else 0.0,
        landmark_scale=tuple(round(float(v), 2) for v in scale),
    )
    raw = dict(
        seconds_of_video=seconds_total, per_video=per_video, white_2d=white_2d, white_2d_dropout=white_2d_dropout,
        white_3d_xy=white_3d_xy, white_3d_z=white_3d_z, white_3d_dropout=white_3d_dropout, dropout_episodes=len(dropout_lengths),
        foot_swap_durations=swap_durations,
        white_2d_per_landmark=dict(zip(LANDMARK_NAMES, np.round(white_2d_per_landmark, 5).tolist())),
        planted_feet=planted_foot_spread(detections),
        multiview={k: (np.round(v, 5).tolist() if isinstance(v, np.ndarray) else v) for k, v in multiview.items()},
    )
    return noise, raw


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", type=Path, default=REPO / "runs" / "contacts" / "detections")
    parser.add_argument("--json", type=Path, help="also write the raw measurements here")
    args = parser.parse_args()
    noise, raw = measure(args.cache)
    print(json.dumps(raw, indent=1, default=float))
    print(noise)
    if args.json:
        args.json.write_text(json.dumps(dict(noise=asdict(noise), raw=raw), indent=1, default=float))


if __name__ == "__main__":
    main()
