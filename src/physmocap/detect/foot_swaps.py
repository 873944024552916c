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
CHANGE_COST = 8.0  # price of a change of reading between two frames (find_foot_swaps)
SWAP_COST = 1.0  # price per frame of the swapped reading
CLIP = 4.0  # cap of each residual, robust standard deviations
# The detector's frame-to-frame noise (contacts/noise.py's MEDIAPIPE_NOISE, white jitter, times sqrt 2 for a
# difference of two landmarks): the smallest spreads the costs' statistics may take.
SHANK_NOISE = 0.004  # m, a shank length (landmark_sd 0.0026 m)
STEP_NOISE = np.array([0.002, 0.004])  # image heights (keypoint_sd 0.0015 person heights) and m, an offset's step
STATISTICS_REFRESH = 30  # frames between CausalFootSwaps' recomputed clip statistics (the medians cost ~0.5 ms)


def _robust_scale(x: np.ndarray) -> float:
    """Spread of x about its median (MAD as a standard deviation), ignoring nan."""
    x = x[np.isfinite(x)]
    return float(1.4826 * np.median(np.abs(x - np.median(x)))) if len(x) else 1.0


def swap_feet(points: np.ndarray) -> np.ndarray:
    """(T, 33, k) landmarks with the feet's left and right exchanged."""
    out = points.copy()
    out[:, FOOT_LANDMARKS] = points[:, np.array(MIRRORED)[FOOT_LANDMARKS]]
    return out


def _shank_lengths(landmarks_3d: np.ndarray) -> np.ndarray:
    """(T, 2, 2) knee-to-ankle distances (3D) per frame, reading (as detected, swapped) and side."""
    return np.stack([np.stack([np.linalg.norm(p[:, k] - p[:, a], axis=-1) for k, a in SHANKS], axis=1)
                     for p in (landmarks_3d, swap_feet(landmarks_3d))], axis=1)


def _shank_statistics(lengths: np.ndarray) -> tuple[np.ndarray, float]:
    """Each side's shank length (2,) (the median of the detected reading's lengths (N, 2, 2)) and their robust
    spread."""
    shank = np.median(lengths[:, 0], axis=0)
    return shank, max(_robust_scale((lengths[:, 0] - shank).ravel()), SHANK_NOISE)


def _shank_cost(lengths: np.ndarray, shank: np.ndarray, scale: float, clip: float) -> np.ndarray:
    """(T, 2) per frame and reading: how far the shank lengths (T, 2, 2) are from each side's `shank`, squared in
    units of `scale`, each side capped at clip^2."""
    return np.minimum(((lengths - shank) / scale) ** 2, clip**2).sum(axis=2)


def _foot_offsets(keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, image_height: float) -> np.ndarray:
    """(T, 2 kinds, 2 readings, 6, 3) the foot landmarks relative to their knees, 2D in image heights (the third
    coordinate 0) and 3D in metres, for both readings: relative to the knee, a whole body that the detector flips
    (front taken for back) moves its feet with their knees and is not a foot swap."""
    kp = np.concatenate([keypoints_2d[..., :2] / max(image_height, 1), np.zeros(keypoints_2d.shape[:-1] + (1,))], -1)
    knees = np.repeat([knee for knee, _ in SHANKS], 3)  # the knee of each of FOOT_LANDMARKS' sides
    return np.stack([np.stack([p[:, FOOT_LANDMARKS] - points[:, knees] for p in (points, swap_feet(points))], 1)
                     for points in (kp, landmarks_3d)], axis=1)


def _motion_scales(offsets: np.ndarray) -> np.ndarray:
    """(2,) the robust frame-to-frame motion of the detected reading's foot offsets (T, 2, 2, 6, 3), per kind."""
    still = np.linalg.norm(np.diff(offsets[:, :, 0], axis=0), axis=-1)  # (T - 1, 2, 6)
    return _scales_of_steps(still)


def _scales_of_steps(steps: np.ndarray) -> np.ndarray:
    """(2,) per kind (2D, 3D) the robust spread of the foot offsets' steps (N, 2, 6), at least the detector's own
    frame-to-frame noise (STEP_NOISE): a person standing still gives a spread that makes any motion look wild."""
    return np.maximum([_robust_scale(steps[:, kind].ravel()) for kind in range(2)], STEP_NOISE)


def _jump_cost(offsets: np.ndarray, scales: np.ndarray, clip: float) -> np.ndarray:
    """(T - 1, 2, 2): cost of reading frame t - 1 as a and frame t as b, from how far each foot landmark moves
    relative to its knee between them (offsets (T, 2, 2, 6, 3)), squared in units of `scales` (2,) per kind,
    capped at clip^2 per landmark."""
    step = np.linalg.norm(offsets[1:, :, None] - offsets[:-1, :, :, None], axis=-1)  # (T - 1, kind, a, b, 6)
    return np.minimum((step / scales[:, None, None, None]) ** 2, clip**2).sum(axis=(1, 4))


