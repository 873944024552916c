"""Skeleton calibration: bone lengths from the detector's 3D landmarks, scaled to the person's stated height.

Landmarks a detector did not see (confidence 0, or not finite: another detector's file without MediaPipe's heels,
toes or hands) carry no weight: a length that no frame shows, or that comes out implausible or degenerate, is the
template's share of the height (anthropometric proportions) and is listed in Calibration.replaced.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..body.model import TEMPLATE_RATIOS, SkeletonLengths, template_lengths
from ..landmarks import LANDMARK_INDEX as LM
from ..motion import Observations

# A measured length further than this factor from the template's is taken as a detector failure; small
# offsets (under 5% of the height) are instead checked against an absolute margin, in fractions of height.
PLAUSIBLE_RATIO = (0.6, 1.6)
PLAUSIBLE_MARGIN = 0.03
# Segment lengths and widths (all fields but OFFSETS) are positive on every body: below this share of the
# template's value they are degenerate (a width of zero where a detector put both ends on one point).
MIN_TEMPLATE_SHARE = 0.5
OFFSETS = ("heel_back", "nose_forward", "nose_down", "eye_forward", "eye_up")  # face and heel points placed
# from a joint: small, zero or negative on real people (synthetic 131_01: eyes 1.8 cm above the ears)
# The core lengths whose median ratio to the template gives the detector's unit: the leg and trunk, which
# detectors measure best.
CORE_LENGTHS = ("thigh", "shank", "spine_up", "upper_arm", "forearm", "shoulder_width")
# Lengths taken as the template's share of the height: the top of the head has no landmark, and the ankle's height
# above the sole (about 5 cm) is as short as the detector's 3D error, which lengthened it by 27% on average
# (synthetic, MediaPipe's measured noise) and, through the height, shortened every other bone (global root error
# 69 -> 45 mm with the template's value). The offline fit measures it again along the fitted foot
# (kinematics.targets.refine_lengths).
TEMPLATE_ONLY = ("head_top", "ankle_height")


@dataclass(frozen=True)
class Calibration:
    """lengths: the person's skeleton in metres; landmark_scale: factor that brings the detector's 3D
    landmarks to the same metric size; frames_used: how many frames the medians came from;
    replaced: lengths that were not seen, implausible or degenerate and fell back to the template;
    height: the standing height the skeleton was scaled to, m; detector_height: the standing height the
    detector's own 3D landmarks imply, m if they are metric (nan when nothing was measured); height_source:
    "given" (settings, the default 1.70 m included) or "estimated" (`resolve_height`).
    """

    lengths: SkeletonLengths
    landmark_scale: float
    frames_used: int
    replaced: tuple[str, ...]
    height: float = float("nan")
    detector_height: float = float("nan")
    height_source: str = "given"


def _distance(points: np.ndarray, a: str, b: str) -> np.ndarray:
    return np.linalg.norm(points[:, LM[a]] - points[:, LM[b]], axis=-1)


def _mid(points: np.ndarray, a: str, b: str) -> np.ndarray:
    return 0.5 * (points[:, LM[a]] + points[:, LM[b]])


def _both_sides(points: np.ndarray, a: str, b: str) -> np.ndarray:
    """(T,) the mean of the left and right distances, or the one side that is seen (NaN where neither is)."""
    sides = np.stack([_distance(points, f"left_{a}", f"left_{b}"), _distance(points, f"right_{a}", f"right_{b}")])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames where neither side is seen
        return np.nanmean(sides, axis=0)


def measure_lengths(landmarks: np.ndarray) -> dict[str, float]:
    """Median lengths (detector units) of every SkeletonLengths field except head_top, from (T, 33, 3); NaN
    landmarks (unseen) leave out the frames' lengths they take part in, and a length no frame shows is NaN."""
    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN medians: lengths nobody saw
        return {k: float(np.nanmedian(v)) for k, v in _frame_lengths(landmarks).items()}


