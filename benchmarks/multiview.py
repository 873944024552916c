"""Triangulation of 2D keypoints seen by several calibrated, synchronised cameras.

Shapes: V views, T frames, K keypoints. Cameras are OpenCV pinholes (x right, y down, z forward) with extrinsics
mapping world -> camera, x_cam = R x_world + t; keypoints are (x, y, confidence) in pixels of each view's video
frames, confidence 0 where a keypoint was not seen. World units are whatever the extrinsics use (metres here).

A single-view detector such as MediaPipe sometimes labels a person's left limbs as right and vice versa in one
view (typically when seen from behind). `correct_left_right_swaps` finds and undoes such swaps by asking which
labelling makes the views agree; `triangulate` then solves a confidence-weighted DLT per point and can drop a view
that disagrees with the others (an occluded limb guessed at).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import cv2
import numpy as np

from physmocap.camera import project_camera_points
from physmocap.landmarks import LANDMARK_INDEX, MIRRORED


def _both_sides(*parts: str) -> tuple[int, ...]:
    """Landmark indices of left_<part> and right_<part> for each part."""
    return tuple(LANDMARK_INDEX[f"{side}_{part}"] for part in parts for side in ("left", "right"))


MEDIAPIPE_SWAP_GROUPS: dict[str, tuple[int, ...]] = {
    "arms": _both_sides("shoulder", "elbow", "wrist", "pinky", "index", "thumb"),
    "legs": _both_sides("hip", "knee", "ankle", "heel", "foot_index"),
    "face": _both_sides("eye_inner", "eye", "eye_outer", "ear") + (LANDMARK_INDEX["mouth_left"],
                                                                    LANDMARK_INDEX["mouth_right"]),
}
"""MediaPipe landmarks whose left/right labels a detector swaps together. Each group lists both sides, so that
swapping a group within itself via `MIRRORED` exchanges left and right."""

SWAP_SCORE_CLIP_PX = 100.0
"""Reprojection errors above this are clipped when views' labellings are compared, so that one wild keypoint
cannot decide a swap."""


def undistort_keypoints(keypoints: np.ndarray, K: np.ndarray, distortion: np.ndarray | None) -> np.ndarray:
    """Remove lens distortion from pixel keypoints, keeping pixel units of the same K.

    keypoints: (..., 3) x, y pixels and confidence (or (..., 2)). K: (3, 3) intrinsics, pixels.
    distortion: OpenCV coefficients (k1, k2, p1, p2[, k3]) of normalised image coordinates, or None.
    Returns an array of the input's shape with undistorted x, y and the confidences unchanged.
    """
    keypoints = np.asarray(keypoints, dtype=float)
    if distortion is None or not np.any(distortion):
        return keypoints.copy()
    xy = keypoints[..., :2].reshape(-1, 1, 2)
    undistorted = cv2.undistortPoints(xy, np.asarray(K, float), np.asarray(distortion, float), P=np.asarray(K, float))
    out = keypoints.copy()
    out[..., :2] = undistorted.reshape(keypoints.shape[:-1] + (2,))
    return out


def _normalised_rays(keypoints: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(..., 2) pixels -> (..., 2) normalised image coordinates (x/z, y/z in the camera frame)."""
    homogeneous = np.concatenate([keypoints[..., :2], np.ones(keypoints.shape[:-1] + (1,))], axis=-1)
    return (homogeneous @ np.linalg.inv(K).T)[..., :2]


