import numpy as np

from conftest import random_poses
from physmocap.body import kinematics as kin
from physmocap.body.model import build_body_model, template_lengths
from physmocap.kinematics.calibration import calibrate, measure_lengths
from physmocap.landmarks import LANDMARK_INDEX
from physmocap.motion import Observations

POINT_OF_LANDMARK = {
    "nose": "nose", "left_eye": "left_eye", "right_eye": "right_eye", "left_ear": "left_ear",
    "right_ear": "right_ear", "left_foot_index": "left_toe", "right_foot_index": "right_toe",
}


def landmarks_of(body, qpos):
    """Hip-relative landmarks (T, 33, 3) of the body model's own points."""
    pts = kin.forward_kinematics(body, qpos).points
    out = np.zeros((len(qpos), 33, 3))
    for name, i in LANDMARK_INDEX.items():
        point = POINT_OF_LANDMARK.get(name, name)
        if point in body.point_names:
            out[:, i] = pts[:, body.point_names.index(point)] - pts[:, 0]
    return out


def straight_spine(body, q):
    """The torso length is measured hip to shoulders: only a straight spine shows it whole."""
    a = body.qpos_address[body.joint_index["spine"]]
    q[:, a:a + 4] = [1.0, 0.0, 0.0, 0.0]
    return q


def test_lengths_measured_from_a_known_skeleton_are_recovered():
    lengths = template_lengths(1.8)
    body = build_body_model(lengths, 70)
    q = straight_spine(body, random_poses(body, 20, np.random.default_rng(0), scale=0.5))
    measured = measure_lengths(landmarks_of(body, q))
    for name, value in measured.items():
        if name in ("spine_low", "spine_up"):  # only their sum is observed
            continue
        assert abs(value - getattr(lengths, name)) < 1e-6, name
    assert abs(measured["spine_low"] + measured["spine_up"] - lengths.spine_low - lengths.spine_up) < 1e-6


def test_calibration_scales_to_the_given_height_and_rejects_implausible_lengths():
    body = build_body_model(template_lengths(1.6), 70)
    q = straight_spine(body, random_poses(body, 30, np.random.default_rng(1), scale=0.3))
    landmarks = 0.8 * landmarks_of(body, q)  # a detector that sees everyone 20% small
    landmarks[:, LANDMARK_INDEX["left_knee"]] *= 3.0  # and a broken left knee
    kp = np.zeros_like(landmarks)
    kp[..., 2] = 1.0
    calib = calibrate(Observations(kp, landmarks, 30.0, (640, 480)), height=1.85)
    assert abs(calib.lengths.standing_height - 1.85) < 1e-9
    assert "thigh" in calib.replaced and set(calib.replaced) <= {"thigh", "shank"}
    assert abs(calib.landmark_scale - 1.85 / 1.6 / 0.8) < 0.05
