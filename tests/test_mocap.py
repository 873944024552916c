"""BVH reading, the mapping onto the project's joints, and synthetic observations (on the shared CMU clips)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from physmocap.errors import InputError
from physmocap.landmarks import LANDMARK_INDEX, NUM_LANDMARKS
from physmocap.mocap.bvh_reader import (
    JOINT_INDEX,
    JOINT_NAMES,
    MocapClip,
    cmu_subject,
    forward_kinematics,
    load_mocap,
    parse_bvh,
    standing_height,
)
from physmocap.mocap.synthetic import (
    MEDIAPIPE_FOOT_INDEX_BELOW_ANKLE,
    MEDIAPIPE_HEEL_BELOW_ANKLE,
    NoiseModel,
    landmarks_from_clip,
    make_observations,
    project,
    random_camera,
    resample,
    skeleton_distances,
    write_synthetic_case,
)
from physmocap.motion import Observations

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MOCAP = DATA / "mocap"
RAW_WALK = MOCAP / "cmu_raw_cgspeed" / "02_01.bvh"
CC3_WALK = MOCAP / "cmu_iclone_cc3_retarget" / "007_03.bvh"  # starts with a prepended T-pose
SITES = ("left_heel", "left_toe", "right_heel", "right_toe")
RIGID_PAIRS = [
    (f"{side}_{a}", f"{side}_{b}")
    for side in ("left", "right")
    for a, b in (("hip", "knee"), ("knee", "ankle"), ("ankle", "heel"), ("ankle", "toe"), ("heel", "toe"),
                 ("shoulder", "elbow"), ("elbow", "wrist"))
]
NO_NOISE = NoiseModel(
    keypoint_sd=0.0, keypoint_drift_sd=0.0, landmark_sd=0.0, landmark_drift_sd=0.0, depth_scale_sd=0.0,
    dropout_per_second=0.0, foot_swaps_per_second=0.0,
)

TINY_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 1 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Knee
  {
    OFFSET 0 -2 0
    CHANNELS 2 Zrotation Xrotation
    End Site
    {
      OFFSET 0 0 1
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
0.5 1 0  90 0 0  0 0
0 0 0  0 0 0  90 90
"""


def test_tiny_bvh_forward_kinematics_matches_hand_computation() -> None:
    bvh = parse_bvh(TINY_BVH)
    assert bvh.joint_names == ("Hips", "Knee", "Knee_End")
    assert bvh.frame_time == 0.5 and bvh.motion.shape == (2, 8)
    positions, rotations = forward_kinematics(bvh, scale=2.0)
    # Frame 0: root at (OFFSET + position channels) = (1.5, 1, 0), turned 90 degrees about Z, which takes the
    # knee's offset (0, -2, 0) to (2, 0, 0); the knee does not turn, so the end site is 1 along Z from it.
    expected_0 = 2.0 * np.array([[1.5, 1.0, 0.0], [3.5, 1.0, 0.0], [3.5, 1.0, 1.0]])
    # Frame 1: root at (1, 0, 0) unrotated; knee R = Rz(90) @ Rx(90): Rx takes (0, 0, 1) to (0, -1, 0), Rz takes
    # that to (1, 0, 0). (The opposite order would give (0, -1, 0).)
    expected_1 = 2.0 * np.array([[1.0, 0.0, 0.0], [1.0, -2.0, 0.0], [2.0, -2.0, 0.0]])
    np.testing.assert_allclose(positions[0], expected_0, atol=1e-12)
    np.testing.assert_allclose(positions[1], expected_1, atol=1e-12)
    np.testing.assert_allclose(rotations[1, 2] @ [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], atol=1e-12)


def test_malformed_bvh_is_an_input_error() -> None:
    with pytest.raises(InputError, match="expected 2 frames"):
        parse_bvh(TINY_BVH.replace("0 0 0  0 0 0  90 90", "0 0 0  0 0 0  90"), source="tiny.bvh")
    with pytest.raises(InputError, match="not a BVH"):
        parse_bvh("hello")


