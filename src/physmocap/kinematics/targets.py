"""What the fit aims at: per-frame targets from the detections (2D keypoints, metric 3D landmarks, depth from
the landmarks' spread against the keypoints'), and the limb lengths measured again against a first fit."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel, SkeletonLengths
from ..body.rotations import unit_vectors
from ..camera import Camera
from ..config import FitSettings
from ..errors import ReconstructionError
from ..motion import Observations
from .calibration import Calibration, plausible_length
from .fit import MARKER_LANDMARKS, MARKERS, FitTargets

# Lengths the offline fit measures again against its first fit (refine_lengths), in the order they are solved for.
REFINED_LENGTHS = ("thigh", "shank", "upper_arm", "forearm", "heel_back", "toe_front", "ankle_height")

# The markers on the hand itself (pinky and index knuckles): they only turn the hand (FitSettings.hand_weight).
HAND_MARKERS = np.array([a in {f"{side}_{part}" for side in ("left", "right") for part in ("pinky", "index")}
                         for a, _ in MARKERS])


def make_targets(keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: np.ndarray, depth: np.ndarray,
                 camera: Camera, calibration: Calibration, fit: FitSettings) -> FitTargets:
    """Per-frame observations (T, 33, 3) -> what the fit pulls towards, in the camera's world frame. Landmarks
    the detector did not see (confidence 0, or not finite) weigh nothing in either term."""
    kp = keypoints_2d[:, MARKER_LANDMARKS]
    landmarks = landmarks_3d[:, MARKER_LANDMARKS]
    seen = (kp[..., 2] > 0) & np.isfinite(kp).all(axis=2) & np.isfinite(landmarks).all(axis=2) & valid[:, None]
    conf = np.where(seen & (kp[..., 2] >= fit.min_confidence), kp[..., 2], 0.0)
    kp = np.where(seen[..., None], kp, 0.0)
    targets_3d = (np.where(seen[..., None], landmarks, 0.0) * calibration.landmark_scale) @ camera.R  # camera -> world
    # A seen but doubtful landmark keeps some 3D weight: the 3D term holds the pose where the 2D term lets go.
    weight_3d = np.sqrt(fit.weight_3d) * seen * np.sqrt(np.clip(kp[..., 2], 0.3, 1.0))
    marker = np.where(HAND_MARKERS, np.sqrt(fit.hand_weight), 1.0)
    return FitTargets(kp[..., :2], np.sqrt(fit.weight_2d * conf) * marker, targets_3d, weight_3d * marker, depth)

def raw_depth(keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: np.ndarray, focal: float,
              calibration: Calibration, min_confidence: float) -> np.ndarray:
    """(T,) the person's distance by similar triangles: the spread of the metric skeleton across the image
    plane against its spread in pixels; nan where a frame shows too little."""
    kp = keypoints_2d[:, MARKER_LANDMARKS]
    conf = np.where(kp[..., 2] >= min_confidence, kp[..., 2], 0.0) * valid[:, None]
    rel = landmarks_3d[:, MARKER_LANDMARKS, :2] * calibration.landmark_scale
    spread_3d = np.sqrt(np.sum(conf * np.sum((rel - _weighted_mean(rel, conf)) ** 2, -1), 1))
    spread_2d = np.sqrt(np.sum(conf * np.sum((kp[..., :2] - _weighted_mean(kp[..., :2], conf)) ** 2, -1), 1))
    with np.errstate(all="ignore"):
        return np.where(valid & (spread_2d > 1e-6), focal * spread_3d / spread_2d, np.nan)

def _weighted_mean(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return (np.sum(x * w[..., None], axis=1) / np.maximum(w.sum(axis=1), 1e-9)[:, None])[:, None]

def landmark_depth_scale(body: BodyModel, camera: Camera, qpos: np.ndarray, obs: Observations,
                         targets: FitTargets, calibration: Calibration, width: int = 5) -> np.ndarray:
    """(T,) per frame, how much the detector stretched its 3D landmarks along the camera axis against the
    fitted skeleton (MediaPipe's depth is the least certain: about 0.66 of the truth on average and +-18% from
    frame to frame): weighted least squares of the detector's hip-relative depths onto the fitted ones, pulled
    towards the clip's own value where a frame shows little depth, then a centred running median of `width`.
    The fitted depths come from the bone lengths and the 2D keypoints as much as from those landmarks."""
    pts = kin.forward_kinematics(body, qpos).points
    relative = (pts[:, body.point_index([b for _, b in MARKERS])] - pts[:, body.point_index(["pelvis"])]) @ camera.R.T
    fitted = relative[..., 2]
    seen = obs.landmarks_3d[:, MARKER_LANDMARKS, 2] * calibration.landmark_scale
    w = targets.weight_3d**2
    clip_scale = np.sum(w * fitted * seen) / max(np.sum(w * seen**2), 1e-12)
    prior = 0.05**2 * np.mean(np.sum(w, axis=1))  # as much as a frame whose landmarks are all 5 cm deep
    per_frame = (np.sum(w * fitted * seen, axis=1) + prior * clip_scale) / (np.sum(w * seen**2, axis=1) + prior)
    return 1.0 / np.clip(smooth_depth(per_frame, width), 0.4, 2.5)

def refine_lengths(body: BodyModel, camera: Camera, qpos: np.ndarray, targets: FitTargets,
                   calibration: Calibration, height: float) -> Calibration:
    """The limbs' and feet's lengths (REFINED_LENGTHS) measured again against a fitted motion, the skeleton then
    scaled to `height` again.

    Each observed offset between two landmarks (hip to knee, ankle to heel, ...) is, in the model, a sum of
    lengths along axes the fit has found (the thigh's direction; the foot's forward and down axes): linear in the
    lengths once the axes are held. They are solved for by weighted least squares over all frames and both
    sides, with the data terms' own residuals (the 3D landmarks' offsets; the keypoints' offsets through the
    projection's derivative at the segment, in metres at the person) and weights (the product of the two ends').
    The calibration's median distance between two noisy landmarks is too long by about the noise variance across
    the segment over its length (synthetic set, MediaPipe's measured noise: upper arm +8 mm, forearm +7 mm; the
    ankle's height above the sole by 27%, so the calibration takes that from the template); along an axis that
    the fit took from all the data, noise across the segment does not count. Implausible results keep the
    calibration's value."""
    points = kin.forward_kinematics(body, qpos).points
    marker = {b: i for i, (_, b) in enumerate(MARKERS)}
    index = {name: k for k, name in enumerate(REFINED_LENGTHS)}
    n = len(REFINED_LENGTHS)
    normal, rhs = np.zeros((n, n)), np.zeros(n)
    metres_per_pixel = (targets.depth / camera.focal)[:, None, None]

    def point(side: str, name: str) -> np.ndarray:
        return points[:, body.point_index([f"{side}_{name}"])[0]]

    for side in ("left", "right"):
        forward = unit_vectors(point(side, "toe") - point(side, "heel"))
        heel = point(side, "heel") - point(side, "ankle")
        down = unit_vectors(heel - np.einsum("ti,ti->t", heel, forward)[:, None] * forward)
        offsets = [(first, second, [(name, unit_vectors(point(side, second) - point(side, first)))])
                   for name, first, second in (("thigh", "hip", "knee"), ("shank", "knee", "ankle"),
                                               ("upper_arm", "shoulder", "elbow"), ("forearm", "elbow", "wrist"))]
        offsets += [("ankle", "heel", [("heel_back", -forward), ("ankle_height", down)]),
                    ("ankle", "toe", [("toe_front", forward), ("ankle_height", down)])]
        for first, second, terms in offsets:
            a, b = marker[f"{side}_{first}"], marker[f"{side}_{second}"]
            cols = [index[name] for name, _ in terms]
            axes = np.stack([axis for _, axis in terms], axis=1)  # (T, k, 3)
            seen = targets.targets_3d[:, b] - targets.targets_3d[:, a]
            # Each axis in the image: pixels per metre at the segment's middle, times metres per pixel.
            jac = camera.projection_jacobian(0.5 * (point(side, first) + point(side, second)))  # (T, 2, 3)
            pixels = np.einsum("tij,tkj->tki", jac, axes) * metres_per_pixel
            rows = [(targets.weight_3d[:, a] * targets.weight_3d[:, b], axes, seen),
                    (targets.weight_2d[:, a] * targets.weight_2d[:, b], pixels,
                     (targets.keypoints[:, b] - targets.keypoints[:, a]) * metres_per_pixel[:, 0])]
            for weight, model, observed in rows:
                normal[np.ix_(cols, cols)] += np.einsum("t,tki,tli->kl", weight, model, model)
                rhs[cols] += np.einsum("t,tki,ti->k", weight, model, observed)
    values, replaced = dict(calibration.lengths.__dict__), set(calibration.replaced)
    try:
        solved = np.linalg.solve(normal, rhs)
    except np.linalg.LinAlgError:
        return calibration
    for name, value in zip(REFINED_LENGTHS, solved, strict=True):
        if plausible_length(name, value / height):
            values[name] = float(value)
            replaced.discard(name)
    lengths = SkeletonLengths(**values)
    return dataclasses.replace(calibration, lengths=lengths.scaled(height / lengths.standing_height),
                               replaced=tuple(n for n in calibration.replaced if n in replaced))

def smooth_depth(depth: np.ndarray, width: int = 9) -> np.ndarray:
    """Centred running median; gaps take their neighbours' values. ReconstructionError without a finite value."""
    good = np.isfinite(depth)
    if not good.any():
        raise ReconstructionError("no frame shows enough of the person with enough confidence to place them in "
                                  "depth.")
    filled = np.interp(np.arange(len(depth)), np.flatnonzero(good), depth[good])
    pad = width // 2
    padded = np.pad(filled, pad, mode="edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1)
