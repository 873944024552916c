"""Detector-like observations made from motion capture, with the ground truth they came from.

A clip (`MocapClip`, world frame: metres, Z up, floor z = 0) is filmed by a random static pinhole camera
(`random_camera`, the distribution of Rempe et al. 2020), its 33 MediaPipe landmarks are placed on the body
(`landmarks_from_clip`) and projected, and errors like a detector's are added (`NoiseModel`, `make_observations`).
`write_synthetic_case` writes the pair of files that the rest of the project reads: observations.npz and truth.npz.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.signal import lfilter
from scipy.sparse.csgraph import shortest_path
from scipy.spatial.transform import Rotation, Slerp

from ..body.rotations import unit_vectors
from ..camera import floor_in_camera
from ..errors import InputError
from ..io.atomic import save_npz
from ..landmarks import LANDMARK_EDGES, LANDMARK_INDEX, LANDMARK_NAMES, NUM_LANDMARKS
from ..motion import Observations
from .bvh_reader import JOINT_NAMES, MocapClip, body_scale, standing_height

# Face landmarks in the head frame (forward, left, up) from the head joint at the skull base, metres, for the
# reference adult (1.75 m); scaled by `body_scale`. Left-side points; the right side mirrors them (left -> -left).
# Eyes 8 cm above and 8 cm in front of the head joint (the CC3 avatar's eye joints, scaled to the reference
# adult, sit at 7.3 and 7.3 cm), nose tip 4.5 cm below the eyes, mouth corners 3.5 cm below the nose tip, ears
# (tragion) 2.5 cm below eye level and 8 cm behind the eyes.
FACE_OFFSETS: dict[str, tuple[float, float, float]] = {
    "nose": (0.105, 0.0, 0.035),
    "left_eye_inner": (0.086, 0.015, 0.078),
    "left_eye": (0.080, 0.032, 0.080),
    "left_eye_outer": (0.072, 0.047, 0.078),
    "left_ear": (0.000, 0.073, 0.055),
    "mouth_left": (0.088, 0.024, 0.000),
}
# Hand landmarks in the hand frame (distal, thumb side, palm normal) from the wrist, metres, reference adult.
# MediaPipe's pinky and index are the first knuckles (MCP), its thumb the thumb's second knuckle (MCP). The palm
# normal component points out of the palm; `MocapClip.hand_rotations` has its third axis palmar for the left hand
# and dorsal for the right, so it flips sign on the right.
HAND_OFFSETS: dict[str, tuple[float, float, float]] = {
    "index": (0.085, 0.025, 0.0),
    "pinky": (0.075, -0.035, 0.0),
    "thumb": (0.045, 0.045, 0.015),
}
# Landmarks that are joints or sole sites of the clip.
JOINT_LANDMARKS: dict[str, str] = {
    f"{side}_{part}": f"{side}_{joint}"
    for side in ("left", "right")
    for part, joint in (("shoulder", "shoulder"), ("elbow", "elbow"), ("wrist", "wrist"), ("hip", "hip"),
                        ("knee", "knee"), ("ankle", "ankle"), ("heel", "heel"), ("foot_index", "toe"))
}
# MediaPipe's heel and foot_index keypoints of a flat standing foot, relative to its ankle keypoint, in units of the
# foot's length F (heel -> foot_index, horizontal): triangulated from the Pose2Sim views 2-4 of a man standing on
# one leg (scripts/contact_foot_keypoints.py; view subsets give heel above foot_index 0.15-0.30 F). MediaPipe's heel
# sits about 4 cm above its foot_index (pitch 12 degrees); the sole sites, which the labels use, are level.
MEDIAPIPE_HEEL_BEHIND_ANKLE = 0.271
MEDIAPIPE_HEEL_BELOW_ANKLE = 0.235
MEDIAPIPE_FOOT_INDEX_AHEAD_OF_ANKLE = 0.692
MEDIAPIPE_FOOT_INDEX_BELOW_ANKLE = 0.448
FOOT_KEYPOINTS = ("sole", "mediapipe")
"""Where `landmarks_from_clip` puts the heel and foot_index keypoints: on the clip's heel and toe sole sites, or
where MediaPipe puts them on the same foot (`mediapipe_foot_keypoints`)."""
FOOT_LANDMARK_PAIRS: tuple[tuple[int, int], ...] = tuple(
    (LANDMARK_INDEX[f"left_{part}"], LANDMARK_INDEX[f"right_{part}"]) for part in ("ankle", "heel", "foot_index")
)

CAMERA_DISTANCE_RANGE = (4.5, 7.5)  # m, from the hips' mean position
CAMERA_HEIGHT_MEAN, CAMERA_HEIGHT_SD, CAMERA_HEIGHT_RANGE = 0.9, 0.3, (0.3, 1.75)  # m above the floor
CAMERA_MAX_ANGLE_FROM_FRONT = np.radians(90.0)
HORIZONTAL_FOV_RANGE = (np.radians(40.0), np.radians(75.0))
IMAGE_MARGIN = 0.05  # fraction of the image size kept free around the person over the whole clip
MAX_HORIZONTAL_FOV = np.radians(100.0)  # a clip that needs a wider view to fit gets another camera
MIN_DEPTH = 1.0  # m: every landmark stays at least this far in front of the camera
MAX_CAMERA_DRAWS = 100


def _mirror(offset: tuple[float, float, float]) -> np.ndarray:
    """(3,) a left-side offset in a (forward, left, up) frame, moved to the right side."""
    return np.array([offset[0], -offset[1], offset[2]])


def mediapipe_foot_keypoints(ankle: np.ndarray, heel: np.ndarray, toe: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MediaPipe's heel and foot_index keypoints of a foot, rigid with it: (T, 3) each, metres.

    ankle, heel, toe: (T, 3) the ankle joint and the heel and toe sole sites (`bvh_reader.sole_sites`). With s the
    unit heel -> toe direction (along the sole), n the unit normal of the sole towards the ankle and F = |toe - heel|,
    the keypoints are ankle - F (MEDIAPIPE_HEEL_BEHIND_ANKLE s + MEDIAPIPE_HEEL_BELOW_ANKLE n) and
    ankle + F (MEDIAPIPE_FOOT_INDEX_AHEAD_OF_ANKLE s - MEDIAPIPE_FOOT_INDEX_BELOW_ANKLE n).
    """
    along = toe - heel
    length = np.linalg.norm(along, axis=-1, keepdims=True)
    sole = along / length
    up = ankle - heel
    normal = unit_vectors(up - np.sum(up * sole, axis=-1, keepdims=True) * sole)
    heel_keypoint = ankle - length * (MEDIAPIPE_HEEL_BEHIND_ANKLE * sole + MEDIAPIPE_HEEL_BELOW_ANKLE * normal)
    toe_keypoint = ankle + length * (MEDIAPIPE_FOOT_INDEX_AHEAD_OF_ANKLE * sole
                                     - MEDIAPIPE_FOOT_INDEX_BELOW_ANKLE * normal)
    return heel_keypoint, toe_keypoint