def test_cmu_subject_from_file_name() -> None:
    assert cmu_subject("02_01.bvh") == "2"
    assert cmu_subject("131_01") == "131"
    assert cmu_subject("/some/where/002_01.bvh") == "2"
    with pytest.raises(InputError):
        cmu_subject("walk.bvh")


@pytest.fixture(scope="module")
def raw_walk() -> MocapClip:
    if not RAW_WALK.is_file():
        pytest.skip(f"{DATA} is not here")
    return load_mocap(RAW_WALK)


@pytest.fixture(scope="module")
def cc3_walk() -> MocapClip:
    if not CC3_WALK.is_file():
        pytest.skip(f"{DATA} is not here")
    return load_mocap(CC3_WALK)


def _file_frames(path: Path) -> int:
    return int(path.read_text().split("Frames:")[1].split()[0])


def test_both_skeletons_load(raw_walk: MocapClip, cc3_walk: MocapClip) -> None:
    for clip, fps, skeleton in ((raw_walk, 120.0, "cmu"), (cc3_walk, 60.0, "cc3")):
        assert clip.joint_names == JOINT_NAMES
        assert clip.fps == fps and clip.skeleton == skeleton
        assert clip.positions.shape == (clip.num_frames, len(JOINT_NAMES), 3)
        assert clip.head_rotation.shape == (clip.num_frames, 3, 3)
        assert clip.hand_rotations.shape == (clip.num_frames, 2, 3, 3)
        assert np.isfinite(clip.positions).all()
        np.testing.assert_allclose(np.linalg.det(clip.head_rotation), 1.0, atol=1e-9)
        pelvis = 0.5 * (clip.joint("left_hip") + clip.joint("right_hip"))
        np.testing.assert_allclose(clip.joint("pelvis"), pelvis)
        assert clip.joint("head")[:, 2].mean() > clip.joint("pelvis")[:, 2].mean() + 0.4  # Z is up
    assert raw_walk.subject == "2" and cc3_walk.subject == "7"


def test_prepended_pose_is_dropped(tmp_path: Path, raw_walk: MocapClip, cc3_walk: MocapClip) -> None:
    # The CC3 walk starts with a T-pose 2.6 m away; the raw CMU file starts with captured data and keeps it.
    assert cc3_walk.num_frames == _file_frames(CC3_WALK) - 1
    assert any("dropped frame 0" in note for note in cc3_walk.notes)
    assert raw_walk.num_frames == _file_frames(RAW_WALK)
    # A T-pose (the rest pose: all rotations zero) added in front of the raw CMU file is dropped, even where it
    # stands: here at frame 0's root position, so that only the arms move much from it to frame 1.
    header, motion = RAW_WALK.read_text().split("MOTION")
    frames = motion.strip().splitlines()
    first = frames[2].split()
    t_pose = " ".join(first[:3] + ["0"] * (len(first) - 3))
    frames[0] = f"Frames: {len(frames) - 2 + 1}"
    with_t_pose = tmp_path / "02_01.bvh"
    with_t_pose.write_text(header + "MOTION\n" + "\n".join(frames[:2] + [t_pose] + frames[2:]) + "\n")
    clip = load_mocap(with_t_pose)
    assert clip.num_frames == raw_walk.num_frames
    np.testing.assert_allclose(clip.positions, raw_walk.positions, atol=1e-9)


def test_bone_lengths_are_constant(raw_walk: MocapClip, cc3_walk: MocapClip) -> None:
    for clip in (raw_walk, cc3_walk):
        for a, b in RIGID_PAIRS:
            lengths = np.linalg.norm(clip.joint(a) - clip.joint(b), axis=1)
            assert lengths.std() < 1e-3, (clip.name, a, b)
            assert lengths.mean() > 0.03, (clip.name, a, b)


