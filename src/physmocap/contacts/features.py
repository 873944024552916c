"""The input representation shared by both contact networks: windows of root-centred, scale-normalised 2D
keypoints with their confidences, plus the frame interval.

A window is `length` consecutive frames around a target; its reference frame (the last one for the causal
network, the centre one for the centred network) fixes the origin: the midpoint of the hips in that frame, as in
Rempe et al. 3.2, so the window keeps the root's motion relative to the reference frame. Coordinates are divided
by the person's size in the window (the median over its frames of shoulder-midpoint-to-hip-midpoint plus thigh
plus shank, in pixels, about 0.8 of the stature for an upright person), which puts them mostly in [-1.5, 1.5]
(Rempe: "largely between [-1, 1]") whatever the resolution and distance. Each point also carries its speed, the
length of the change of its normalised position since the previous frame, per 1/30 s, and its confidence. The
networks could compute speeds from the positions, but given explicitly, and without their direction (which
depends on where the person walks relative to the camera, not on contact), they generalise better across
motions. Trained alike (12 sequences per clip, 6 epochs), the causal network scored on the 2 held-out CMU
subjects 0.775 from positions alone, 0.81 with velocities and 0.825 with speeds, and on the hand-labelled real
frames 0.82 with velocities and 0.875 with speeds: without them it learns poses (a foot stretched out sideways
is swinging), which fails on the tai-chi bow stance and on sideways and backward steps.

One scalar joins every window: the frame interval in units of 1/30 s (REFERENCE_FPS / fps). The networks are
trained at 12-60 fps, and the same foot speed is a 5x different displacement per frame at 12 and at 60 fps;
without the interval the networks could not tell a slow slide at 12 fps from a fast swing at 60 fps.

Frames that are not valid (no person), and points a detector did not see (confidence 0 or NaN), are filled from
the nearest frame that saw them with confidence 0, so a window never holds zeros as positions; windows reaching
past the clip's ends repeat the end frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..landmarks import LANDMARK_INDEX, MIRRORED, NUM_LANDMARKS

FEATURE_LANDMARKS: tuple[str, ...] = (
    "left_shoulder", "right_shoulder", "left_hip", "right_hip", "left_knee", "right_knee",
    "left_ankle", "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)
"""The keypoints the networks read: lower body up to the hips (Rempe's best ablation) plus the shoulders, which
carry the trunk's lean and the scale."""
FEATURE_INDICES: tuple[int, ...] = tuple(LANDMARK_INDEX[name] for name in FEATURE_LANDMARKS)
NUM_FEATURE_POINTS = len(FEATURE_LANDMARKS)
VALUES_PER_POINT = 4  # x, y (normalised), speed (normalised, per 1/30 s), confidence
REFERENCE_FPS = 30.0
MIN_SCALE_PIXELS = 1.0

# Positions within FEATURE_LANDMARKS.
_SHOULDERS = (0, 1)
_HIPS = (2, 3)
_KNEES = (4, 5)
_ANKLES = (6, 7)
FOOT_POINTS = (8, 10, 9, 11)
"""Positions of the contact sites' keypoints (l heel, l toe, r heel, r toe) within FEATURE_LANDMARKS."""
HIP_POINTS = _HIPS


@dataclass(frozen=True)
class WindowSpec:
    """Frames a network reads around each target frame.

    length: frames in the window (PhysCap: 7, causal; Rempe: 9, centred).
    reference: index in the window of the target frame, whose hip midpoint is the origin (length - 1 for causal,
        length // 2 for centred).
    outputs: frames the network predicts, centred on the reference frame (1 causal; Rempe: 5).
    """

    length: int
    reference: int
    outputs: int = 1

    def __post_init__(self) -> None:
        if self.length < 1 or not 0 <= self.reference < self.length:
            raise InputError(f"WindowSpec: reference {self.reference} outside a window of {self.length} frames.")
        half = self.outputs // 2
        odd_count = self.outputs >= 1 and self.outputs % 2 == 1
        if not (odd_count and 0 <= self.reference - half and self.reference + half < self.length):
            raise InputError(f"WindowSpec: {self.outputs} output frames do not fit around frame {self.reference}.")

    @property
    def input_size(self) -> int:
        """Length of a flattened input vector: length x 12 points x (x, y, speed, c), plus the frame interval."""
        return self.length * NUM_FEATURE_POINTS * VALUES_PER_POINT + 1


CAUSAL_WINDOW = WindowSpec(length=7, reference=6, outputs=1)
CENTRED_WINDOW = WindowSpec(length=9, reference=4, outputs=5)


# Where a point that is never seen in the clip (another detector's file: COCO's 17 joints have no heel or toe)
# takes its position from, in FEATURE_LANDMARKS positions, with confidence 0: the sole points from the ankle,
# the rest from their other side (a missing point at the image origin would wreck the root and the scale).
_STAND_IN = {8: 6, 9: 7, 10: 6, 11: 7, 0: 1, 1: 0, 2: 3, 3: 2, 4: 5, 5: 4, 6: 7, 7: 6}


def select_keypoints(keypoints_2d: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """The network's keypoints of every frame, unseen ones filled with confidence 0.

    keypoints_2d: (T, 33, 3) pixels and confidence. valid: (T,) bool.
    Returns (T, 12, 3) float32: FEATURE_LANDMARKS' x, y (pixels) and confidence. A point is unseen in a frame
    that is not valid, or where its confidence is 0 or its position not finite; it takes its position from the
    nearest frame where it is seen, or, if it is never seen, from its stand-in (`_STAND_IN`), with confidence 0.
    All zeros if no frame is valid.
    """
    keypoints_2d = np.asarray(keypoints_2d)
    valid = np.asarray(valid, dtype=bool)
    if keypoints_2d.ndim != 3 or keypoints_2d.shape[1:] != (NUM_LANDMARKS, 3) or valid.shape != keypoints_2d.shape[:1]:
        raise InputError(f"keypoints_2d {keypoints_2d.shape} and valid {valid.shape}: expected (T, 33, 3) and (T,).")
    points = keypoints_2d[:, FEATURE_INDICES].astype(np.float32)
    seen = valid[:, None] & np.isfinite(points).all(axis=2) & (points[..., 2] > 0)
    if seen.all():
        return points
    if not seen.any():
        return np.zeros_like(points)
    filled = points.copy()
    frames = np.arange(len(valid))
    for j in range(NUM_FEATURE_POINTS):
        seen_frames = np.flatnonzero(seen[:, j])
        if len(seen_frames) == 0 or len(seen_frames) == len(frames):
            continue
        after = np.clip(np.searchsorted(seen_frames, frames), 0, len(seen_frames) - 1)
        before = np.clip(after - 1, 0, len(seen_frames) - 1)
        nearer = np.where(np.abs(seen_frames[before] - frames) <= np.abs(seen_frames[after] - frames), before, after)
        filled[:, j] = points[seen_frames[nearer], j]
    never = ~seen.any(axis=0)
    for j in np.flatnonzero(never):
        stand_in = _STAND_IN[j]
        if never[stand_in]:  # neither side seen: the middle of whatever is seen
            seen_points = [k for k in range(NUM_FEATURE_POINTS) if not never[k]]
            filled[:, j, :2] = filled[:, seen_points, :2].mean(axis=1)
        else:
            filled[:, j, :2] = filled[:, stand_in, :2]
    filled[..., 2] = np.where(seen, points[..., 2], 0.0)
    return filled


def window_indices(num_frames: int, targets: np.ndarray, spec: WindowSpec) -> np.ndarray:
    """(N, length) frame indices of the windows of target frames (N,), clamped to the clip [0, T - 1]."""
    offsets = np.arange(spec.length) - spec.reference
    return np.clip(np.asarray(targets)[:, None] + offsets, 0, num_frames - 1)


def person_size(windows: np.ndarray) -> np.ndarray:
    """The person's size in each window, pixels: median over its frames of shoulder-midpoint-to-hip-midpoint plus
    mean thigh plus mean shank length. windows: (N, W, 12, 3) (`select_keypoints` rows). Returns (N,), at least
    MIN_SCALE_PIXELS."""
    xy = windows[..., :2]
    hips = 0.5 * (xy[..., _HIPS[0], :] + xy[..., _HIPS[1], :])
    shoulders = 0.5 * (xy[..., _SHOULDERS[0], :] + xy[..., _SHOULDERS[1], :])
    torso = np.linalg.norm(shoulders - hips, axis=-1)
    thigh = 0.5 * sum(np.linalg.norm(xy[..., k, :] - xy[..., h, :], axis=-1)
                      for h, k in zip(_HIPS, _KNEES, strict=True))
    shank = 0.5 * sum(np.linalg.norm(xy[..., a, :] - xy[..., k, :], axis=-1)
                      for k, a in zip(_KNEES, _ANKLES, strict=True))
    return np.maximum(np.median(torso + thigh + shank, axis=1), MIN_SCALE_PIXELS)


def normalise_windows(windows: np.ndarray, reference: int) -> np.ndarray:
    """Root-centre and scale windows of selected keypoints.

    windows: (N, W, 12, 3) pixels + confidence (`select_keypoints` rows). reference: index of the frame whose hip
    midpoint becomes the origin. Returns (N, W, 12, 3) float32: positions divided by the window's `person_size`,
    confidences unchanged.
    """
    xy = windows[..., :2]
    hips = 0.5 * (xy[:, reference, _HIPS[0]] + xy[:, reference, _HIPS[1]])
    scale = person_size(windows)
    normalised = np.empty(windows.shape, dtype=np.float32)
    normalised[..., :2] = (xy - hips[:, None, None, :]) / scale[:, None, None, None]
    normalised[..., 2] = windows[..., 2]
    return normalised


def inputs_from_windows(
    windows: np.ndarray, reference: int, interval: np.ndarray, position_noise: np.ndarray | None = None
) -> np.ndarray:
    """Flattened network inputs from windows that start one frame early (for the first frame's velocity).

    windows: (N, length + 1, 12, 3) `select_keypoints` rows; frame 0 only serves the velocities.
    reference: index of the target frame within the length frames.
    interval: (N,) frame interval in units of 1/30 s (REFERENCE_FPS / fps).
    position_noise: optional (N, length + 1, 12, 2) added to the normalised positions (training augmentation).
    Returns (N, length x 48 + 1) float32: per frame, per point, (x, y, speed, c) with positions from
    `normalise_windows`, speeds the length of their change since the previous frame per 1/30 s, then the
    interval.
    """
    normalised = normalise_windows(windows, reference + 1)
    if position_noise is not None:
        normalised[..., :2] += position_noise
    speed = np.linalg.norm(np.diff(normalised[..., :2], axis=1), axis=-1, keepdims=True) / interval[:, None, None, None]
    frames = np.concatenate([normalised[:, 1:, :, :2], speed, normalised[:, 1:, :, 2:]], axis=3)
    inputs = np.empty((len(windows), frames[0].size + 1), dtype=np.float32)
    inputs[:, :-1] = frames.reshape(len(windows), -1)
    inputs[:, -1] = interval
    return inputs


def window_inputs(points: np.ndarray, fps: float, targets: np.ndarray, spec: WindowSpec) -> np.ndarray:
    """Flattened network inputs of the windows around target frames.

    points: (T, 12, 3) from `select_keypoints`. fps: frames per second. targets: (N,) frame indices.
    Returns (N, spec.input_size) float32 (`inputs_from_windows`).
    """
    if fps <= 0:
        raise InputError(f"window_inputs: fps is {fps}, expected a positive number.")
    with_previous = WindowSpec(spec.length + 1, spec.reference + 1)
    windows = points[window_indices(len(points), targets, with_previous)]
    return inputs_from_windows(windows, spec.reference, np.full(len(windows), REFERENCE_FPS / fps, np.float32))


def mirror_keypoints(keypoints_2d: np.ndarray, image_width: int) -> np.ndarray:
    """Keypoints of the horizontally mirrored video: x -> width - 1 - x and left <-> right landmarks swapped.

    keypoints_2d: (T, 33, C) with x in column 0 (pixels, integer coordinates at pixel centres). Returns a copy.
    """
    mirrored = np.array(keypoints_2d[:, list(MIRRORED)], copy=True)
    mirrored[..., 0] = image_width - 1 - mirrored[..., 0]
    return mirrored
