"""Multi-view triangulation, left/right swap correction and the Qualisys calibration reader."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from benchmarks.multiview import MEDIAPIPE_SWAP_GROUPS, correct_left_right_swaps, triangulate
from benchmarks.qualisys import parse_qualisys_calibration, read_qualisys_calibration
from physmocap.camera import project_camera_points
from physmocap.landmarks import LANDMARK_INDEX, MIRRORED, NUM_LANDMARKS

QUALISYS_FILE = (Path(__file__).resolve().parents[1].parent / "shared" / "data" / "videos"
                 / "pose2sim_demo_singleperson" / "calibration" / "Calib.qca.txt")


def look_at(centre: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World -> camera (R, t) of an OpenCV camera at `centre` looking at `target`, world Z up."""
    forward = (target - centre) / np.linalg.norm(target - centre)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    return R, -R @ centre


def ring_of_cameras(views: int, radius: float = 4.0, focal: float = 1000.0):
    """Intrinsics, rotations and translations of `views` cameras on a circle around the origin, 1.5 m high."""
    K = np.array([[focal, 0.0, 540.0], [0.0, focal, 960.0], [0.0, 0.0, 1.0]])
    Ks, Rs, ts = [], [], []
    for angle in np.linspace(0.0, 2 * np.pi, views, endpoint=False) + 0.3:
        R, t = look_at(np.array([radius * np.cos(angle), radius * np.sin(angle), 1.5]), np.array([0.0, 0.0, 1.0]))
        Ks.append(K)
        Rs.append(R)
        ts.append(t)
    return Ks, Rs, ts


def observe(Ks, Rs, ts, points: np.ndarray, rng: np.random.Generator, noise_px: float = 0.0) -> np.ndarray:
    """(V, T, K, 3) pixel keypoints of (T, K, 3) points with confidences in 0.5..1 and Gaussian pixel noise."""
    views = []
    for K, R, t in zip(Ks, Rs, ts, strict=True):
        pixels = project_camera_points(K, points @ R.T + t) + rng.normal(scale=noise_px, size=points.shape[:-1] + (2,))
        confidence = rng.uniform(0.5, 1.0, size=points.shape[:-1] + (1,))
        views.append(np.concatenate([pixels, confidence], axis=-1))
    return np.stack(views)


def random_points(rng: np.random.Generator, frames: int = 5, count: int = 12) -> np.ndarray:
    return rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.8], size=(frames, count, 3))


@pytest.mark.parametrize("views", [3, 4, 6])
def test_noise_free_triangulation_is_exact(views):
    rng = np.random.default_rng(views)
    Ks, Rs, ts = ring_of_cameras(views)
    points = random_points(rng)
    recovered, errors = triangulate(Ks, Rs, ts, observe(Ks, Rs, ts, points, rng))
    assert recovered.shape == points.shape and errors.shape == points.shape[:2]
    assert np.abs(recovered - points).max() < 1e-9
    assert errors.max() < 1e-6


def test_noisy_triangulation_within_tolerance():
    rng = np.random.default_rng(1)
    Ks, Rs, ts = ring_of_cameras(4)
    points = random_points(rng, frames=50)
    recovered, errors = triangulate(Ks, Rs, ts, observe(Ks, Rs, ts, points, rng, noise_px=1.0))
    # 1 px at 1000 px focal length and about 4 m is 4 mm across a ray. Four views give 8 such constraints on 3
    # axes: about 4 mm / sqrt(8 / 3) = 2.5 mm per axis, and a mean 3D distance of about 1.6 times that, 4 mm.
    assert np.linalg.norm(recovered - points, axis=-1).mean() < 0.006
    assert 0.3 < errors.mean() < 1.5


def test_low_confidence_view_is_ignored_and_outlier_view_dropped():
    rng = np.random.default_rng(2)
    Ks, Rs, ts = ring_of_cameras(4)
    points = random_points(rng)
    keypoints = observe(Ks, Rs, ts, points, rng)
    garbage = rng.uniform(0.0, 1000.0, size=keypoints[1, ..., :2].shape)

    low_confidence = keypoints.copy()
    low_confidence[1, ..., :2] = garbage
    low_confidence[1, ..., 2] = 0.05
    recovered, _ = triangulate(Ks, Rs, ts, low_confidence, min_confidence=0.1)
    assert np.abs(recovered - points).max() < 1e-9

    confident_outlier = keypoints.copy()
    confident_outlier[1, ..., :2] = garbage
    plain, _ = triangulate(Ks, Rs, ts, confident_outlier)
    assert np.abs(plain - points).max() > 0.05  # the wrong view pulls the plain solution away
    robust, errors = triangulate(Ks, Rs, ts, confident_outlier, outlier_threshold_px=20.0)
    assert np.abs(robust - points).max() < 1e-9 and errors.max() < 1e-6