def landmarks_from_clip(clip: MocapClip, foot_keypoints: str = "sole") -> np.ndarray:
    """World positions of the 33 MediaPipe landmarks (LANDMARK_NAMES order): (T, 33, 3) metres.

    Shoulders, elbows, wrists, hips, knees and ankles are the clip's points; heel and foot_index are its heel and
    toe sites (foot_keypoints "sole") or MediaPipe's places on the same foot ("mediapipe",
    `mediapipe_foot_keypoints`). Face points are FACE_OFFSETS in the head frame, hand points HAND_OFFSETS in the
    hand frames, both scaled by `body_scale(clip)`.
    """
    if foot_keypoints not in FOOT_KEYPOINTS:
        raise InputError(f"foot_keypoints is {foot_keypoints!r}, expected one of {', '.join(FOOT_KEYPOINTS)}.")
    scale = body_scale(clip)
    landmarks = np.zeros((clip.num_frames, NUM_LANDMARKS, 3))
    for landmark, joint in JOINT_LANDMARKS.items():
        landmarks[:, LANDMARK_INDEX[landmark]] = clip.joint(joint)
    if foot_keypoints == "mediapipe":
        for side in ("left", "right"):
            heel, toe = mediapipe_foot_keypoints(*(clip.joint(f"{side}_{part}") for part in ("ankle", "heel", "toe")))
            landmarks[:, LANDMARK_INDEX[f"{side}_heel"]] = heel
            landmarks[:, LANDMARK_INDEX[f"{side}_foot_index"]] = toe
    head = clip.joint("head")
    for name, offset in FACE_OFFSETS.items():
        landmarks[:, LANDMARK_INDEX[name]] = head + scale * clip.head_rotation @ np.asarray(offset)
        mirrored = name.replace("left", "right")
        if mirrored != name:
            landmarks[:, LANDMARK_INDEX[mirrored]] = head + scale * clip.head_rotation @ _mirror(offset)
    for h, side in enumerate(("left", "right")):
        palm_sign = 1.0 if side == "left" else -1.0
        wrist = clip.joint(f"{side}_wrist")
        for name, (distal, thumb_side, palmar) in HAND_OFFSETS.items():
            hand_offset = np.array([distal, thumb_side, palm_sign * palmar])
            landmarks[:, LANDMARK_INDEX[f"{side}_{name}"]] = wrist + scale * clip.hand_rotations[:, h] @ hand_offset
    return landmarks


