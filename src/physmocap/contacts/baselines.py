"""Heuristic contact detectors to compare the networks with (Rempe et al. 2020, Table 1).

- Always contact: every site touches the floor in every frame (and the person is always stationary).
- 2D velocity: a heel or toe keypoint is in contact when it moves slower than a threshold in the image, measured
  in person sizes per second (the size of `features.normalise_windows`: shoulder-hip + thigh + shank, in pixels,
  median over the surrounding 9 frames) so that it does not depend on resolution or distance; stationary when the
  hips' midpoint does.
- 3D velocity: the same on the detector's 3D landmarks (metres). MediaPipe's 3D landmarks are relative to the
  hips, so the root's own motion is invisible to it and it gives no stationary flag.

Speeds are measured over the last 1/30 s (`labels.point_speed`), as the automatic labels are. The thresholds were
chosen on the training subjects' synthetic data (the grid search of benchmarks/bench_contacts.py, best
accuracy), which is fairer to the heuristics than fixed guesses. The 3D threshold comes out high (2.2 m/s):
relative to the hips, a planted foot moves as fast as the body walks, so only a swinging foot stands out.
Invalid frames get no contact and are not stationary.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..landmarks import LANDMARK_INDEX
from .features import FOOT_POINTS, HIP_POINTS, WindowSpec, person_size, select_keypoints, window_indices
from .labels import point_speed

FOOT_LANDMARKS: tuple[str, ...] = ("left_heel", "left_foot_index", "right_heel", "right_foot_index")
"""Keypoints standing for the four contact sites (l heel, l toe, r heel, r toe)."""
FOOT_INDICES = [LANDMARK_INDEX[name] for name in FOOT_LANDMARKS]
SPEED_INTERVAL = 1.0 / 30.0  # s, as labels.LabelSettings.contact_speed_interval
SIZE_WINDOW = WindowSpec(length=9, reference=4)
CAUSAL_SIZE_WINDOW = WindowSpec(length=9, reference=8)  # the same median over the last 9 frames only


@dataclass(frozen=True)
class HeuristicSettings:
    """Thresholds of the velocity heuristics; the defaults are the grid search's choice (see the module doc).

    contact_speed_2d: person sizes per second under which a foot keypoint is in contact (2D velocity).
    stationary_speed_2d: person sizes per second under which the hips' midpoint is stationary (2D velocity).
    contact_speed_3d: m/s under which a foot landmark is in contact (3D velocity; hip-relative landmarks).
    """

    contact_speed_2d: float = 0.7
    stationary_speed_2d: float = 0.3
    contact_speed_3d: float = 2.2


def always_contact(num_frames: int, valid: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Contacts (T, 4) and stationary (T,), True in every valid frame."""
    valid = np.ones(num_frames, bool) if valid is None else np.asarray(valid, bool)
    return np.repeat(valid[:, None], 4, axis=1), valid.copy()


def velocity_2d(
    keypoints_2d: np.ndarray, valid: np.ndarray, fps: float, settings: HeuristicSettings = HeuristicSettings(),
    causal: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """2D velocity heuristic. keypoints_2d (T, 33, 3) pixels; valid (T,). Returns contacts (T, 4), stationary (T,).
    causal: measure the person's size over the last 9 frames instead of the 9 around each frame, so that each
    frame's flags depend on the past only (online and live capture)."""
    valid = np.asarray(valid, bool)
    points = select_keypoints(keypoints_2d, valid)
    window = CAUSAL_SIZE_WINDOW if causal else SIZE_WINDOW
    size = person_size(points[window_indices(len(points), np.arange(len(points)), window)])
    xy = points[..., :2]
    hips = xy[:, list(HIP_POINTS)].mean(axis=1)
    foot_speed = point_speed(xy[:, list(FOOT_POINTS)], fps, SPEED_INTERVAL, centred=False) / size[:, None]
    hip_speed = point_speed(hips, fps, SPEED_INTERVAL, centred=False) / size
    contacts = foot_speed < settings.contact_speed_2d
    stationary = hip_speed < settings.stationary_speed_2d
    return contacts & valid[:, None], stationary & valid


def velocity_3d(
    landmarks_3d: np.ndarray, valid: np.ndarray, fps: float, settings: HeuristicSettings = HeuristicSettings()
) -> np.ndarray:
    """3D velocity heuristic on hip-relative landmarks (T, 33, 3) metres. Returns contacts (T, 4) bool."""
    valid = np.asarray(valid, bool)
    speed = point_speed(landmarks_3d[:, FOOT_INDICES], fps, SPEED_INTERVAL, centred=False)
    contacts = speed < settings.contact_speed_3d
    return contacts & valid[:, None]