def test_heights_are_plausible(raw_walk: MocapClip, cc3_walk: MocapClip) -> None:
    for clip in (raw_walk, cc3_walk):
        assert 1.5 < standing_height(clip) < 1.95, clip.name


@pytest.mark.parametrize("which", ["raw", "cc3"])
def test_feet_touch_the_floor_alternately_in_a_walk(which: str, raw_walk: MocapClip, cc3_walk: MocapClip) -> None:
    clip = raw_walk if which == "raw" else cc3_walk
    sites = clip.positions[:, [JOINT_INDEX[name] for name in SITES]]
    lowest = sites[..., 2].min(axis=1)
    assert np.abs(np.median(lowest)) < 0.01  # a walk always has a foot on the floor
    assert np.all(lowest > -0.03) and np.mean(lowest < 0.03) > 0.95
    for foot in range(2):
        heights = sites[:, 2 * foot : 2 * foot + 2, 2]
        speed = np.linalg.norm(np.gradient(sites[:, 2 * foot : 2 * foot + 2], axis=0), axis=-1) * clip.fps
        stance = (speed < 0.2).all(axis=1)
        assert stance.mean() > 0.2
        assert np.all(np.abs(heights[stance].min(axis=1)) < 0.03)  # heel or toe on the floor in stance
        assert heights.max() > 0.15  # and the foot swings
    # Alternation: most of the time one foot is down and the other is not.
    left_down = sites[:, :2, 2].min(axis=1) < 0.03
    right_down = sites[:, 2:, 2].min(axis=1) < 0.03
    assert np.mean(left_down != right_down) > 0.4


def test_synthetic_camera_films_the_whole_clip(raw_walk: MocapClip, cc3_walk: MocapClip) -> None:
    image_size = (1280, 720)
    for seed, clip in enumerate((raw_walk, cc3_walk, raw_walk, cc3_walk)):
        K, R, t = random_camera(clip, np.random.default_rng(seed), image_size)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        centre = -R.T @ t
        assert 4.5 - 1e-9 <= np.linalg.norm(centre - clip.joint("pelvis").mean(axis=0)) <= 7.5 + 1e-9
        assert 0.3 - 1e-9 <= centre[2] <= 1.75 + 1e-9
        assert (R.T @ [0.0, 1.0, 0.0])[2] < 0  # image y points down in the world
        pixels, depth = project(landmarks_from_clip(clip), K, R, t)
        assert depth.min() > 1.0
        assert np.all((pixels >= 0) & (pixels <= image_size)), clip.name
        floor_camera = np.append(R[:, 2], -R[:, 2] @ t)
        heels = clip.joint("left_heel") @ R.T + t
        np.testing.assert_allclose(heels @ floor_camera[:3] + floor_camera[3], clip.joint("left_heel")[:, 2])


def test_landmarks_3d_are_hip_relative_in_camera_axes(raw_walk: MocapClip) -> None:
    K, R, t = random_camera(raw_walk, np.random.default_rng(7))
    observations, truth = make_observations(raw_walk, K, R, t, np.random.default_rng(8), NO_NOISE)
    landmarks = truth["landmarks_world"]
    hips = 0.5 * (landmarks[:, LANDMARK_INDEX["left_hip"]] + landmarks[:, LANDMARK_INDEX["right_hip"]])
    np.testing.assert_allclose(observations.landmarks_3d @ R + hips[:, None], landmarks, atol=1e-9)
    pixels, _ = project(landmarks, K, R, t)
    np.testing.assert_allclose(observations.keypoints_2d[..., :2], pixels, atol=1e-9)
    np.testing.assert_allclose(truth["joints_world"], raw_walk.positions)
    assert truth["floor"].shape == (4,) and truth["camera_K"] is K

    noisy, _ = make_observations(raw_walk, K, R, t, np.random.default_rng(9))
    errors_3d = np.linalg.norm(noisy.landmarks_3d - observations.landmarks_3d, axis=-1)
    assert 0.01 < np.median(errors_3d) < 0.1
    pixel_errors = np.linalg.norm(noisy.keypoints_2d[..., :2] - pixels, axis=-1)
    assert 0.5 < np.median(pixel_errors) < 10.0
    confidence = noisy.keypoints_2d[..., 2]
    assert np.median(confidence) > 0.8 and 0.0 < np.mean(confidence < 0.5) < 0.2