def facing_direction(clip: MocapClip) -> np.ndarray:
    """(3,) unit horizontal direction the person faces on average over the clip.

    Per frame the front is the hip line (right hip -> left hip) turned 90 degrees about Z; if those cancel out
    (the person turns round), the first frame's front is used.
    """
    left = clip.joint("left_hip") - clip.joint("right_hip")
    left[:, 2] = 0.0
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    front = np.cross(left, np.array([0.0, 0.0, 1.0]))
    mean = front.mean(axis=0)
    return mean / np.linalg.norm(mean) if np.linalg.norm(mean) > 0.1 else front[0]


def look_at(camera_position: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera rotation R (3, 3) and translation t (3,) of an upright OpenCV camera looking at `target`.

    Camera axes: x right, y down, z forward; x_camera = R x_world + t.
    """
    forward = target - camera_position
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward])
    return rotation, -rotation @ camera_position


def project(points: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection. points: (..., 3) world metres. Returns pixels (..., 2) and depths (...,) in metres."""
    camera = points @ R.T + t
    depth = camera[..., 2]
    return (camera @ K.T)[..., :2] / depth[..., None], depth


def random_camera(
    clip: MocapClip, rng: np.random.Generator, image_size: tuple[int, int] = (1280, 720)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random static camera filming the clip, after Rempe et al. 2020. Returns K (3, 3), R (3, 3), t (3,).

    The camera stands at a distance uniform in CAMERA_DISTANCE_RANGE (4.5-7.5 m) from the hips' mean position
    (3D distance), at a height above the floor drawn from N(0.9 m, 0.3 m) clamped to [0.3, 1.75] m, within
    90 degrees (uniform) of the person's front (`facing_direction`), and looks at the hips' mean position. Its
    horizontal field of view is uniform in 40-75 degrees, square pixels, principal point at the image centre;
    if the person would leave the image (with IMAGE_MARGIN) at some frame, the focal length is shortened until
    the whole clip fits. A camera that the person comes closer to than MIN_DEPTH, or that needs a field of view
    wider than MAX_HORIZONTAL_FOV, is drawn again.
    """
    width, height = image_size
    hips = clip.joint("pelvis").mean(axis=0)
    front = facing_direction(clip)
    landmarks = landmarks_from_clip(clip)
    for _ in range(MAX_CAMERA_DRAWS):
        distance = rng.uniform(*CAMERA_DISTANCE_RANGE)
        camera_height = np.clip(rng.normal(CAMERA_HEIGHT_MEAN, CAMERA_HEIGHT_SD), *CAMERA_HEIGHT_RANGE)
        rise = camera_height - hips[2]
        if abs(rise) >= distance:
            continue
        angle = rng.uniform(-CAMERA_MAX_ANGLE_FROM_FRONT, CAMERA_MAX_ANGLE_FROM_FRONT)
        cos, sin = np.cos(angle), np.sin(angle)
        direction = np.array([cos * front[0] - sin * front[1], sin * front[0] + cos * front[1], 0.0])
        position = hips + np.sqrt(distance**2 - rise**2) * direction
        position[2] = camera_height
        R, t = look_at(position, hips)
        camera = landmarks @ R.T + t
        if camera[..., 2].min() < MIN_DEPTH:
            continue
        focal = 0.5 * width / np.tan(0.5 * rng.uniform(*HORIZONTAL_FOV_RANGE))
        # Largest |x/z| and |y/z| over the clip must fit in half the image less the margin.
        half_extent = 0.5 * (1.0 - 2.0 * IMAGE_MARGIN) * np.array([width, height])
        spread = np.abs(camera[..., :2] / camera[..., 2:]).reshape(-1, 2).max(axis=0)
        focal = min(focal, *(half_extent / np.maximum(spread, 1e-9)))
        if 2.0 * np.arctan(0.5 * width / focal) > MAX_HORIZONTAL_FOV:
            continue
        K = np.array([[focal, 0.0, 0.5 * width], [0.0, focal, 0.5 * height], [0.0, 0.0, 1.0]])
        return K, R, t
    raise InputError(f"clip {clip.name}: no camera of the Rempe distribution keeps the whole clip in view.")


@dataclass(frozen=True)
class NoiseModel:
    """Errors of a pose detector, by kind; defaults are plausible for MediaPipe Pose on clear video, meant to be
    replaced by values measured against ground truth.

    2D errors are in units of the person's image height (focal length x standing height / depth of the pelvis),
    so that they scale with resolution and distance as a detector that crops the person does; 3D errors are in
    metres. "Drift" terms are Ornstein-Uhlenbeck processes: Gaussian with the given SD, correlated over the given
    time scale, independent per coordinate; across landmarks independent, or correlated along the skeleton.

    keypoint_sd: white 2D noise (0.004 is 1.6 px for a person 400 px tall).
    keypoint_drift_sd, keypoint_drift_seconds: slowly varying 2D offset per keypoint.
    keypoint_drift_length: person heights along the skeleton (`skeleton_distances`) over which two keypoints'
        drifts correlate by exp(-distance / length), as a detector's errors move a limb's landmarks together
        (0 for independent drifts; range 0-1).
    landmark_sd: white 3D noise of landmarks_3d, metres.
    landmark_drift_sd, landmark_drift_seconds: slowly varying 3D offset per landmark, metres.
    landmark_drift_length: the same correlation length for the 3D drift, person heights.
    depth_scale_sd, depth_scale_seconds: slowly varying relative error of the depth (camera z) of landmarks_3d,
        one per frame for the whole body (monocular depth is the least certain).
    confidence_mean, confidence_sd: confidence of a seen keypoint, Gaussian, clipped to [0, 1].
    dropout_per_second: failure episodes starting per keypoint per second (a rate, whatever the frame rate).
    dropout_seconds: mean length of an episode (geometric in frames).
    dropout_confidence: confidence during an episode, uniform in [0, dropout_confidence].
    dropout_keypoint_sd, dropout_landmark_sd: extra white error during an episode (2D as above, 3D metres).
    foot_swaps_per_second: episodes starting per second in which the detector swaps the left and right ankle,
        heel and foot index (2D and 3D together).
    foot_swap_seconds: mean length of a swap episode.
    landmark_scale: optional (33,) multipliers of every error term per landmark, e.g. measured per-landmark
        errors divided by their mean; None for all ones.
    """

    keypoint_sd: float = 0.004
    keypoint_drift_sd: float = 0.006
    keypoint_drift_seconds: float = 0.5
    keypoint_drift_length: float = 0.0
    landmark_sd: float = 0.01
    landmark_drift_sd: float = 0.02
    landmark_drift_seconds: float = 1.0
    landmark_drift_length: float = 0.0
    depth_scale_sd: float = 0.1
    depth_scale_seconds: float = 2.0
    confidence_mean: float = 0.92
    confidence_sd: float = 0.05
    dropout_per_second: float = 0.2
    dropout_seconds: float = 0.15
    dropout_confidence: float = 0.3
    dropout_keypoint_sd: float = 0.05
    dropout_landmark_sd: float = 0.1
    foot_swaps_per_second: float = 0.1
    foot_swap_seconds: float = 0.15
    landmark_scale: tuple[float, ...] | None = None


def _drift(rng: np.random.Generator, shape: tuple[int, ...], sd: float, seconds: float, fps: float) -> np.ndarray:
    """Stationary Ornstein-Uhlenbeck noise along axis 0: (T, ...) with SD `sd` and correlation time `seconds`."""
    decay = np.exp(-1.0 / (max(seconds, 1e-9) * fps))
    start = decay * sd * rng.standard_normal(shape[1:])
    innovations = sd * np.sqrt(1.0 - decay**2) * rng.standard_normal(shape)
    return lfilter([1.0], [1.0, -decay], innovations, axis=0, zi=start[None])[0]


def skeleton_distances(landmarks: np.ndarray, height: float) -> np.ndarray:
    """(33, 33) distances between the landmarks along the body's graph (`LANDMARK_EDGES`), in units of `height`
    (m): the shortest path over edges as long as their median length in `landmarks` (T, 33, 3) m."""
    lengths = np.zeros((NUM_LANDMARKS, NUM_LANDMARKS))
    for a, b in LANDMARK_EDGES:
        i, j = LANDMARK_INDEX[a], LANDMARK_INDEX[b]
        lengths[i, j] = lengths[j, i] = max(float(np.nanmedian(np.linalg.norm(landmarks[:, i] - landmarks[:, j],
                                                                              axis=-1))), 1e-6)
    return shortest_path(lengths, directed=False) / height


def _along_skeleton(drift: np.ndarray, distances: np.ndarray | None, length: float) -> np.ndarray:
    """Drifts (T, 33, C), independent per landmark, mixed so that two landmarks `distances` (33, 33) apart
    correlate by exp(-distance / length) and each keeps its SD (a symmetric square root of that correlation; its
    negative eigenvalues, where the graph's loops make it indefinite, dropped and the rows renormalised). Length 0
    keeps them independent; distances is None only when no drift of the noise model is correlated."""
    if length <= 0.0 or distances is None:
        return drift
    values, vectors = np.linalg.eigh(np.exp(-distances / length))
    root = (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T
    root /= np.linalg.norm(root, axis=1, keepdims=True)
    return np.einsum("kj,tjc->tkc", root, drift)


def _episodes(
    rng: np.random.Generator, shape: tuple[int, ...], per_second: float, mean_seconds: float, fps: float
) -> np.ndarray:
    """(T, ...) bool: episodes that start `per_second` times a second (independently per element) and last a
    geometric number of frames with mean `mean_seconds` (at least one frame)."""
    starts = rng.random(shape) < per_second / fps
    lengths = rng.geometric(1.0 / max(mean_seconds * fps, 1.0), size=shape)
    frame = np.arange(shape[0]).reshape((-1,) + (1,) * (len(shape) - 1))
    ends = np.where(starts, frame + lengths, 0)
    return frame < np.maximum.accumulate(ends, axis=0)


def make_observations(
    clip: MocapClip,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    rng: np.random.Generator,
    noise: NoiseModel = NoiseModel(),
    image_size: tuple[int, int] = (1280, 720),
    foot_keypoints: str = "sole",
) -> tuple[Observations, dict[str, np.ndarray]]:
    """Observations a detector could have made of the clip through camera (K, R, t), and the truth.

    keypoints_2d: projected landmarks (`landmarks_from_clip` with foot_keypoints) with `noise`'s 2D errors;
        confidence per keypoint.
    landmarks_3d: landmarks minus the hips' midpoint, rotated into camera axes, with the 3D errors.
    Returns the observations (camera_K = K, all frames valid) and a dict of truth arrays: joint_names (20,),
    joints_world (T, 20, 3), landmarks_world (T, 33, 3), camera_K, camera_R, camera_t, fps, image_size,
    floor (4,) (plane in camera coordinates), dropout (T, 33) and foot_swapped (T,) (where the errors were gross).
    """
    num_frames, fps = clip.num_frames, clip.fps
    landmarks = landmarks_from_clip(clip, foot_keypoints)
    scale = np.ones(NUM_LANDMARKS) if noise.landmark_scale is None else np.asarray(noise.landmark_scale, float)
    if scale.shape != (NUM_LANDMARKS,):
        raise InputError(f"NoiseModel.landmark_scale has {scale.size} values, expected {NUM_LANDMARKS}.")

    dropout = _episodes(rng, (num_frames, NUM_LANDMARKS), noise.dropout_per_second, noise.dropout_seconds, fps)
    foot_swapped = _episodes(rng, (num_frames,), noise.foot_swaps_per_second, noise.foot_swap_seconds, fps)
    seen = landmarks.copy()
    for left, right in FOOT_LANDMARK_PAIRS:
        seen[foot_swapped, left] = landmarks[foot_swapped, right]
        seen[foot_swapped, right] = landmarks[foot_swapped, left]

    # The 2D errors are drawn before the 3D ones: the order of the draws makes a seed's data.
    correlated = noise.keypoint_drift_length > 0.0 or noise.landmark_drift_length > 0.0
    distances = skeleton_distances(landmarks, standing_height(clip)) if correlated else None
    keypoints = _noisy_keypoints(clip, seen, K, R, t, rng, noise, scale, dropout, distances)
    relative = _noisy_landmarks(seen, R, rng, noise, scale, dropout, fps, distances)
    observations = Observations(keypoints_2d=keypoints, landmarks_3d=relative, fps=fps, image_size=image_size,
                                camera_K=K, source=f"synthetic:{clip.name}")
    truth = {
        "joint_names": np.array(JOINT_NAMES),
        "joints_world": clip.positions,
        "landmarks_world": landmarks,
        "landmark_names": np.array(LANDMARK_NAMES),
        "camera_K": K,
        "camera_R": R,
        "camera_t": t,
        "fps": np.asarray(fps, dtype=np.float64),
        "image_size": np.array(image_size),
        "floor": floor_in_camera(R, t),
        "dropout": dropout,
        "foot_swapped": foot_swapped,
    }
    return observations, truth


def _noisy_keypoints(clip: MocapClip, seen: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray,
                     rng: np.random.Generator, noise: NoiseModel, scale: np.ndarray, dropout: np.ndarray,
                     distances: np.ndarray | None) -> np.ndarray:
    """(T, 33, 3) the landmarks `seen` (T, 33, 3, world) projected, with `noise`'s 2D errors (in units of the
    person's height in pixels, times the landmark's `scale`; drifts correlated over `distances` (33, 33), person
    heights), and a confidence per keypoint."""
    shape_2d = seen.shape[:2] + (2,)
    pixels, _ = project(seen, K, R, t)
    _, pelvis_depth = project(clip.joint("pelvis"), K, R, t)
    person_pixels = (K[1, 1] * standing_height(clip) / pelvis_depth)[:, None, None]
    error_2d = (
        noise.keypoint_sd * rng.standard_normal(shape_2d)
        + _along_skeleton(_drift(rng, shape_2d, noise.keypoint_drift_sd, noise.keypoint_drift_seconds, clip.fps),
                          distances, noise.keypoint_drift_length)
        + dropout[..., None] * noise.dropout_keypoint_sd * rng.standard_normal(shape_2d)
    )
    pixels = pixels + person_pixels * scale[:, None] * error_2d
    confidence = np.clip(rng.normal(noise.confidence_mean, noise.confidence_sd, dropout.shape), 0.0, 1.0)
    confidence = np.where(dropout, rng.uniform(0.0, noise.dropout_confidence, dropout.shape), confidence)
    return np.concatenate([pixels, confidence[..., None]], axis=2)


def _noisy_landmarks(seen: np.ndarray, R: np.ndarray, rng: np.random.Generator, noise: NoiseModel,
                     scale: np.ndarray, dropout: np.ndarray, fps: float, distances: np.ndarray | None) -> np.ndarray:
    """(T, 33, 3) the landmarks `seen` (T, 33, 3, world) minus the hips' midpoint in camera axes, with `noise`'s
    depth scale drift and 3D errors (metres, times the landmark's `scale`; drifts correlated over `distances`)."""
    num_frames, shape_3d = len(seen), seen.shape
    hips = 0.5 * (seen[:, LANDMARK_INDEX["left_hip"]] + seen[:, LANDMARK_INDEX["right_hip"]])
    relative = (seen - hips[:, None]) @ R.T
    relative[..., 2] *= 1.0 + _drift(rng, (num_frames, 1), noise.depth_scale_sd, noise.depth_scale_seconds, fps)
    error_3d = (
        noise.landmark_sd * rng.standard_normal(shape_3d)
        + _along_skeleton(_drift(rng, shape_3d, noise.landmark_drift_sd, noise.landmark_drift_seconds, fps),
                          distances, noise.landmark_drift_length)
        + dropout[..., None] * noise.dropout_landmark_sd * rng.standard_normal(shape_3d)
    )
    return relative + scale[:, None] * error_3d


def resample(clip: MocapClip, fps: float) -> MocapClip:
    """The clip at another frame rate: frames at k / fps for every k within the clip's duration.

    Positions are interpolated linearly, head and hand rotations by slerp.
    """
    if fps <= 0:
        raise InputError(f"resample: fps is {fps}, expected a positive number.")
    duration = (clip.num_frames - 1) / clip.fps
    source_times = np.arange(clip.num_frames) / clip.fps
    times = np.arange(int(np.floor(duration * fps + 1e-9)) + 1) / fps
    position = np.clip(times * clip.fps, 0.0, clip.num_frames - 1)
    lower = np.minimum(np.floor(position).astype(int), clip.num_frames - 2)
    weight = (position - lower)[:, None, None]
    positions = (1.0 - weight) * clip.positions[lower] + weight * clip.positions[lower + 1]

    def slerp(matrices: np.ndarray) -> np.ndarray:
        return Slerp(source_times, Rotation.from_matrix(matrices))(np.minimum(times, source_times[-1])).as_matrix()

    hands = np.stack([slerp(clip.hand_rotations[:, h]) for h in range(2)], axis=1)
    return replace(
        clip, fps=float(fps), positions=positions, head_rotation=slerp(clip.head_rotation), hand_rotations=hands
    )


def write_synthetic_case(
    clip: MocapClip, out_dir: str | os.PathLike, seed: int, noise: NoiseModel = NoiseModel()
) -> tuple[Path, Path]:
    """Film the clip with a random camera (`random_camera`), make observations, and write them.

    Writes out_dir/observations.npz (Observations.save) and out_dir/truth.npz (the truth dict of
    `make_observations`, plus the clip's name and subject). Returns both paths.
    """
    rng = np.random.default_rng(seed)
    out_dir = Path(out_dir)
    K, R, t = random_camera(clip, rng)
    observations, truth = make_observations(clip, K, R, t, rng, noise)
    observations.source = f"synthetic:{clip.name}:seed{seed}"
    observations_path, truth_path = out_dir / "observations.npz", out_dir / "truth.npz"
    observations.save(observations_path)
    save_npz(truth_path, **truth, clip_name=np.str_(clip.name), subject=np.str_(clip.subject), seed=np.int64(seed))
    return observations_path, truth_path
