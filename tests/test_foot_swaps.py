import numpy as np
import pytest

from physmocap.detect.foot_swaps import FOOT_LANDMARKS, find_foot_swaps, undo_foot_swaps
from physmocap.landmarks import MIRRORED
from physmocap.motion import Observations
from test_fit import camera, observe, walking_motion  # noqa: F401 - camera is a fixture


@pytest.fixture(scope="module")
def walk(body, camera):  # noqa: F811
    """Four seconds of walking past the camera, with detector-like jitter in 2D (1.5 px) and 3D (2 cm)."""
    obs = observe(body, walking_motion(body, 120), camera)
    rng = np.random.default_rng(4)
    seen = obs.keypoints_2d[..., 2] > 0
    obs.keypoints_2d[..., :2] += seen[..., None] * rng.normal(scale=1.5, size=obs.keypoints_2d[..., :2].shape)
    obs.landmarks_3d += seen[..., None] * rng.normal(scale=0.02, size=obs.landmarks_3d.shape)
    return obs


def mirrored(obs: Observations, frames: slice, landmarks: np.ndarray) -> Observations:
    """The observations with `landmarks` exchanged with their mirror images in `frames`, 2D and 3D."""
    k2, k3 = obs.keypoints_2d.copy(), obs.landmarks_3d.copy()
    k2[frames, landmarks], k3[frames, landmarks] = obs.keypoints_2d[frames, np.array(MIRRORED)[landmarks]], \
        obs.landmarks_3d[frames, np.array(MIRRORED)[landmarks]]
    return Observations(k2, k3, obs.fps, obs.image_size, camera_K=obs.camera_K)


def test_clean_walk_has_no_swaps(walk):
    assert not find_foot_swaps(walk).any()


def test_swapped_feet_are_found_and_undone(walk):
    episodes = (slice(20, 32), slice(70, 74))
    swapped = walk
    for frames in episodes:
        swapped = mirrored(swapped, frames, FOOT_LANDMARKS)
    found = find_foot_swaps(swapped)
    truth = np.zeros(walk.num_frames, dtype=bool)
    for frames in episodes:
        truth[frames] = True
    assert (found == truth).mean() > 0.97 and found[truth].mean() > 0.9
    undone = undo_foot_swaps(swapped, truth)
    assert np.array_equal(undone.keypoints_2d, walk.keypoints_2d)
    assert np.array_equal(undone.landmarks_3d, walk.landmarks_3d)


def test_whole_body_flip_is_not_a_foot_swap(walk):
    """A detector that takes the front for the back mirrors every landmark; the feet stay with their knees."""
    flipped = mirrored(walk, slice(40, 52), np.arange(33))
    assert not find_foot_swaps(flipped)[40:52].any()


def test_capture_reports_the_swapped_frames(walk, tmp_path):
    """The run's summary.json names the frames whose feet were swapped and undone, also from a cached fit."""
    from physmocap.config import Settings
    from physmocap.pipeline import run_capture

    path = tmp_path / "observations.npz"
    mirrored(walk, slice(20, 32), FOOT_LANDMARKS).save(path)
    for _ in range(2):  # the second run takes the fit from the cache
        summary = run_capture(tmp_path / "run", Settings().replace("body", height=1.75), observations=path)
        assert summary.foot_swap_frames == ["20-31"]
    assert "kinematics" in summary.cached_stages