def test_drifts_correlate_along_the_skeleton_by_their_length(raw_walk: MocapClip) -> None:
    """keypoint_drift_length and landmark_drift_length: a foot's landmarks drift together (heel and ankle about
    0.065 person heights apart: exp(-0.065 / 0.166) = 0.68), the two ankles (about a person height apart along
    the legs) independently, and every landmark keeps its drift's SD. At length 0 neighbours drift independently."""
    K, R, t = random_camera(raw_walk, np.random.default_rng(7))
    clean, _ = make_observations(raw_walk, K, R, t, np.random.default_rng(8), NO_NOISE)
    distances = skeleton_distances(landmarks_from_clip(raw_walk), standing_height(raw_walk))
    ankle, heel, other = LANDMARK_INDEX["left_ankle"], LANDMARK_INDEX["left_heel"], LANDMARK_INDEX["right_ankle"]
    assert distances[ankle, heel] == pytest.approx(distances[heel, ankle]) and 0.03 < distances[ankle, heel] < 0.09
    assert distances[ankle, other] > 0.9

    def correlations(length: float) -> tuple[float, float, np.ndarray]:
        noise = replace(NO_NOISE, landmark_drift_sd=0.02, landmark_drift_seconds=0.05, landmark_drift_length=length)
        noisy, _ = make_observations(raw_walk, K, R, t, np.random.default_rng(9), noise)
        error = (noisy.landmarks_3d - clean.landmarks_3d)[..., :2]
        pair = lambda i, j: float(np.corrcoef(error[:, i].ravel(), error[:, j].ravel())[0, 1])  # noqa: E731
        return pair(ankle, heel), pair(ankle, other), error.std(axis=(0, 2))

    near, far, sd = correlations(0.166)
    assert near == pytest.approx(np.exp(-distances[ankle, heel] / 0.166), abs=0.15) and abs(far) < 0.25
    np.testing.assert_allclose(np.median(sd), 0.02, rtol=0.25)
    near, far, sd = correlations(0.0)
    assert abs(near) < 0.25 and abs(far) < 0.25


def test_face_and_hands_are_placed_on_the_right_side(cc3_walk: MocapClip) -> None:
    landmarks = landmarks_from_clip(cc3_walk)
    assert landmarks.shape == (cc3_walk.num_frames, NUM_LANDMARKS, 3)
    left = cc3_walk.joint("left_shoulder") - cc3_walk.joint("right_shoulder")
    for a, b in (("left_eye", "right_eye"), ("left_ear", "right_ear"), ("mouth_left", "mouth_right")):
        assert np.all(np.sum((landmarks[:, LANDMARK_INDEX[a]] - landmarks[:, LANDMARK_INDEX[b]]) * left, 1) > 0)
    nose_above_shoulders = landmarks[:, LANDMARK_INDEX["nose"], 2] - cc3_walk.joint("left_shoulder")[:, 2]
    assert np.all((0.05 < nose_above_shoulders) & (nose_above_shoulders < 0.35))
    for side in ("left", "right"):
        reach = np.linalg.norm(landmarks[:, LANDMARK_INDEX[f"{side}_index"]] - cc3_walk.joint(f"{side}_wrist"), axis=1)
        assert np.all((0.05 < reach) & (reach < 0.15))


