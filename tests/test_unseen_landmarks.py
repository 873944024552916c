"""Observations files from other detectors: landmarks a detector does not provide (NaN, or confidence 0) carry
no weight anywhere (calibration, both data terms of the fit, the contact features), calibration never makes a
degenerate segment, and `capture --observations` completes with a head above the neck and finite outputs."""

import dataclasses
import json

import numpy as np
import pytest

from physmocap.body.model import TEMPLATE_RATIOS, build_body_model, template_lengths
from physmocap.camera import Camera
from physmocap.config import FitSettings
from physmocap.contacts.features import FEATURE_LANDMARKS, select_keypoints
from physmocap.contacts.predict import predict_contacts
from physmocap.kinematics.calibration import OFFSETS, calibrate, estimate_height, height_line, resolve_height
from physmocap.kinematics.fit import MARKERS, initial_qpos
from physmocap.kinematics.targets import make_targets
from physmocap.landmarks import LANDMARK_INDEX, LANDMARK_NAMES
from physmocap.motion import Observations
from physmocap.result import load_result
from test_cli import physmocap
from test_fit import observe, walking_motion

COCO_17 = ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
           "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
           "right_knee", "left_ankle", "right_ankle")
NOT_COCO = [i for i, name in enumerate(LANDMARK_NAMES) if name not in COCO_17]
TORSO = [LANDMARK_INDEX[n] for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")]


@pytest.fixture(scope="module")
def camera():
    cam = Camera.from_settings((1280, 720), fov=60)
    pitch = np.radians(8)
    R = np.array([[1, 0, 0], [0, -np.sin(pitch), -np.cos(pitch)], [0, np.cos(pitch), -np.sin(pitch)]])
    return cam.with_extrinsics(R, -R @ np.array([0.5, -4.0, 1.2]))


@pytest.fixture(scope="module")
def walker(camera):
    body = build_body_model(template_lengths(1.62), 60.0)
    return body, observe(body, walking_motion(body, 45), camera)


def without(obs: Observations, landmarks, frames=slice(None)) -> Observations:
    """The observations with the given landmarks NaN (2D, confidence and 3D) in the given frames."""
    k2, k3 = obs.keypoints_2d.copy(), obs.landmarks_3d.copy()
    index = np.ix_(np.arange(obs.num_frames)[frames], landmarks)
    k2[index] = np.nan
    k3[index] = np.nan
    return Observations(k2, k3, obs.fps, obs.image_size, camera_K=obs.camera_K, source="test")


def saved_and_loaded(obs: Observations, path) -> Observations:
    np.savez(path, keypoints_2d=obs.keypoints_2d, landmarks_3d=obs.landmarks_3d, fps=obs.fps,
             image_size=np.array(obs.image_size), camera_K=obs.camera_K)
    return Observations.load(path)


def test_loading_marks_nan_landmarks_unseen_and_keeps_the_frames(walker, tmp_path):
    _, obs = walker
    loaded = saved_and_loaded(without(obs, NOT_COCO), tmp_path / "coco.npz")
    assert np.isfinite(loaded.keypoints_2d).all() and np.isfinite(loaded.landmarks_3d).all()
    assert (loaded.keypoints_2d[:, NOT_COCO, 2] == 0).all() and loaded.valid.all()


def test_calibration_ignores_unseen_landmarks_and_never_makes_a_degenerate_segment(walker, tmp_path):
    body, obs = walker
    full = calibrate(obs, 1.62, frames=0)
    coco = calibrate(saved_and_loaded(without(obs, NOT_COCO), tmp_path / "coco.npz"), 1.62, frames=0)
    # The lengths COCO's joints show are measured as from the full set; heels, toes and hands fall back to the
    # template's proportions and say so.
    for name in ("thigh", "shank", "upper_arm", "forearm", "shoulder_width", "hip_width", "head_height"):
        assert abs(getattr(coco.lengths, name) - getattr(full.lengths, name)) < 0.01 * 1.62, name
    assert {"heel_back", "toe_front", "hand_length", "hand_width"} <= set(coco.replaced)
    template = template_lengths(1.62)
    for name in ("toe_front", "hand_length", "hand_width"):
        assert getattr(coco.lengths, name) == pytest.approx(getattr(template, name), rel=0.1)
    for name, ratio in TEMPLATE_RATIOS.items():
        if ratio > 0 and name not in OFFSETS:
            assert getattr(coco.lengths, name) > 0.4 * ratio * 1.62, name
    assert np.isfinite(coco.landmark_scale) and coco.height == 1.62


def test_a_limb_seen_on_one_side_only_is_measured_from_that_side(walker):
    _, obs = walker
    full = calibrate(obs, 1.62, frames=0)
    one_sided = calibrate(without(obs, [LANDMARK_INDEX[n] for n in ("right_knee", "right_elbow")]), 1.62, frames=0)
    for name in ("thigh", "shank", "upper_arm", "forearm"):
        assert name not in one_sided.replaced
        assert abs(getattr(one_sided.lengths, name) - getattr(full.lengths, name)) < 0.01, name


def test_zero_width_segments_fall_back_to_the_template(walker):
    """A detector that puts both eyes (or both hips) on one point must not make a zero-width head or pelvis."""
    _, obs = walker
    k3 = obs.landmarks_3d.copy()
    k3[:, LANDMARK_INDEX["right_eye"]] = k3[:, LANDMARK_INDEX["left_eye"]]
    k3[:, LANDMARK_INDEX["right_hip"]] = k3[:, LANDMARK_INDEX["left_hip"]]
    calibration = calibrate(Observations(obs.keypoints_2d, k3, obs.fps, obs.image_size), 1.62, frames=0)
    assert {"eye_width", "hip_width"} <= set(calibration.replaced)
    assert calibration.lengths.eye_width > 0.01 and calibration.lengths.hip_width > 0.15


def test_unseen_landmarks_weigh_nothing_in_either_data_term(walker, camera, tmp_path):
    _, obs = walker
    loaded = saved_and_loaded(without(obs, NOT_COCO), tmp_path / "coco.npz")
    calibration = calibrate(loaded, 1.62, frames=0)
    targets = make_targets(loaded.keypoints_2d, loaded.landmarks_3d, loaded.valid, np.full(45, 4.0), camera,
                           calibration, FitSettings())
    unseen = [i for i, (landmark, _) in enumerate(MARKERS) if landmark not in COCO_17]
    seen = [i for i, (landmark, _) in enumerate(MARKERS) if landmark in COCO_17]
    assert (targets.weight_2d[:, unseen] == 0).all() and (targets.weight_3d[:, unseen] == 0).all()
    assert (targets.weight_2d[:, seen] > 0).all() and (targets.weight_3d[:, seen] > 0).all()


def test_a_first_frame_without_torso_starts_from_the_nearest_frame_that_shows_one(walker, camera):
    body, obs = walker
    targets = make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, np.full(45, 4.0), camera,
                           calibrate(obs, 1.62), FitSettings())
    start = initial_qpos(body, camera, targets, 5)
    for array in (targets.weight_3d, targets.weight_2d, targets.targets_3d, targets.keypoints):
        array[:3] = 0.0  # as a loaded file holds what nobody saw
    q = initial_qpos(body, camera, targets, 0)
    assert np.isfinite(q).all()
    assert abs(np.dot(q[0, 3:7], start[0, 3:7])) > 0.95  # the nearest seen frame's orientation, about


