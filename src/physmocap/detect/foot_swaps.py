"""Left/right foot swaps of a pose detector, found and undone offline.

MediaPipe now and then trades the labels of the two feet (ankle, heel and foot index together, in 2D and 3D)
for a fraction of a second, mostly when one foot passes the other. The knees keep their labels, so a swapped
frame joins each knee to the other side's ankle; and the feet jump to each other's place when a swap begins and
ends. Both cues are scored per frame for the two readings (as detected, swapped), and the most likely sequence
of readings over the whole clip is found by Viterbi, with a price for every change of reading: a single noisy
frame cannot flip a reading, a consistent episode can; the decision uses frames on both sides. A live stream
has only the past: `CausalFootSwaps` compares the two readings against the pose the fit predicts from it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..landmarks import LANDMARK_INDEX, MIRRORED
from ..motion import Observations

FOOT_LANDMARKS = np.array([LANDMARK_INDEX[f"{side}_{part}"] for side in ("left", "right")
                           for part in ("ankle", "heel", "foot_index")])
SHANKS = tuple((LANDMARK_INDEX[f"{side}_knee"], LANDMARK_INDEX[f"{side}_ankle"]) for side in ("left", "right"))


def _robust_scale(x: np.ndarray) -> float:
    """Spread of x about its median (MAD as a standard deviation), ignoring nan."""
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else 1.0


def swap_feet(points: np.ndarray) -> np.ndarray:
    """(T, 33, k) landmarks with the feet's left and right exchanged."""
    out = points.copy()
    out[:, FOOT_LANDMARKS] = points[:, np.array(MIRRORED)[FOOT_LANDMARKS]]
    return out


def _shank_cost(landmarks_3d: np.ndarray, valid: np.ndarray, clip: float) -> np.ndarray:
    """(T, 2) per frame and reading: how far the knee-to-ankle distances (3D) are from each side's shank
    length (the median over the clip), squared in units of their robust spread, each side capped at clip^2."""
    readings = (landmarks_3d, swap_feet(landmarks_3d))
    lengths = [np.stack([np.linalg.norm(p[:, k] - p[:, a], axis=-1) for k, a in SHANKS], axis=1) for p in readings]
    shank = np.median(lengths[0][valid], axis=0)
    scale = max(_robust_scale((lengths[0][valid] - shank).ravel()), 1e-3)
    return np.stack([np.minimum(((length - shank) / scale) ** 2, clip**2).sum(axis=1) for length in lengths], 1)


def _jump_cost(obs: Observations, clip: float) -> np.ndarray:
    """(T - 1, 2, 2): cost of reading frame t - 1 as a and frame t as b, from how far each foot landmark moves
    relative to its knee between them (2D in image heights, 3D in metres), squared in units of the clip's
    robust frame-to-frame motion, capped at clip^2 per landmark. Relative to the knee: when the detector
    flips the whole body (front taken for back), the feet jump with their knees and are not a foot swap."""
    kp = obs.keypoints_2d[..., :2] / max(obs.image_size[1], 1)
    knees = np.repeat([knee for knee, _ in SHANKS], 3)  # the knee of each of FOOT_LANDMARKS' sides
    out = np.zeros((obs.num_frames - 1, 2, 2))
    for points in (kp, obs.landmarks_3d):
        readings = [p[:, FOOT_LANDMARKS] - points[:, knees] for p in (points, swap_feet(points))]
        still = np.linalg.norm(np.diff(readings[0], axis=0), axis=-1)
        scale = max(_robust_scale(still.ravel()), 1e-4)
        for a in range(2):
            for b in range(2):
                step = np.linalg.norm(readings[b][1:] - readings[a][:-1], axis=-1) / scale
                out[:, a, b] += np.minimum(step**2, clip**2).sum(axis=1)
    return out


def find_foot_swaps(obs: Observations, change_cost: float = 8.0, swap_cost: float = 1.0,
                    clip: float = 4.0) -> np.ndarray:
    """(T,) bool: frames whose feet the detector most likely labelled the wrong way round.

    change_cost: price of a change of reading between two frames (both ends of an episode pay it);
    swap_cost: price per frame of the swapped reading (ties stay as detected); clip: cap of each residual, in
    robust standard deviations (a single wild landmark is not evidence). Frames marked invalid keep their
    reading and do not join their neighbours."""
    T = obs.num_frames
    valid = obs.valid
    if T < 3 or valid.sum() < 3:
        return np.zeros(T, dtype=bool)
    unary = _shank_cost(obs.landmarks_3d, valid, clip) + np.array([0.0, swap_cost])
    unary[~valid] = [0.0, 1e6]
    pairwise = _jump_cost(obs, clip) + change_cost * (1 - np.eye(2))
    pairwise[~(valid[1:] & valid[:-1])] = change_cost * (1 - np.eye(2))  # no motion evidence across a gap
    total = unary[0].copy()
    came_from = np.zeros((T, 2), dtype=int)
    for t in range(1, T):
        options = total[:, None] + pairwise[t - 1]  # (previous reading, this reading)
        came_from[t] = np.argmin(options, axis=0)
        total = options[came_from[t], [0, 1]] + unary[t]
    reading = np.zeros(T, dtype=int)
    reading[-1] = int(np.argmin(total))
    for t in range(T - 1, 0, -1):
        reading[t - 1] = came_from[t, reading[t]]
    return reading.astype(bool)


def undo_foot_swaps(obs: Observations, swapped: np.ndarray) -> Observations:
    """The observations with the feet of the `swapped` frames (T,) exchanged back, in 2D and 3D."""
    keypoints, landmarks = obs.keypoints_2d.copy(), obs.landmarks_3d.copy()
    keypoints[swapped] = swap_feet(obs.keypoints_2d[swapped])
    landmarks[swapped] = swap_feet(obs.landmarks_3d[swapped])
    return dataclasses.replace(obs, keypoints_2d=keypoints, landmarks_3d=landmarks)


class CausalFootSwaps:
    """Per frame of a live stream, whether to read the detector's feet the other way round: the reading whose
    fitting cost at the pose predicted from the past is lower, with hysteresis: the reading changes only when the
    other one costs less than (1 - margin) times the current one, so that a frame where the feet pass each other
    (both readings alike) keeps the reading of its past."""

    def __init__(self, margin: float):
        self.margin = margin
        self.swapped = False

    def update(self, cost_as_detected: float, cost_swapped: float) -> bool:
        """The costs of both readings of one frame -> True where the frame's feet are to be swapped back."""
        current, other = (cost_swapped, cost_as_detected) if self.swapped else (cost_as_detected, cost_swapped)
        if other < (1.0 - self.margin) * current:
            self.swapped = not self.swapped
        return self.swapped
