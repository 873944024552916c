"""Evaluation metrics of PhysCap (Shimada et al. 2020, Sec. 5.3) and of Rempe et al. 2020 (Sec. 4.3, App. E).

Pure numpy functions on plain arrays. Shapes: T frames, J joints, F foot points, K contact columns.
Positions are metres in the world frame, Z up, with the floor at z = 0 unless a floor is passed
(`floor_height` for a horizontal floor at another height, or `floor_plane` for any plane).
Percentages are 0..100; contact classification scores are fractions 0..1 as in Rempe's Tables 1 and E1.
Standard deviations are population standard deviations (ddof = 0).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal, TypedDict

import numpy as np

from .camera import project_camera_points

Alignment = Literal["root", "procrustes", "none", "first_frame", "first_frame_root"]
GrfMeasure = Literal["magnitude", "vertical"]


class GrfStatistics(TypedDict):
    """What `grf_statistics` returns; the fields are described there."""

    mean_percent_bw: float
    max_percent_bw: float
    ballistic_percent_bw: float
    flight_percent_bw: np.ndarray


class ContactScores(TypedDict):
    """What `contact_scores` returns; the fields are described there."""

    accuracy: float
    precision: float
    recall: float
    f1: float
    per_column: dict[str, np.ndarray]


PCK_THRESHOLD = 0.150  # metres; PhysCap Table 2 "PCK at 150 mm"
AUC_THRESHOLDS = np.linspace(0.0, 0.150, 31)  # metres; 0..150 mm in 5 mm steps (VNect / MPI-INF-3DHP)
FLOATING_THRESHOLD = 0.03  # metres above the floor while in contact (Rempe Sec. 4.3)
PENETRATION_THRESHOLD = 0.03  # metres below the floor at any time (Rempe Sec. 4.3)
SKATE_THRESHOLD = 0.02  # metres of movement per frame while in contact (Rempe Sec. 4.3)
SKATE_REFERENCE_FPS = 30.0  # frame rate of Rempe's synthetic test set (App. A.1), where 2 cm per frame applies
GRAVITY = 9.81  # m/s^2


# ---------------------------------------------------------------------------------------------------------
# Input checks


def _points(array: np.ndarray, name: str) -> np.ndarray:
    """Float (T, J, 3) array or ValueError."""
    points = np.asarray(array, dtype=float)
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (T, J, 3), got {points.shape}")
    return points


def _matching_points(pred: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred_points, truth_points = _points(pred, "pred"), _points(truth, "truth")
    if pred_points.shape != truth_points.shape:
        raise ValueError(f"pred {pred_points.shape} and truth {truth_points.shape} must have the same shape")
    return pred_points, truth_points


def _min_frames(points: np.ndarray, count: int, name: str) -> None:
    if points.shape[0] < count:
        raise ValueError(f"{name} needs at least {count} frames, got {points.shape[0]}")


def _flags(array: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Boolean array of exactly `shape` or ValueError."""
    flags = np.asarray(array)
    if flags.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {flags.shape}")
    return flags.astype(bool)


# ---------------------------------------------------------------------------------------------------------
# Floor


def height_above_floor(points: np.ndarray, floor_height: float = 0.0,
                       floor_plane: np.ndarray | None = None) -> np.ndarray:
    """Signed height of points above the floor, metres; negative below it.

    points: (..., 3) world positions, metres.
    floor_height: height of a horizontal floor z = floor_height (used when floor_plane is None).
    floor_plane: (4,) plane a x + b y + c z + d = 0 in world coordinates whose normal (a, b, c) points up,
        away from the floor into the space the person stands in; it need not be normalised.
    Returns (...,) heights.
    """
    points = np.asarray(points, dtype=float)
    if points.shape[-1] != 3:
        raise ValueError(f"points must end in a dimension of 3, got {points.shape}")
    if floor_plane is None:
        return points[..., 2] - floor_height
    if floor_height != 0.0:
        raise ValueError("pass either floor_height or floor_plane, not both")
    normal, offset = _unit_plane(floor_plane)
    return points @ normal + offset