def test_contact_features_fill_unseen_points_and_predictions_stay_finite(walker, tmp_path):
    _, obs = walker
    loaded = saved_and_loaded(without(obs, NOT_COCO), tmp_path / "coco.npz")
    points = select_keypoints(loaded.keypoints_2d, loaded.valid)
    heel, ankle = FEATURE_LANDMARKS.index("left_heel"), FEATURE_LANDMARKS.index("left_ankle")
    assert np.allclose(points[:, heel, :2], points[:, ankle, :2]) and (points[:, heel, 2] == 0).all()
    # A point unseen in some frames takes its nearest seen frame's position.
    gappy = without(obs, [LANDMARK_INDEX["left_knee"]], slice(10, 14))
    filled = select_keypoints(gappy.keypoints_2d, gappy.valid)
    knee = FEATURE_LANDMARKS.index("left_knee")
    assert np.allclose(filled[10:12, knee, :2], obs.keypoints_2d[9, LANDMARK_INDEX["left_knee"], :2], atol=1e-3)
    assert (filled[10:14, knee, 2] == 0).all()
    for mode in ("causal", "centred"):
        contacts, stationary, probabilities = predict_contacts(loaded, mode)
        assert np.isfinite(probabilities).all() and contacts.shape == (45, 4)


def test_height_estimate_reads_the_detector_metric_landmarks(walker, tmp_path):
    body, obs = walker
    estimate = estimate_height(obs)
    assert abs(estimate.height - body.height) < 0.03 and estimate.frames > 0
    coco = estimate_height(saved_and_loaded(without(obs, NOT_COCO), tmp_path / "coco.npz"))
    assert abs(coco.height - body.height) < 0.05


def test_the_height_is_estimated_only_when_asked_and_every_run_can_say_which(walker):
    _, obs = walker
    assert resolve_height(obs, 1.70, False) == (1.70, "given")
    height, source = resolve_height(obs, 1.70, True)
    assert source == "estimated" and abs(height - 1.62) < 0.03
    blind = Observations(np.zeros_like(obs.keypoints_2d), obs.landmarks_3d, obs.fps, obs.image_size)
    assert resolve_height(blind, 1.70, True) == (1.70, "given")  # nothing seen: the given height stays
    line = height_line(calibrate(obs, 1.70), default_height=1.70)
    assert "1.70 m assumed" in line and "--height" in line
    estimated = dataclasses.replace(calibrate(obs, height), height_source=source)
    assert "estimated" in height_line(estimated, default_height=1.70)


def _result_of_capture(obs_path, out):
    proc = physmocap("capture", "--observations", obs_path, "-o", out, "--no-overlay", "--physics", "none",
                     "--height", "1.62")
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    result = load_result(out / "result.npz")
    for key, value in result.items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f":
            assert np.isfinite(value).all(), key
    names = list(result["joint_names"])
    head, neck = result["joints_world"][:, names.index("head"), 2], result["joints_world"][:, names.index("neck"), 2]
    assert (head > neck + 0.05).all()
    confidence = json.loads(str(result["floor_confidence"]))
    assert bool(result["floor_trusted"]) == confidence["trusted"] and 0 <= confidence["inlier_fraction"] <= 1
    return result, json.loads((out / "summary.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("case", ["coco_17", "half_missing_first_frames_without_torso"])
def test_capture_from_another_detectors_observations(walker, tmp_path, case):
    _, obs = walker
    if case == "coco_17":
        changed = without(obs, NOT_COCO)
    else:
        rng = np.random.default_rng(0)
        changed = without(obs, list(rng.choice(33, 16, replace=False)))
        changed = without(changed, TORSO, slice(0, 3))
    path = tmp_path / "obs.npz"
    saved_and_loaded(changed, path)
    result, summary = _result_of_capture(path, tmp_path / "out")
    assert summary["valid_frames"] == 45