def _frame_lengths(landmarks: np.ndarray) -> dict[str, np.ndarray]:
    """(T,) per frame, every SkeletonLengths field except head_top (detector units, NaN where unseen)."""
    P = landmarks
    heel = _both_sides(P, "ankle", "heel")
    toe = _both_sides(P, "ankle", "foot_index")
    foot = _both_sides(P, "heel", "foot_index")
    # Ankle, heel and toe form a triangle whose base (heel-toe) lies on the sole.
    heel_back = 0.5 * (foot + (heel**2 - toe**2) / np.maximum(foot, 1e-6))
    ankle_height = np.sqrt(np.maximum(heel**2 - heel_back**2, 1e-6))
    hips, shoulders = _mid(P, "left_hip", "right_hip"), _mid(P, "left_shoulder", "right_shoulder")
    ears = _mid(P, "left_ear", "right_ear")
    torso = np.linalg.norm(shoulders - hips, axis=-1)
    head_up = ears - shoulders
    head_height = np.linalg.norm(head_up, axis=-1)
    up = head_up / np.maximum(head_height, 1e-6)[:, None]
    nose = P[:, LM["nose"]] - ears
    nose_down = -np.einsum("ti,ti->t", nose, up)
    eyes = _mid(P, "left_eye", "right_eye") - ears
    eye_up = np.einsum("ti,ti->t", eyes, up)
    ear_axis = P[:, LM["left_ear"]] - P[:, LM["right_ear"]]
    ear_axis /= np.maximum(np.linalg.norm(ear_axis, axis=-1), 1e-6)[:, None]

    def forward_part(v, along_up):
        side = np.einsum("ti,ti->t", v, ear_axis)
        return np.sqrt(np.maximum(np.einsum("ti,ti->t", v, v) - along_up**2 - side**2, 0.0))

    hand_mid = lambda side: 0.5 * (P[:, LM[f"{side}_index"]] + P[:, LM[f"{side}_pinky"]])  # noqa: E731
    hands = np.stack([np.linalg.norm(hand_mid(side) - P[:, LM[f"{side}_wrist"]], axis=-1)
                      for side in ("left", "right")])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames where neither hand is seen
        hand = np.nanmean(hands, axis=0)
    raw = dict(
        hip_width=_distance(P, "left_hip", "right_hip"),
        thigh=_both_sides(P, "hip", "knee"),
        shank=_both_sides(P, "knee", "ankle"),
        ankle_height=ankle_height,
        heel_back=heel_back,
        toe_front=foot - heel_back,
        spine_low=0.2 * torso,
        spine_up=0.8 * torso,
        shoulder_width=_distance(P, "left_shoulder", "right_shoulder"),
        upper_arm=_both_sides(P, "shoulder", "elbow"),
        forearm=_both_sides(P, "elbow", "wrist"),
        hand_length=hand,
        hand_width=_both_sides(P, "index", "pinky"),
        head_height=head_height,
        ear_width=_distance(P, "left_ear", "right_ear"),
        nose_forward=forward_part(nose, -nose_down),
        nose_down=nose_down,
        eye_forward=forward_part(eyes, eye_up),
        eye_up=eye_up,
        eye_width=_distance(P, "left_eye", "right_eye"),
    )
    return raw


def plausible_length(name: str, value: float) -> bool:
    """Whether a length (SkeletonLengths field), as a share of the height, is one a person could have: within
    PLAUSIBLE_RATIO of the template's, or PLAUSIBLE_MARGIN of it for the short offsets, and never under
    MIN_TEMPLATE_SHARE of it for a segment's length or width (all but OFFSETS)."""
    expected = TEMPLATE_RATIOS[name]
    if not np.isfinite(value):
        return False
    if name not in OFFSETS and value < MIN_TEMPLATE_SHARE * expected:
        return False
    if abs(expected) >= 0.05:
        return PLAUSIBLE_RATIO[0] <= value / expected <= PLAUSIBLE_RATIO[1]
    return abs(value - expected) <= PLAUSIBLE_MARGIN


def seen_landmarks(obs: Observations) -> np.ndarray:
    """(T, 33, 3) the detector's 3D landmarks with NaN where it did not see them (confidence 0 or not finite)."""
    seen = (obs.keypoints_2d[..., 2] > 0) & np.isfinite(obs.landmarks_3d).all(axis=2)
    return np.where(seen[..., None], obs.landmarks_3d, np.nan)


def _usable_frames(obs: Observations, frames: int, min_confidence: float) -> np.ndarray:
    """Valid frames whose body landmarks are confidently seen (all valid frames if none is), the first `frames`
    of them (0: all)."""
    body = [LM[n] for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip", "left_knee",
                            "right_knee", "left_ankle", "right_ankle")]
    usable = np.flatnonzero(obs.valid & (obs.keypoints_2d[:, body, 2].min(axis=1) >= min_confidence))
    if len(usable) == 0:
        usable = np.flatnonzero(obs.valid)
    return usable[:frames] if frames > 0 else usable


def _detector_unit(measured: dict[str, float]) -> float:
    """The detector's length of one standing height: median over the CORE_LENGTHS it measured of their ratio to
    the template's share of the height (nan if it measured none)."""
    template = template_lengths(1.0)
    ratios = [measured[k] / getattr(template, k) for k in CORE_LENGTHS
              if np.isfinite(measured.get(k, np.nan)) and measured[k] > 0]
    return float(np.median(ratios)) if ratios else float("nan")