def test_points_seen_by_fewer_than_two_views_are_nan():
    rng = np.random.default_rng(3)
    Ks, Rs, ts = ring_of_cameras(3)
    points = random_points(rng, frames=2, count=3)
    keypoints = observe(Ks, Rs, ts, points, rng)
    keypoints[1:, 0, 0, 2] = 0.0  # point 0 of frame 0: only view 0 sees it
    recovered, errors = triangulate(Ks, Rs, ts, keypoints)
    assert np.isnan(recovered[0, 0]).all() and np.isnan(errors[0, 0])
    assert np.isfinite(recovered[0, 1:]).all() and np.isfinite(recovered[1]).all()


def test_distorted_keypoints_are_undistorted_before_triangulation():
    rng = np.random.default_rng(4)
    Ks, Rs, ts = ring_of_cameras(3)
    points = random_points(rng, frames=2)
    distortion = np.array([-0.2, 0.1, 0.001, -0.002, 0.0])
    views = []
    for K, R, t in zip(Ks, Rs, ts, strict=True):
        pixels, _ = cv2.projectPoints(points.reshape(-1, 3), cv2.Rodrigues(R)[0], t, K, distortion)
        views.append(np.concatenate([pixels.reshape(points.shape[:-1] + (2,)), np.ones(points.shape[:-1] + (1,))], -1))
    keypoints = np.stack(views)
    ignored, _ = triangulate(Ks, Rs, ts, keypoints)
    assert np.abs(ignored - points).max() > 1e-3
    recovered, _ = triangulate(Ks, Rs, ts, keypoints, distortion_list=[distortion] * 3)
    assert np.abs(recovered - points).max() < 1e-6


def test_left_right_swap_of_one_view_is_found_and_undone():
    rng = np.random.default_rng(5)
    Ks, Rs, ts = ring_of_cameras(4)
    # A person-sized cloud of 33 landmarks, left side at +x; noise of 2 px in every view.
    landmarks = rng.uniform([-0.3, -0.15, 0.0], [0.3, 0.15, 1.7], size=(1, NUM_LANDMARKS, 3))
    points = landmarks + np.linspace(0.0, 0.2, 8)[:, None, None] * np.array([1.0, 0.0, 0.0])
    keypoints = observe(Ks, Rs, ts, points, rng, noise_px=2.0)
    legs = np.array(MEDIAPIPE_SWAP_GROUPS["legs"])
    swapped_input = keypoints.copy()
    for frame in (3, 4, 5):
        swapped_input[2, frame, legs] = keypoints[2, frame, np.array(MIRRORED)[legs]]
    corrected, swapped = correct_left_right_swaps(Ks, Rs, ts, swapped_input)
    assert np.array_equal(corrected, keypoints)
    expected = np.zeros_like(swapped)
    expected[2, 3:6, 1] = True
    assert np.array_equal(swapped, expected)
    assert LANDMARK_INDEX["left_hip"] in legs and LANDMARK_INDEX["right_foot_index"] in legs

    # Two of four views swapped, view 0 among them: the views alone cannot tell which pair is right (keeping view
    # 0's labels would be wrong here); the previous frames decide.
    two_swapped = keypoints.copy()
    for view in (0, 3):
        for frame in (3, 4, 5):
            two_swapped[view, frame, legs] = keypoints[view, frame, np.array(MIRRORED)[legs]]
    corrected, swapped = correct_left_right_swaps(Ks, Rs, ts, two_swapped)
    assert np.array_equal(corrected, keypoints)
    expected = np.zeros_like(swapped)
    expected[[0, 3], 3:6, 1] = True
    assert np.array_equal(swapped, expected)


