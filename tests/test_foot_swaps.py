import numpy as np
import pytest

from physmocap.body import kinematics as kin
from physmocap.detect.foot_swaps import FOOT_LANDMARKS, CausalFootSwaps, find_foot_swaps, undo_foot_swaps
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


@pytest.mark.slow
@pytest.mark.parametrize("online", [False, True])
def test_capture_reports_the_swapped_frames(walk, tmp_path, online):
    """The run's summary.json names and counts the frames whose feet were swapped and undone, offline and online
    (in the warm-up and after it), also from a cached fit."""
    import json

    from physmocap.config import Settings
    from physmocap.pipeline import run_capture

    path = tmp_path / "observations.npz"
    mirrored(mirrored(walk, slice(20, 32), FOOT_LANDMARKS), slice(100, 110), FOOT_LANDMARKS).save(path)
    for _ in range(2):  # the second run takes the fit from the cache
        summary = run_capture(tmp_path / "run", Settings(online=online).replace("body", height=1.75),
                              observations=path)
        assert summary.foot_swap_frames == ["20-31", "100-109"]
        assert json.loads((tmp_path / "run" / "summary.json").read_text())["foot_swap_frame_count"] == 22
    assert "kinematics" in summary.cached_stages


@pytest.mark.slow
def test_terminal_summary_counts_the_swapped_frames(walk, tmp_path, capsys):
    from physmocap.cli import main

    path = tmp_path / "observations.npz"
    mirrored(walk, slice(100, 110), FOOT_LANDMARKS).save(path)
    assert main(["capture", "--observations", str(path), "-o", str(tmp_path / "run"), "--online", "--physics",
                 "none", "--height", "1.75", "--no-overlay"]) == 0
    assert "swapped the left and right feet on 10 frames" in capsys.readouterr().out


def test_online_capture_of_a_video_reports_the_swapped_frames(tmp_path, monkeypatch):
    """Online, a video is detected and fitted as a stream (live's loop): its summary counts the frames read
    swapped too (it reported none: the stream's motion did not carry them)."""
    from conftest import DEMO_VIDEO
    from physmocap.config import Settings
    from physmocap.pipeline import run_capture

    monkeypatch.setattr(CausalFootSwaps, "update", lambda self, keypoints, landmarks, valid: True)
    settings = Settings(online=True).replace("physics", method="none").replace("body", calibration_frames=30)
    summary = run_capture(tmp_path / "run", settings, video=DEMO_VIDEO, overlay=False)
    assert summary.foot_swap_frame_count >= summary.frames - 30  # every frame after the warm-up


def test_causal_reading_finds_a_swap_from_the_past_alone_and_reads_a_gap_as_detected(walk):
    """Decoded forward, the clip's model of foot swaps finds an episode as it happens (frame by frame, the
    detections alone), reads a clean walk as detected, and starts again from the detected reading after frames
    without the person, as the whole clip's decision does."""
    swapped = mirrored(walk, slice(100, 110), FOOT_LANDMARKS)
    valid = np.ones(walk.num_frames, bool)
    valid[60:66] = False

    def causal(obs):
        reading = CausalFootSwaps(obs.image_size[1])
        return np.array([reading.update(obs.keypoints_2d[t], obs.landmarks_3d[t], bool(valid[t]))
                         for t in range(obs.num_frames)])

    assert not causal(walk).any()
    found = causal(swapped)
    assert found[101:110].all() and not found[:100].any() and not found[111:].any()
    held = CausalFootSwaps(walk.image_size[1])
    for t in range(100, 105):  # a swapped reading, then the person unseen for a frame
        held.update(swapped.keypoints_2d[t], swapped.landmarks_3d[t], True)
    held.update(walk.keypoints_2d[105], walk.landmarks_3d[105], False)
    assert not held.update(walk.keypoints_2d[106], walk.landmarks_3d[106], True)


def test_swaps_of_a_detector_without_heels_or_toes_are_found_on_its_ankles(walk, tmp_path):
    """An observations file from a detector with the 17 COCO joints has no heel or toe (NaN there, read as unseen
    points at the origin): those points weigh the same in both readings, so the ankles alone decide, offline
    and causally, and nothing warns."""
    import warnings

    from physmocap.landmarks import LANDMARK_INDEX

    swapped = mirrored(walk, slice(40, 52), FOOT_LANDMARKS)
    k2, k3 = swapped.keypoints_2d.copy(), swapped.landmarks_3d.copy()
    for name in ("left_heel", "right_heel", "left_foot_index", "right_foot_index"):
        k2[:, LANDMARK_INDEX[name]] = np.nan
        k3[:, LANDMARK_INDEX[name]] = np.nan
    path = tmp_path / "coco.npz"
    np.savez(path, keypoints_2d=k2, landmarks_3d=k3, fps=walk.fps, image_size=np.array(walk.image_size))
    coco = Observations.load(path)
    truth = np.zeros(walk.num_frames, bool)
    truth[40:52] = True
    reading = CausalFootSwaps(coco.image_size[1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        found = find_foot_swaps(coco)
        causal = np.array([reading.update(coco.keypoints_2d[t], coco.landmarks_3d[t], True)
                           for t in range(coco.num_frames)])
    assert np.array_equal(found, truth)
    assert causal[41:52].all() and causal.sum() <= 13


@pytest.mark.slow
def test_online_fit_reads_swapped_feet_the_right_way_round(body, walk):
    """Swaps inside the warm-up (found as offline) and after it (causal check against the predicted pose): the
    online fit's ankles stay where the clean detections put them."""
    from physmocap.config import Settings
    from physmocap.kinematics.stage import fit_motion

    swapped = mirrored(mirrored(walk, slice(20, 32), FOOT_LANDMARKS), slice(100, 110), FOOT_LANDMARKS)
    settings = Settings(online=True).replace("body", height=body.height, mass=body.mass)

    def ankles(obs, undo=True):
        motion = fit_motion(obs, settings.replace("fit", undo_foot_swaps=undo))
        points = kin.forward_kinematics(motion.body, motion.qpos).points
        return points[:, motion.body.point_index(["left_ankle", "right_ankle"])]

    clean = ankles(walk)
    undone = np.linalg.norm(ankles(swapped) - clean, axis=-1)
    kept = np.linalg.norm(ankles(swapped, undo=False) - clean, axis=-1)
    for frames in (slice(20, 32), slice(100, 110)):
        assert undone[frames].max() < 0.03 and kept[frames].max() > 0.1