def _unit_plane(floor_plane: np.ndarray) -> tuple[np.ndarray, float]:
    plane = np.asarray(floor_plane, dtype=float)
    if plane.shape != (4,):
        raise ValueError(f"floor_plane must have shape (4,), got {plane.shape}")
    norm = np.linalg.norm(plane[:3])
    if norm == 0.0:
        raise ValueError("floor_plane has a zero normal")
    return plane[:3] / norm, float(plane[3] / norm)


def _floor_normal(floor_plane: np.ndarray | None) -> np.ndarray:
    return np.array([0.0, 0.0, 1.0]) if floor_plane is None else _unit_plane(floor_plane)[0]


# ---------------------------------------------------------------------------------------------------------
# Joint position error, PCK, AUC


def similarity_align(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-frame Procrustes alignment: the similarity (rotation, translation, uniform scale) that best maps
    each frame of pred onto the same frame of truth in least squares (Umeyama 1991, with the reflection fix).

    pred, truth: (T, J, 3) metres. Returns (T, J, 3) aligned pred, metres. A frame whose predicted joints all
    coincide has no defined rotation or scale; it is mapped to the centroid of the true joints.
    """
    pred, truth = _matching_points(pred, truth)
    pred_centroid = pred.mean(axis=1, keepdims=True)
    truth_centroid = truth.mean(axis=1, keepdims=True)
    pred_centred = pred - pred_centroid
    truth_centred = truth - truth_centroid
    covariance = np.einsum("tji,tjk->tik", truth_centred, pred_centred)  # sum over joints of g p^T
    u, singular_values, vt = np.linalg.svd(covariance)
    reflection_fix = np.ones_like(singular_values)
    reflection_fix[:, 2] = np.sign(np.linalg.det(u @ vt))
    rotation = u @ (reflection_fix[:, :, None] * vt)
    pred_variance = np.einsum("tji,tji->t", pred_centred, pred_centred)
    scale = np.divide((singular_values * reflection_fix).sum(axis=1), pred_variance,
                      out=np.zeros_like(pred_variance), where=pred_variance > 0)
    return scale[:, None, None] * np.einsum("tik,tjk->tji", rotation, pred_centred) + truth_centroid


def first_frame_yaw_align(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """One rigid transform for the whole clip: the rotation about the vertical (world Z) axis plus the 3D
    translation that best map the joints of frame 0 of pred onto frame 0 of truth in least squares, applied
    to every frame. Our reading of Rempe et al. 2020's "Body-Align 1" (Sec. 4.3), extended by a heading.

    pred, truth: (T, J, 3) metres. Returns (T, J, 3) aligned pred, metres.
    """
    pred, truth = _matching_points(pred, truth)
    pred_centroid = pred[0].mean(axis=0)
    truth_centroid = truth[0].mean(axis=0)
    p = pred[0] - pred_centroid
    g = truth[0] - truth_centroid
    # Closed-form 2D Kabsch in the horizontal plane: the yaw that maximises sum g_h . R p_h.
    yaw = np.arctan2(np.sum(p[:, 0] * g[:, 1] - p[:, 1] * g[:, 0]), np.sum(p[:, 0] * g[:, 0] + p[:, 1] * g[:, 1]))
    cos_yaw, sin_yaw = np.cos(yaw), np.sin(yaw)
    rotation = np.array([[cos_yaw, -sin_yaw, 0.0], [sin_yaw, cos_yaw, 0.0], [0.0, 0.0, 1.0]])
    return (pred - pred_centroid) @ rotation.T + truth_centroid


def align_prediction(pred: np.ndarray, truth: np.ndarray, align: Alignment = "root",
                     root_index: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Bring pred and truth into the frame in which a position error is measured.

    pred, truth: (T, J, 3) metres.
    align:
      "root": root-relative; the root joint is subtracted from every joint of its own frame, in both pred and
          truth (PhysCap Table 2 "no Procrustes"; the root joint's error is then 0).
      "procrustes": per-frame similarity alignment of pred onto truth, see `similarity_align`
          (PhysCap Table 2 "Procrustes").
      "none": global positions as they are (PhysCap "global root position", Rempe "Feet" and "Body").
      "first_frame": one yaw + translation fitted on frame 0 over all joints, see `first_frame_yaw_align`.
      "first_frame_root": one translation that puts pred's root joint on truth's root joint in frame 0, applied
          to all frames; the literal text of Rempe's "Body-Align 1": "aligning the root joint of only the
          first frame of each sequence ... removing any spurious constant offset".
    root_index: index of the root (pelvis) joint.
    Returns (aligned pred, truth used), both (T, J, 3) metres.
    """
    pred, truth = _matching_points(pred, truth)
    if not -pred.shape[1] <= root_index < pred.shape[1]:
        raise ValueError(f"root_index {root_index} is out of range for {pred.shape[1]} joints")
    if align == "root":
        return pred - pred[:, root_index:root_index + 1], truth - truth[:, root_index:root_index + 1]
    if align == "procrustes":
        return similarity_align(pred, truth), truth
    if align == "none":
        return pred, truth
    if align == "first_frame":
        return first_frame_yaw_align(pred, truth), truth
    if align == "first_frame_root":
        return pred + (truth[0, root_index] - pred[0, root_index]), truth
    raise ValueError(f"unknown alignment {align!r}; use root, procrustes, none, first_frame or first_frame_root")


def joint_errors(pred: np.ndarray, truth: np.ndarray, align: Alignment = "root", root_index: int = 0,
                 joints: Sequence[int] | None = None) -> np.ndarray:
    """Euclidean error of every joint in every frame after alignment, metres.

    pred, truth: (T, J, 3) metres. align, root_index: see `align_prediction`. joints: indices of the joints to
    keep after alignment (all when None), e.g. Rempe's "Feet" (ankles and toes) or the root alone for
    PhysCap's "global root position". Returns (T, len(joints)) metres.
    """
    aligned_pred, aligned_truth = align_prediction(pred, truth, align, root_index)
    errors = np.linalg.norm(aligned_pred - aligned_truth, axis=-1)
    return errors if joints is None else errors[:, list(joints)]


def mpjpe(pred: np.ndarray, truth: np.ndarray, align: Alignment = "root", root_index: int = 0,
          joints: Sequence[int] | None = None) -> float:
    """Mean per-joint position error, metres (the papers report mm): the mean over frames and joints of the
    Euclidean joint error after alignment. PhysCap Sec. 5.3.1 / Table 2; Rempe Sec. 4.3 / Table 3.

    pred, truth: (T, J, 3) metres. align, root_index, joints: see `align_prediction` and `joint_errors`.
    """
    return float(joint_errors(pred, truth, align, root_index, joints).mean())


def pck(pred: np.ndarray, truth: np.ndarray, threshold: float = PCK_THRESHOLD, align: Alignment = "root",
        root_index: int = 0, joints: Sequence[int] | None = None) -> float:
    """Percentage of correct keypoints, percent: the share of joint-frames whose error after alignment is at
    most `threshold` metres (PhysCap Table 2, 150 mm). pred, truth: (T, J, 3) metres; see `joint_errors`.
    """
    return float(100.0 * np.mean(joint_errors(pred, truth, align, root_index, joints) <= threshold))


def auc(pred: np.ndarray, truth: np.ndarray, thresholds: np.ndarray = AUC_THRESHOLDS, align: Alignment = "root",
        root_index: int = 0, joints: Sequence[int] | None = None) -> float:
    """Area under the PCK curve, percent: the mean of PCK over `thresholds` (metres), by default 0..150 mm in
    31 steps as in VNect / MPI-INF-3DHP, whose convention PhysCap Table 2 follows.
    pred, truth: (T, J, 3) metres; see `joint_errors`.
    """
    errors = joint_errors(pred, truth, align, root_index, joints)
    levels = np.asarray(thresholds, dtype=float)
    if levels.ndim != 1 or levels.size == 0:
        raise ValueError(f"thresholds must be a non-empty 1D array, got shape {levels.shape}")
    return float(100.0 * np.mean(errors[..., None] <= levels))


# ---------------------------------------------------------------------------------------------------------
# Reprojection


def reprojection_error(points_world: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                       keypoints_2d: np.ndarray, min_confidence: float = 0.0) -> tuple[float, float]:
    """Mean pixel error of the projected 3D joints and its standard deviation over frames, pixels.

    PhysCap Sec. 5.3.1: e_2D^input (input view) and e_2D^side (any other calibrated view), "the average per
    frame distance to the ground truth 2D joint positions", with sigma_2D its standard deviation. Per frame the
    distances of the used joints are averaged; mean and std are then taken over frames.

    points_world: (T, J, 3) metres. K: (3, 3) intrinsics, pixels. R: (3, 3), t: (3,) world -> camera
    (x_cam = R x + t, OpenCV axes, no lens distortion). keypoints_2d: (T, J, 2) pixels, or (T, J, 3) with a
    confidence in the last column; joints with confidence <= min_confidence are left out (with the default 0,
    undetected joints of confidence 0 are left out). Frames with no joint left are left out.
    Returns (mean, std) in pixels; (nan, nan) when no frame is left.
    """
    points = _points(points_world, "points_world")
    keypoints = np.asarray(keypoints_2d, dtype=float)
    if keypoints.ndim != 3 or keypoints.shape[:2] != points.shape[:2] or keypoints.shape[2] not in (2, 3):
        raise ValueError(f"keypoints_2d must have shape {points.shape[:2] + (2,)} or {points.shape[:2] + (3,)}, "
                         f"got {keypoints.shape}")
    K, R, t = np.asarray(K, dtype=float), np.asarray(R, dtype=float), np.asarray(t, dtype=float)
    if K.shape != (3, 3) or R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"K and R must be (3, 3) and t (3,), got {K.shape}, {R.shape}, {t.shape}")
    pixels = project_camera_points(K, points @ R.T + t)
    distances = np.linalg.norm(pixels - keypoints[..., :2], axis=-1)
    used = keypoints[..., 2] > min_confidence if keypoints.shape[2] == 3 else np.ones(distances.shape, bool)
    joints_used = used.sum(axis=1)
    frames = joints_used > 0
    if not frames.any():
        return float("nan"), float("nan")
    per_frame = np.where(used, distances, 0.0).sum(axis=1)[frames] / joints_used[frames]
    return float(per_frame.mean()), float(per_frame.std())