def test_mediapipe_foot_keypoints_sit_where_mediapipe_puts_those_of_a_flat_foot(cc3_walk: MocapClip) -> None:
    sole = landmarks_from_clip(cc3_walk)
    placed = landmarks_from_clip(cc3_walk, "mediapipe")
    feet = [LANDMARK_INDEX[f"{side}_{part}"] for side in ("left", "right") for part in ("heel", "foot_index")]
    others = np.setdiff1d(np.arange(NUM_LANDMARKS), feet)
    np.testing.assert_array_equal(placed[:, others], sole[:, others])
    for site, landmark in (("left_heel", "left_heel"), ("left_toe", "left_foot_index")):
        np.testing.assert_array_equal(sole[:, LANDMARK_INDEX[landmark]], cc3_walk.joint(site))
    ankle, heel, toe = (placed[:, LANDMARK_INDEX[f"left_{part}"]] for part in ("ankle", "heel", "foot_index"))
    sites = cc3_walk.positions[:, [JOINT_INDEX["left_heel"], JOINT_INDEX["left_toe"]]]
    # A flat foot: heel and toe sites on the floor, level within 3 mm.
    flat = (np.abs(sites[..., 2]) < 0.02).all(axis=1) & (np.abs(sites[:, 0, 2] - sites[:, 1, 2]) < 0.003)
    assert flat.sum() >= 10
    length = np.linalg.norm(sites[flat, 1] - sites[flat, 0], axis=1)
    # A flat foot's heel keypoint rises about 4 cm above its foot_index, as MediaPipe's does (sole sites: level).
    rise = heel[flat, 2] - toe[flat, 2]
    expected = (MEDIAPIPE_FOOT_INDEX_BELOW_ANKLE - MEDIAPIPE_HEEL_BELOW_ANKLE) * length
    np.testing.assert_allclose(rise, expected, atol=0.01)
    assert 0.03 < np.median(rise) < 0.06
    np.testing.assert_allclose(ankle[flat, 2] - heel[flat, 2], MEDIAPIPE_HEEL_BELOW_ANKLE * length, atol=0.01)
    # Rigid with the foot: heel keypoint to foot_index keypoint keeps its length in every frame.
    keypoint_length = np.linalg.norm(toe - heel, axis=1)
    assert np.ptp(keypoint_length) < 1e-6 + 1e-3 * keypoint_length.mean()
    with pytest.raises(InputError, match="foot_keypoints"):
        landmarks_from_clip(cc3_walk, "toes")


def test_resample_halves_the_frames_at_half_the_rate(raw_walk: MocapClip) -> None:
    half = resample(raw_walk, raw_walk.fps / 2)
    assert half.fps == raw_walk.fps / 2
    assert abs(half.num_frames - raw_walk.num_frames / 2) <= 1
    np.testing.assert_allclose(half.positions[1:4], raw_walk.positions[2:8:2], atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(half.hand_rotations), 1.0, atol=1e-9)
    np.testing.assert_allclose(half.head_rotation[5], raw_walk.head_rotation[10], atol=1e-9)


def test_write_synthetic_case_round_trip(tmp_path: Path, cc3_walk: MocapClip) -> None:
    observations_path, truth_path = write_synthetic_case(cc3_walk, tmp_path / "case", seed=3)
    observations = Observations.load(observations_path)
    assert observations.num_frames == cc3_walk.num_frames and observations.fps == 60.0
    assert observations.image_size == (1280, 720) and observations.camera_K is not None
    with np.load(truth_path) as truth:
        assert tuple(truth["joint_names"]) == JOINT_NAMES
        assert truth["joints_world"].shape == cc3_walk.positions.shape
        for key in ("camera_K", "camera_R", "camera_t", "fps", "floor"):
            assert key in truth.files
    again, _ = write_synthetic_case(cc3_walk, tmp_path / "again", seed=3)
    np.testing.assert_array_equal(Observations.load(again).keypoints_2d, observations.keypoints_2d)