def calibrate(obs: Observations, height: float, frames: int = 30, min_confidence: float = 0.5) -> Calibration:
    """Bone lengths from the median over the first `frames` usable frames (0: all), scaled to `height` metres.

    A frame is usable when it is valid and its body landmarks are confidently seen; landmarks the detector did
    not see take no part (`seen_landmarks`)."""
    usable = _usable_frames(obs, frames, min_confidence)
    measured = measure_lengths(seen_landmarks(obs)[usable]) if len(usable) else {}
    template = template_lengths(1.0)  # ratios of height
    # Everything measured is in detector units; find their scale to ratios of height using the leg and
    # trunk, which detectors measure best, then reject outliers against the template.
    measured_unit = _detector_unit(measured)
    unit = measured_unit if np.isfinite(measured_unit) else 1.0
    values, replaced = {}, []
    for name in TEMPLATE_RATIOS:
        if name in TEMPLATE_ONLY:
            continue
        value = measured.get(name, np.nan) / unit
        if plausible_length(name, value):
            values[name] = value
        else:
            values[name] = getattr(template, name)
            replaced.append(name)
    values.update({name: getattr(template, name) for name in TEMPLATE_ONLY})
    unscaled = SkeletonLengths(**values)
    factor = height / unscaled.standing_height
    detector_height = measured_unit * unscaled.standing_height
    return Calibration(unscaled.scaled(factor), factor / unit, len(usable), tuple(replaced), float(height),
                       float(detector_height))


@dataclass(frozen=True)
class HeightEstimate:
    """height: m, the person's standing height from the detector's metric 3D landmarks; spread: m, the robust
    standard deviation (1.4826 x MAD) of the per-frame estimates; frames: how many frames gave one."""

    height: float
    spread: float
    frames: int


def estimate_height(obs: Observations, min_confidence: float = 0.5) -> HeightEstimate:
    """The standing height that the detector's 3D landmarks imply, read as metres (MediaPipe's world landmarks
    are metric by design): the calibration's skeleton (proportions from all usable frames) at the detector's
    unit (`_detector_unit`), and per frame the same from that frame's core lengths alone for the spread.
    Raises ValueError when no frame shows the core lengths."""
    calibration = calibrate(obs, 1.0, frames=0, min_confidence=min_confidence)
    if not np.isfinite(calibration.detector_height):
        raise ValueError(f"{obs.source}: no frame shows the legs, trunk and arms needed to estimate a height.")
    landmarks = seen_landmarks(obs)[_usable_frames(obs, 0, min_confidence)]
    unit = _detector_unit(measure_lengths(landmarks))
    per_frame, template = _frame_lengths(landmarks), template_lengths(1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames that show no core length
        units = np.nanmedian(np.stack([per_frame[k] / getattr(template, k) for k in CORE_LENGTHS]), axis=0)
    heights = calibration.detector_height * units[np.isfinite(units)] / unit
    spread = 1.4826 * float(np.median(np.abs(heights - np.median(heights))))
    return HeightEstimate(float(calibration.detector_height), spread, int(len(heights)))


HEIGHT_RANGE = (1.0, 2.3)  # m: an estimate outside BodySettings.height's range is not believed


def resolve_height(obs: Observations, height: float, estimate: bool) -> tuple[float, str]:
    """The standing height (m) to scale the skeleton to and its source: with `estimate`, `estimate_height`'s
    reading of the detector's 3D landmarks ("estimated"), unless it cannot be made or lies outside HEIGHT_RANGE;
    otherwise `height` ("given")."""
    if estimate:
        try:
            estimated = estimate_height(obs).height
        except ValueError:
            estimated = float("nan")
        if HEIGHT_RANGE[0] <= estimated <= HEIGHT_RANGE[1]:
            return float(estimated), "estimated"
    return float(height), "given"


def height_line(calibration: Calibration, default_height: float) -> str:
    """One line for the terminal and the report: the height the run assumed, where it came from, how to set it."""
    height = calibration.lengths.standing_height  # the skeleton is scaled to it, also when read from a cache
    how = "set it with --height M or body.height in a settings file"
    if calibration.height_source == "estimated":
        return f"Body height: {height:.2f} m, estimated from the detector's 3D landmarks; {how} if it is known."
    if abs(height - default_height) < 1e-6:
        return f"Body height: {height:.2f} m assumed (the default); {how}: every length scales with it."
    return f"Body height: {height:.2f} m (given)."