# ---------------------------------------------------------------------------------------------------------
# Smoothness and acceleration


def e_smooth(pred: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Motion jitter error of PhysCap eq. 11 and its standard deviation, metres (the paper reports mm).

    Jit_X = |p_X^{s,t} - p_X^{s,t-1}| and Jit_GT likewise for every joint s and frame t = 1..T-1;
    e_smooth is the mean of |Jit_GT - Jit_X| over the (T-1) x J joint-frames and sigma_smooth the standard
    deviation of the same values. (Table 4's sigma/e ratios, 0.65-0.77, match a spread over single
    joint-frames rather than over per-frame means.) The positions are used as given, without alignment;
    a constant offset between pred and truth does not change the result.

    pred, truth: (T, J, 3) metres, T >= 2.
    """
    pred, truth = _matching_points(pred, truth)
    _min_frames(pred, 2, "e_smooth")
    jitter_pred = np.linalg.norm(np.diff(pred, axis=0), axis=-1)
    jitter_truth = np.linalg.norm(np.diff(truth, axis=0), axis=-1)
    deviation = np.abs(jitter_truth - jitter_pred)
    return float(deviation.mean()), float(deviation.std())


def accelerations(points: np.ndarray, fps: float) -> np.ndarray:
    """(T, ...) m -> (T-2, ...) m/s^2: central second differences (p[t+1] - 2 p[t] + p[t-1]) fps^2 at the interior
    frames."""
    return (points[2:] - 2.0 * points[1:-1] + points[:-2]) * fps**2


def acceleration_error(pred: np.ndarray, truth: np.ndarray, fps: float) -> float:
    """Mean joint acceleration error, m/s^2: the mean over interior frames and joints of
    |a_pred - a_truth| with accelerations from central second differences times fps^2.

    Not in either paper; the usual companion of e_smooth in later work. pred, truth: (T, J, 3) metres, T >= 3.
    """
    pred, truth = _matching_points(pred, truth)
    _min_frames(pred, 3, "acceleration_error")
    return float(np.linalg.norm(accelerations(pred, fps) - accelerations(truth, fps), axis=-1).mean())


def mean_acceleration(points: np.ndarray, fps: float) -> float:
    """Mean joint acceleration magnitude, m/s^2, over interior frames and joints (central second differences
    times fps^2); a reference-free jitter measure. points: (T, J, 3) metres, T >= 3.
    """
    points = _points(points, "points")
    _min_frames(points, 3, "mean_acceleration")
    return float(np.linalg.norm(accelerations(points, fps), axis=-1).mean())


def explained_interior(explained: np.ndarray) -> np.ndarray:
    """(T - 2,) bool: the interior frames of `explained` (T,) bool that are explained with both neighbours, those
    whose central second difference (`accelerations`) reads explained frames only."""
    explained = np.asarray(explained, bool)
    return explained[1:-1] & explained[:-2] & explained[2:]


def explained_acceleration(points: np.ndarray, fps: float, explained: np.ndarray) -> float:
    """Mean joint acceleration magnitude, m/s^2, at the frames that are `explained` (T,) bool with both neighbours
    (valid and not flagged: where only the feet carry the body, as far as the physics knows); nan where none is.
    points: (T, J, 3) metres."""
    inner = explained_interior(explained)
    if not inner.any():
        return float("nan")
    return float(np.linalg.norm(accelerations(np.asarray(points, float), fps)[inner], axis=-1).mean())


# ---------------------------------------------------------------------------------------------------------
# Feet and floor


def mpe_pnp(foot_points: np.ndarray, contacts: np.ndarray, floor_height: float = 0.0,
            floor_plane: np.ndarray | None = None,
            penetration_tolerance: float = 0.0) -> tuple[float, float, float]:
    """PhysCap's Mean Penetration Error (MPE), its standard deviation, and Percentage of Non-Penetration (PNP).

    PhysCap Sec. 5.3.1: "MPE is the mean distance between the floor and 3D foot position, and it is computed
    only when the foot is in contact with the floor. We use the ground truth foot contact labels"; "PNP ...
    shows the ratio of frames where the feet are not below the floor plane over the entire sequence."
    MPE is the mean of |height| over the foot-point frames whose ground-truth contact is set, sigma_MPE their
    standard deviation (metres; the paper reports mm). PNP is the percentage of all frames in which no foot
    point lies more than `penetration_tolerance` metres below the floor (default 0: any depth counts).

    foot_points: (T, F, 3) metres, points on the sole (e.g. heels and toes), not ankle joint centres.
    contacts: (T, F) bool, ground-truth contact of each foot point.
    floor_height, floor_plane: see `height_above_floor`.
    Returns (mpe, mpe_std, pnp_percent); mpe and mpe_std are nan when no contact is set.
    """
    points = _points(foot_points, "foot_points")
    in_contact = _flags(contacts, points.shape[:2], "contacts")
    heights = height_above_floor(points, floor_height, floor_plane)
    contact_distances = np.abs(heights[in_contact])
    if contact_distances.size:
        mpe, mpe_std = float(contact_distances.mean()), float(contact_distances.std())
    else:
        mpe, mpe_std = float("nan"), float("nan")
    non_penetrating = np.all(heights >= -penetration_tolerance, axis=1)
    return mpe, mpe_std, float(100.0 * non_penetrating.mean())


def contact_skating(foot_points: np.ndarray, contacts: np.ndarray, fps: float | None = None,
                    skate_threshold: float = SKATE_THRESHOLD, floor_plane: np.ndarray | None = None,
                    breaks: np.ndarray | None = None) -> np.ndarray:
    """(T, F) bool: foot joints (T, F, 3) m in contact (T, F) on this frame and the one before that moved along
    the floor by more than the skate threshold between them (per frame at 30 fps, rescaled to the same speed
    when fps is given); none into a row of `breaks` (T,) bool, which does not follow the previous row in time.
    Frame 0 never skates. The skate of `foot_contact_errors`."""
    step_threshold = skate_threshold if fps is None else skate_threshold * SKATE_REFERENCE_FPS / fps
    normal = _floor_normal(floor_plane)
    steps = np.diff(foot_points, axis=0)
    sliding_steps = steps - (steps @ normal)[..., None] * normal
    skating = np.zeros(contacts.shape, bool)
    skating[1:] = contacts[1:] & contacts[:-1] & (np.linalg.norm(sliding_steps, axis=-1) > step_threshold)
    if breaks is not None:
        skating[np.asarray(breaks, bool)] = False
    return skating


def foot_contact_errors(foot_points: np.ndarray, contacts: np.ndarray, fps: float | None = None,
                        floating_threshold: float = FLOATING_THRESHOLD,
                        penetration_threshold: float = PENETRATION_THRESHOLD,
                        skate_threshold: float = SKATE_THRESHOLD, floor_height: float = 0.0,
                        floor_plane: np.ndarray | None = None, breaks: np.ndarray | None = None) -> dict[str, float]:
    """Rempe et al. 2020's foot position metrics (Sec. 4.3, Table 2 right), percent of foot-joint frames.

    Paper: "Floating is the fraction of foot joints more than 3 cm off the ground when they should be in
    contact. Penetration is the fraction penetrating the ground more than 3 cm at any time. Skate is the
    fraction moving more than 2 cm when in contact." and, in the caption, "the percentage of frames
    containing typical foot contact errors per joint". Counted here, for each foot joint f and frame t:
      floating:    contact[t, f] and height[t, f] > floating_threshold;
      penetration: height[t, f] < -penetration_threshold (contact or not);
      skate:       contact[t, f] and contact[t-1, f] and the displacement of the joint from frame t-1 to t,
                   projected onto the floor (the sliding part; vertical motion is floating or penetration),
                   is longer than the skate threshold. Frame 0 never skates.
    The `*_percent` values divide by all T x F foot-joint frames (the caption's reading);
    `floating_percent_of_contact` and `skate_percent_of_contact` divide by the in-contact joint-frames instead
    (the other reading of "when they should be in contact"); nan when there is none.

    foot_points: (T, F, 3) metres; Rempe uses F = 4: heel and toe of each foot.
    contacts: (T, F) bool, ground-truth contact labels.
    fps: frame rate of the clip. The 2 cm skate threshold is per frame of Rempe's 30 fps data; with fps given
        it is rescaled to the same speed, skate_threshold * 30 / fps; with None it is used per frame as is.
    floor_height, floor_plane: see `height_above_floor`.
    breaks: (T,) bool, frames that do not follow the previous row in time (rows of a clip with gaps): no skate
        into them.
    Returns dict with floating_percent, penetration_percent, skate_percent, floating_percent_of_contact,
    skate_percent_of_contact.
    """
    points = _points(foot_points, "foot_points")
    in_contact = _flags(contacts, points.shape[:2], "contacts")
    heights = height_above_floor(points, floor_height, floor_plane)
    floating = in_contact & (heights > floating_threshold)
    penetrating = heights < -penetration_threshold

    skating = contact_skating(points, in_contact, fps, skate_threshold, floor_plane, breaks)

    contact_count = in_contact.sum()
    return {
        "floating_percent": float(100.0 * floating.mean()),
        "penetration_percent": float(100.0 * penetrating.mean()),
        "skate_percent": float(100.0 * skating.mean()),
        "floating_percent_of_contact": float(100.0 * floating.sum() / contact_count) if contact_count else float("nan"),
        "skate_percent_of_contact": float(100.0 * skating.sum() / contact_count) if contact_count else float("nan"),
    }


# ---------------------------------------------------------------------------------------------------------
# Ground reaction forces


def implied_grf(com: np.ndarray, body_mass: float, fps: float, gravity: float = GRAVITY) -> np.ndarray:
    """Net external force that a centre-of-mass trajectory implies, newtons: f = m (a_com - g), g = (0, 0, -gravity).

    Rempe Sec. 4.3: "we estimate the COM trajectory ... We then approximate the acceleration at each time step
    and solve for the implied GRFs for all time steps (both in contact and flight)." The acceleration is the
    central second difference times fps^2; the first and last frames take the value of their neighbour (the
    one-sided second difference). Feed the result to `grf_statistics`.

    com: (T, 3) metres, T >= 3. body_mass: kg. fps: frames per second. Returns (T, 3) newtons, world frame.
    """
    positions = np.asarray(com, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"com must have shape (T, 3), got {positions.shape}")
    if positions.shape[0] < 3:
        raise ValueError(f"implied_grf needs at least 3 frames, got {positions.shape[0]}")
    acceleration = np.pad(accelerations(positions, fps), ((1, 1), (0, 0)), mode="edge")
    return body_mass * (acceleration + np.array([0.0, 0.0, gravity]))


def grf_statistics(grf: np.ndarray, body_mass: float, contacts_truth: np.ndarray | None = None,
                   gravity: float = GRAVITY, measure: GrfMeasure = "magnitude",
                   floor_plane: np.ndarray | None = None) -> GrfStatistics:
    """Rempe et al. 2020's GRF plausibility metrics (Sec. 4.3, Table 2 left), percent of body weight m g.

    The net GRF f(t) = sum_i f_i(t) (Rempe: "net ground reaction forces (GRF), defined as f_GRF(t) = sum_i
    f_i(t)") is reduced per frame to its magnitude |f(t)| (default) or its component along the floor normal
    (measure="vertical"). Then
      mean_percent_bw:      mean over all frames (flight included: over a clip it should be near 100%,
                            Table 2's 99.0% for physics),
      max_percent_bw:       maximum over all frames,
      ballistic_percent_bw: median over the frames in which no foot point is in contact according to
                            `contacts_truth` ("the median GRF on the COM when no feet joints should be in
                            contact according to ground truth labels"; ideal 0); nan without contacts_truth or
                            without such frames.
      flight_percent_bw:    (F,) the per-frame values behind ballistic_percent_bw, for pooling the median
                            over many clips (a mean of per-clip medians weighs a clip with one flight frame as
                            much as one with fifty); empty without contacts_truth.

    grf: (T, C, 3) newtons per contact point (the result file's (T, 4, 3)), or (T, 3) a net force such as
        `implied_grf`. body_mass: kg. contacts_truth: (T, C') bool or None. floor_plane: orients "vertical"
        (world Z when None); see `height_above_floor`.
    Returns dict with mean_percent_bw, max_percent_bw, ballistic_percent_bw, flight_percent_bw.
    """
    forces = np.asarray(grf, dtype=float)
    if forces.ndim == 3 and forces.shape[2] == 3:
        net = forces.sum(axis=1)
    elif forces.ndim == 2 and forces.shape[1] == 3:
        net = forces
    else:
        raise ValueError(f"grf must have shape (T, C, 3) or (T, 3), got {forces.shape}")
    if body_mass <= 0 or gravity <= 0:
        raise ValueError("body_mass and gravity must be positive")
    if measure == "magnitude":
        per_frame = np.linalg.norm(net, axis=1)
    elif measure == "vertical":
        per_frame = net @ _floor_normal(floor_plane)
    else:
        raise ValueError(f"unknown measure {measure!r}; use magnitude or vertical")
    percent = 100.0 * per_frame / (body_mass * gravity)

    in_flight = np.zeros(0)
    if contacts_truth is not None:
        flags = np.asarray(contacts_truth)
        if flags.ndim != 2 or flags.shape[0] != net.shape[0]:
            raise ValueError(f"contacts_truth must have shape ({net.shape[0]}, C), got {flags.shape}")
        in_flight = percent[~flags.astype(bool).any(axis=1)]
    return {"mean_percent_bw": float(percent.mean()), "max_percent_bw": float(percent.max()),
            "ballistic_percent_bw": float(np.median(in_flight)) if in_flight.size else float("nan"),
            "flight_percent_bw": in_flight}


# ---------------------------------------------------------------------------------------------------------
# Contact classification


def _binary_scores(pred: np.ndarray, truth: np.ndarray, axis: int | None) -> dict[str, np.ndarray]:
    true_positive = np.sum(pred & truth, axis=axis)
    predicted_positive = np.sum(pred, axis=axis)
    actual_positive = np.sum(truth, axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = true_positive / predicted_positive
        recall = true_positive / actual_positive
        f1 = 2.0 * true_positive / (predicted_positive + actual_positive)
    return {"accuracy": np.mean(pred == truth, axis=axis), "precision": precision, "recall": recall, "f1": f1}


def contact_scores(pred: np.ndarray, truth: np.ndarray) -> ContactScores:
    """Contact classification scores, fractions 0..1: accuracy (Rempe Table 1) and precision, recall and F1 of
    the contact class (Rempe App. E.1, Table E1).

    pred, truth: (T, K) bool (or (T,) for one column), contact = True. The overall scores pool all T x K
    decisions; `per_column` holds (K,) arrays of the same scores for each column. A score whose denominator
    is zero (no predicted contact for precision, no true contact for recall, neither for F1) is nan.
    F1 = 2 TP / (2 TP + FP + FN), the harmonic mean of precision and recall.
    Returns dict with accuracy, precision, recall, f1 (floats) and per_column (dict of (K,) arrays).
    """
    predicted = np.asarray(pred)
    actual = np.asarray(truth)
    if predicted.shape != actual.shape or predicted.ndim not in (1, 2):
        raise ValueError(f"pred {predicted.shape} and truth {actual.shape} must have the same (T,) or (T, K) shape")
    predicted = predicted.astype(bool).reshape(predicted.shape[0], -1)
    actual = actual.astype(bool).reshape(actual.shape[0], -1)
    overall = {name: float(value) for name, value in _binary_scores(predicted, actual, None).items()}
    return ContactScores(accuracy=overall["accuracy"], precision=overall["precision"], recall=overall["recall"],
                         f1=overall["f1"], per_column=_binary_scores(predicted, actual, 0))


# ---------------------------------------------------------------------------------------------------------
# Skeleton consistency


def bone_lengths(points: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Length of every bone in every frame, metres.

    points: (T, J, 3) metres. edges: (E, 2) joint index pairs (parent, child). Returns (T, E) metres.
    """
    points = _points(points, "points")
    pairs = np.asarray(edges)
    if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
        raise ValueError(f"edges must be integer pairs of shape (E, 2), got {pairs.shape} {pairs.dtype}")
    return np.linalg.norm(points[:, pairs[:, 1]] - points[:, pairs[:, 0]], axis=-1)


def bone_length_std(points: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bone-length constancy: the standard deviation over time of each bone's length, metres; 0 for a rigid
    skeleton. points: (T, J, 3) metres. edges: (E, 2) joint index pairs. Returns (E,) metres.
    """
    return bone_lengths(points, edges).std(axis=0)