QUALISYS_XML = """<?xml version='1.0' encoding='ASCII'?>
<calibration type="regular">
  <cameras>
    <camera active="1" avg-residual="0.4" serial="front" viewrotation="0">
      <fov_video bottom="1919" left="8" right="1087" top="0"/>
      <transform x="1000.0" y="-2000.0" z="1500.0"
                 r11="1" r12="0" r13="0" r21="0" r22="0" r23="1" r31="0" r32="-1" r33="0"/>
      <intrinsic focalLengthU="64000" focalLengthV="64000" centerPointU="32512" centerPointV="61440"
                 radialDistortion1="-0.05" radialDistortion2="0.1" radialDistortion3="0"
                 tangentalDistortion1="0.001" tangentalDistortion2="0.002" skew="0"/>
    </camera>
    <camera active="0" serial="unused"/>
  </cameras>
</calibration>"""


def test_qualisys_reader_on_a_known_camera():
    (camera,) = parse_qualisys_calibration(QUALISYS_XML)
    # A camera at (1, -2, 1.5) m, level, looking along world +y: the rows of the Qualisys matrix are its right
    # (world +x), up (world +z) and backwards (world -y) axes. Intrinsics: 1000 px focal length, principal point
    # at sensor pixel (508, 960), i.e. (500, 960) of a video that starts at sensor column 8.
    assert camera.name == "front" and camera.image_size == (1080, 1920)
    assert np.allclose(camera.K, [[1000.0, 0.0, 500.0], [0.0, 1000.0, 960.0], [0.0, 0.0, 1.0]])
    assert np.allclose(camera.centre, [1.0, -2.0, 1.5]) and np.allclose(camera.optical_axis, [0.0, 1.0, 0.0])
    assert np.allclose(camera.distortion, [-0.05, 0.1, 0.001, 0.002, 0.0])
    ahead = np.array([[1.0, 2.0, 1.5], [1.5, 2.0, 1.5], [1.0, 2.0, 2.5]])  # 4 m ahead; 0.5 m right; 1 m up
    assert np.allclose(camera.camera().project(ahead), [[500.0, 960.0], [625.0, 960.0], [500.0, 710.0]])


def test_qualisys_reader_rejects_what_it_cannot_read():
    with pytest.raises(ValueError, match="not valid XML"):
        parse_qualisys_calibration("<calibration><cameras>")
    with pytest.raises(ValueError, match="viewrotation"):
        parse_qualisys_calibration(QUALISYS_XML.replace('viewrotation="0"', 'viewrotation="90"'))
    with pytest.raises(ValueError, match="not a rotation"):
        parse_qualisys_calibration(QUALISYS_XML.replace('r32="-1"', 'r32="1"'))
    with pytest.raises(ValueError, match="focalLengthV"):
        parse_qualisys_calibration(QUALISYS_XML.replace('focalLengthV="64000"', ""))


@pytest.mark.skipif(not QUALISYS_FILE.is_file(), reason="shared data not available")
def test_real_qualisys_calibration_cameras_surround_a_common_point():
    cameras = read_qualisys_calibration(QUALISYS_FILE)
    assert [c.name for c in cameras] == ["cam01", "cam02", "cam03", "cam04"]
    for camera in cameras:
        assert camera.image_size == (1088, 1920) and 1600 < camera.focal < 1750
        assert np.allclose(camera.R @ camera.R.T, np.eye(3)) and np.isclose(np.linalg.det(camera.R), 1.0)
        assert 1.5 < camera.centre[2] < 2.5 and camera.optical_axis[2] < 0  # mounted high, looking down
    centres = np.array([c.centre for c in cameras])
    spacing = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    assert spacing[~np.eye(4, dtype=bool)].min() > 2.0
    # The point nearest to all four optical axes (least squares) lies in front of every camera, near each axis.
    projectors = [np.eye(3) - np.outer(c.optical_axis, c.optical_axis) for c in cameras]
    common = np.linalg.solve(sum(projectors), sum(P @ c.centre for P, c in zip(projectors, cameras, strict=True)))
    for camera, projector in zip(cameras, projectors, strict=True):
        assert 2.0 < camera.R[2] @ common + camera.t[2] < 6.0
        assert np.linalg.norm(projector @ (common - camera.centre)) < 0.5
    assert 0.0 < common[2] < 1.5