def _readings_costs(obs: Observations, change_cost: float, swap_cost: float,
                    clip: float) -> tuple[np.ndarray, np.ndarray]:
    """find_foot_swaps' costs: unary (T, 2) per frame and reading, pairwise (T - 1, 2, 2) per step."""
    valid = obs.valid
    lengths = _shank_lengths(obs.landmarks_3d)
    unary = _shank_cost(lengths, *_shank_statistics(lengths[valid]), clip) + np.array([0.0, swap_cost])
    unary[~valid] = [0.0, 1e6]
    offsets = _foot_offsets(obs.keypoints_2d, obs.landmarks_3d, obs.image_size[1])
    pairwise = _jump_cost(offsets, _motion_scales(offsets), clip) + change_cost * (1 - np.eye(2))
    pairwise[~(valid[1:] & valid[:-1])] = change_cost * (1 - np.eye(2))  # no motion evidence across a gap
    return unary, pairwise


def find_foot_swaps(obs: Observations, change_cost: float = CHANGE_COST, swap_cost: float = SWAP_COST,
                    clip: float = CLIP) -> np.ndarray:
    """(T,) bool: frames whose feet the detector most likely labelled the wrong way round.

    change_cost: price of a change of reading between two frames (both ends of an episode pay it);
    swap_cost: price per frame of the swapped reading (ties stay as detected); clip: cap of each residual, in
    robust standard deviations (a single wild landmark is not evidence). Frames marked invalid keep their
    reading and do not join their neighbours."""
    T = obs.num_frames
    if T < 3 or obs.valid.sum() < 3:
        return np.zeros(T, dtype=bool)
    unary, pairwise = _readings_costs(obs, change_cost, swap_cost, clip)
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
    """Per frame of a stream, whether the detector's feet are to be read the other way round: find_foot_swaps'
    model (the same costs and prices), decoded forward. Each frame takes the reading that ends the cheapest
    sequence of readings over the frames so far, and the clip's statistics (shank lengths, the feet's usual
    motion) are those of the frames so far, recomputed every STATISTICS_REFRESH frames. The evidence is the
    detections alone: a reading judged by the fit's cost at its own predicted pose had reinforced itself, holding
    a wrong reading for 52 and 102 frames on two videos (docs/decisions/online-foot-swaps.md). image_height: px,
    for the 2D offsets."""

    def __init__(self, image_height: float, change_cost: float = CHANGE_COST, swap_cost: float = SWAP_COST,
                 clip: float = CLIP):
        self.image_height, self.change_cost, self.swap_cost, self.clip = image_height, change_cost, swap_cost, clip
        self.total: np.ndarray | None = None  # (2,) the cheapest sequence so far ending in each reading
        self._lengths: list[np.ndarray] = []  # (2, 2) per valid frame
        self._steps: list[np.ndarray] = []  # (2, 6) the detected reading's offset motion per step between frames
        self._previous: np.ndarray | None = None  # the last frame's offsets (2, 2, 6, 3), if it showed the person
        self._statistics: tuple | None = None
        self._counted = 0  # frames (valid) when the statistics were computed

    def update(self, keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: bool) -> bool:
        """One frame's detections (33, 3) + (33, 3) -> True where its feet are to be read swapped. A frame without
        the person is read as detected and breaks the motion evidence, as offline."""
        change = self.change_cost * (1 - np.eye(2))
        if not valid:
            self._advance(change, np.array([0.0, 1e6]))
            self._previous = None
            return False
        lengths = _shank_lengths(landmarks_3d[None])[0]
        offsets = _foot_offsets(keypoints_2d[None], landmarks_3d[None], self.image_height)[0]
        self._lengths.append(lengths)
        if self._previous is not None:
            self._steps.append(np.linalg.norm(offsets[:, 0] - self._previous[:, 0], axis=-1))
        shank, scale, scales = self._current_statistics()
        pairwise = change if self._previous is None or scales is None else \
            change + _jump_cost(np.stack([self._previous, offsets]), scales, self.clip)[0]
        unary = _shank_cost(lengths[None], shank, scale, self.clip)[0] + np.array([0.0, self.swap_cost])
        self._previous = offsets
        return bool(np.argmin(self._advance(pairwise, unary)))

    def _advance(self, pairwise: np.ndarray, unary: np.ndarray) -> np.ndarray:
        """One Viterbi step: the cheapest sequences extended by a frame of costs unary (2,) through pairwise
        (2, 2), kept relative to the cheapest (only their difference decides); returns them."""
        total = unary if self.total is None else np.min(self.total[:, None] + pairwise, axis=0) + unary
        self.total = total - total.min()
        return self.total

    def skip(self) -> None:
        """A frame that was not observed (live capture dropped it): no motion evidence to the next one."""
        self._previous = None

    def _current_statistics(self) -> tuple[np.ndarray, float, np.ndarray | None]:
        """find_foot_swaps' statistics over the frames so far (shank lengths and spread; motion scales, None
        before any step)."""
        if self._statistics is None or len(self._lengths) - self._counted >= STATISTICS_REFRESH \
                or len(self._lengths) < STATISTICS_REFRESH:
            steps = np.array(self._steps)
            scales = _scales_of_steps(steps) if len(steps) else None
            self._statistics = (*_shank_statistics(np.array(self._lengths)), scales)
            self._counted = len(self._lengths)
        return self._statistics