def _weighted_dlt(extrinsics: np.ndarray, rays: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Confidence-weighted linear triangulation in normalised coordinates.

    extrinsics: (V, 3, 4) [R | t]. rays: (V, ..., 2) normalised image coordinates. weights: (V, ...) >= 0.
    Returns (..., 3) points; NaN where fewer than two views have a positive weight.
    """
    # Each view contributes w (x P_3 - P_1) and w (y P_3 - P_2): (..., 2V, 4).
    views = extrinsics.shape[0]
    batch = rays.shape[1:-1]
    P = extrinsics.reshape((views,) + (1,) * len(batch) + (3, 4))
    rows_x = rays[..., 0, None] * P[..., 2, :] - P[..., 0, :]
    rows_y = rays[..., 1, None] * P[..., 2, :] - P[..., 1, :]
    rows = np.stack([rows_x, rows_y], axis=1) * weights[:, None, ..., None]  # (V, 2, ..., 4)
    A = np.moveaxis(rows.reshape((2 * views,) + batch + (4,)), 0, -2)
    _, _, vt = np.linalg.svd(A)
    homogeneous = vt[..., -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        points = homogeneous[..., :3] / homogeneous[..., 3:]
    points[(weights > 0).sum(axis=0) < 2] = np.nan
    return points


def _pixel_errors(K: np.ndarray, extrinsics: np.ndarray, points: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """(V, ...) pixel distance between the projections of (..., 3) points and (V, ..., 2+) keypoints."""
    errors = []
    for view in range(len(K)):
        camera_points = points @ extrinsics[view, :, :3].T + extrinsics[view, :, 3]
        errors.append(np.linalg.norm(project_camera_points(K[view], camera_points) - keypoints[view, ..., :2], axis=-1))
    return np.stack(errors)


def _worst_error(errors: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(...) largest of the (V, ...) errors over the views with positive weight; -inf where none."""
    return np.where(weights > 0, errors, -np.inf).max(axis=0)


def _stack_cameras(K_list, R_list, t_list) -> tuple[np.ndarray, np.ndarray]:
    K = np.asarray(K_list, dtype=float)
    R = np.asarray(R_list, dtype=float)
    t = np.asarray(t_list, dtype=float)
    if K.ndim != 3 or K.shape[1:] != (3, 3) or R.shape != K.shape or t.shape != (len(K), 3):
        raise ValueError(f"need V intrinsics (V, 3, 3), rotations (V, 3, 3) and translations (V, 3), got "
                         f"{K.shape}, {R.shape}, {t.shape}")
    if len(K) < 2:
        raise ValueError(f"triangulation needs at least two views, got {len(K)}")
    return K, np.concatenate([R, t[:, :, None]], axis=2)


def _check_keypoints(keypoints_list, views: int) -> np.ndarray:
    keypoints = np.asarray(keypoints_list, dtype=float)
    if keypoints.ndim != 4 or keypoints.shape[0] != views or keypoints.shape[-1] != 3:
        raise ValueError(f"keypoints must have shape ({views}, T, K, 3), got {keypoints.shape}")
    return keypoints


def triangulate(K_list: Sequence[np.ndarray] | np.ndarray, R_list: Sequence[np.ndarray] | np.ndarray,
                t_list: Sequence[np.ndarray] | np.ndarray, keypoints_list: np.ndarray, min_confidence: float = 0.3,
                distortion_list: Sequence[np.ndarray | None] | None = None,
                outlier_threshold_px: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """3D points from keypoints seen by V >= 2 calibrated views, by confidence-weighted DLT.

    K_list: V intrinsics (3, 3), pixels. R_list: V rotations (3, 3), t_list: V translations (3,), world -> camera.
    keypoints_list: (V, T, K, 3) x, y pixels and confidence per view. Observations with confidence below
        min_confidence are ignored; the others weigh by their confidence.
    distortion_list: per view OpenCV distortion coefficients (k1, k2, p1, p2[, k3]) or None; keypoints are
        undistorted first (errors are then measured against the undistorted keypoints).
    outlier_threshold_px: if given, while a point's largest reprojection error over its views exceeds this and more
        than two views see it, the view whose removal leaves the smallest largest error is dropped for that point
        and the point is solved again.
    Returns points (T, K, 3) in world units, NaN where fewer than two views saw the point, and the mean
    reprojection error (T, K) in pixels over the views used.
    """
    K, extrinsics = _stack_cameras(K_list, R_list, t_list)
    keypoints = _check_keypoints(keypoints_list, len(K))
    if distortion_list is not None:
        keypoints = np.stack([undistort_keypoints(keypoints[v], K[v], distortion_list[v]) for v in range(len(K))])
    rays = np.stack([_normalised_rays(keypoints[v], K[v]) for v in range(len(K))])
    confidence = np.nan_to_num(keypoints[..., 2])
    weights = np.where(confidence >= min_confidence, confidence, 0.0)

    points = _weighted_dlt(extrinsics, rays, weights)
    errors = _pixel_errors(K, extrinsics, points, keypoints)
    if outlier_threshold_px is not None:
        views = np.arange(len(K))[:, None, None]
        for _ in range(len(K) - 2):
            worst = _worst_error(errors, weights)
            to_fix = (worst > outlier_threshold_px) & ((weights > 0).sum(axis=0) > 2)
            if not to_fix.any():
                break
            # Drop, for each such point, the view whose removal leaves the smallest worst error (the view with
            # the largest error is not always the culprit: a wrong view pulls the point off the right ones).
            best = (worst, points, errors, weights)
            for view in range(len(K)):
                trial_weights = np.where((views == view) & to_fix, 0.0, weights)
                trial_points = _weighted_dlt(extrinsics, rays, trial_weights)
                trial_errors = _pixel_errors(K, extrinsics, trial_points, keypoints)
                trial_worst = _worst_error(trial_errors, trial_weights)
                better = to_fix & (weights[view] > 0) & (trial_worst < best[0])
                best = (np.where(better, trial_worst, best[0]), np.where(better[..., None], trial_points, best[1]),
                        np.where(better, trial_errors, best[2]), np.where(better, trial_weights, best[3]))
            _, points, errors, weights = best
    used = weights > 0
    with np.errstate(invalid="ignore"):
        mean_error = np.where(used, errors, 0.0).sum(axis=0) / used.sum(axis=0)
    mean_error[np.isnan(points[..., 0])] = np.nan
    return points, mean_error


def correct_left_right_swaps(K_list: Sequence[np.ndarray], R_list: Sequence[np.ndarray],
                             t_list: Sequence[np.ndarray], keypoints_list: np.ndarray, min_confidence: float = 0.3,
                             groups: Sequence[Sequence[int]] = tuple(MEDIAPIPE_SWAP_GROUPS.values()),
                             mirror: Sequence[int] = MIRRORED) -> tuple[np.ndarray, np.ndarray]:
    """Undo left/right label swaps of single views, group by group and frame by frame.

    For every frame and group (e.g. the legs), every choice of views to swap is triangulated and scored by the
    confidence-weighted mean reprojection error (each error clipped at SWAP_SCORE_CLIP_PX); the best choice wins.
    Swapping a set of views or all the other views explains the views equally well (it mirrors the person's
    labels in 3D), so of the two the one that swaps fewer views is taken, and on a tie the one whose points stay
    closest to the previous frame's (in the first frame: the one that keeps view 0's labels).

    K_list, R_list, t_list, keypoints_list (V, T, K, 3), min_confidence: as in `triangulate`, without distortion
        (undistort first if it matters). groups: keypoint indices swapped together, each holding both sides.
    mirror: (K,) index of each keypoint's left/right counterpart.
    Returns the corrected keypoints (V, T, K, 3) and which views were swapped, (V, T, len(groups)) bool.
    """
    K, extrinsics = _stack_cameras(K_list, R_list, t_list)
    keypoints = _check_keypoints(keypoints_list, len(K))
    views, frames = keypoints.shape[:2]
    mirror_index = np.asarray(mirror)
    corrected = keypoints.copy()
    swapped = np.zeros((views, frames, len(groups)), dtype=bool)
    # Choices of views to swap, as (C, V) bool; one of each complementary pair is enough to score.
    choices = np.array([c for c in itertools.product((False, True), repeat=views) if not c[0]])
    for g, group_keypoints in enumerate(groups):
        group = np.asarray(group_keypoints)
        scores, choice_points = [], []
        for choice in choices:
            candidate = keypoints[:, :, group].copy()
            candidate[choice] = keypoints[choice][:, :, mirror_index[group]]
            points, _ = triangulate(K, extrinsics[:, :, :3], extrinsics[:, :, 3], candidate, min_confidence)
            errors = np.minimum(_pixel_errors(K, extrinsics, points, candidate), SWAP_SCORE_CLIP_PX)
            weights = np.where(candidate[..., 2] >= min_confidence, candidate[..., 2], 0.0)
            valid = ~np.isnan(errors)
            total = np.where(valid, weights, 0.0).sum(axis=(0, 2))
            with np.errstate(invalid="ignore"):
                scores.append(np.where(valid, errors * weights, 0.0).sum(axis=(0, 2)) / total)
            choice_points.append(points)
        scores = np.nan_to_num(np.stack(scores), nan=np.inf)  # (C, T)
        previous = None
        for frame in range(frames):
            best = int(scores[:, frame].argmin())
            choice = choices[best]
            points = choice_points[best][frame]
            if 2 * choice.sum() > views:  # the complement swaps fewer views
                choice, points = ~choice, _mirror_points(points, group, mirror_index)
            elif 2 * choice.sum() == views and previous is not None:
                mirrored = _mirror_points(points, group, mirror_index)
                mirrored_step = np.nanmean(np.linalg.norm(mirrored - previous, axis=-1))
                if mirrored_step < np.nanmean(np.linalg.norm(points - previous, axis=-1)):
                    choice, points = ~choice, mirrored
            if np.isfinite(scores[best, frame]):
                previous = points
            swapped[choice, frame, g] = True
            for view in np.flatnonzero(choice):
                corrected[view, frame, group] = keypoints[view, frame, mirror_index[group]]
    return corrected, swapped


def _mirror_points(points: np.ndarray, group: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """(G, 3) points labelled by `group` -> the same points with left and right labels exchanged."""
    position = {int(index): i for i, index in enumerate(group)}
    return points[[position[int(mirror[index])] for index in group]]
