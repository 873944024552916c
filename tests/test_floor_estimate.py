"""The floor from the feet and the person's posture (kinematics.floor.estimate_floor): it agrees with the true floor,
reports its confidence, and when the feet's plane leans far from the posture it is not trusted, says so and
stays level with the posture instead of leaning the whole motion."""

import logging

import numpy as np
import pytest

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.camera import Camera, angle_degrees, robust_offset
from physmocap.kinematics import floor as floor_module
from physmocap.landmarks import LANDMARK_INDEX


def standing_and_travelling(body, frames, fps=30.0):
    """Standing straight with flat feet while gliding along a curve and turning, arms swinging: the soles stay
    on one plane, spread over a few metres."""
    t = np.arange(frames) / fps
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    step = np.zeros((frames, body.nv))
    step[:, 5] = 0.4 * t  # turn about z
    for side, sign in (("left", 1.0), ("right", -1.0)):
        step[:, body.dof_address[body.joint_index[f"{side}_shoulder"]]] = sign * (1.2 + 0.3 * np.sin(3 * t))
    q = kin.integrate(body, q, step)
    q[:, 0] += 0.8 * t
    q[:, 1] += 0.5 * np.sin(t)
    return q


@pytest.fixture(scope="module")
def scene():
    body = build_body_model(template_lengths(1.7), 70.0)
    cam = Camera.from_settings((1280, 720), fov=60)
    pitch = np.radians(12)
    R = np.array([[1, 0, 0], [0, -np.sin(pitch), -np.cos(pitch)], [0, np.cos(pitch), -np.sin(pitch)]])
    camera = cam.with_extrinsics(R, -R @ np.array([0.5, -4.0, 1.3]))
    qpos = standing_and_travelling(body, 90)
    soles = kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)]
    qpos[:, 2] -= soles[..., 2].min()  # the lowest sole point of the clip on the floor z = 0
    return body, camera, qpos


def rotate_about_x(v, degrees):
    a = np.radians(degrees)
    R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return R @ v


def test_floor_of_a_walk_is_the_true_floor_and_trusted(scene):
    body, camera, qpos = scene
    floor = floor_module.estimate_floor(body, qpos, camera, 30.0, np.ones(len(qpos), bool))
    assert angle_degrees(floor.normal, camera.R[:, 2]) < 2.0
    assert floor.trusted and floor.source == "feet and posture"
    assert floor.inlier_fraction > 0.9 and 0.0 <= floor.tilt_spread < 2.0
    assert np.isfinite(floor.prior_disagreement) and floor.prior_disagreement < floor_module.FLOOR_AGREEMENT


def test_a_posture_that_leans_a_little_is_outweighed_by_the_feet(scene, monkeypatch):
    body, camera, qpos = scene
    leaning = rotate_about_x(camera.R[:, 2], 4.0)
    monkeypatch.setattr(floor_module, "posture_vertical", lambda *args: leaning)
    floor = floor_module.estimate_floor(body, qpos, camera, 30.0, np.ones(len(qpos), bool))
    assert floor.trusted
    assert angle_degrees(floor.normal, camera.R[:, 2]) < angle_degrees(leaning, camera.R[:, 2]) - 1.0


def test_feet_far_from_the_posture_are_not_trusted_and_the_floor_stays_level_with_it(scene, monkeypatch, caplog):
    """Contact points that put the floor 20 degrees from the person's vertical (feet on the wrong points, a wrong
    depth) must not lean the whole motion: the floor follows the posture, a warning says so."""
    body, camera, qpos = scene
    posture = rotate_about_x(camera.R[:, 2], 20.0)
    monkeypatch.setattr(floor_module, "posture_vertical", lambda *args: posture)
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        floor = floor_module.estimate_floor(body, qpos, camera, 30.0, np.ones(len(qpos), bool))
    assert not floor.trusted and floor.source == "posture"
    assert angle_degrees(floor.normal, posture) < 1e-6
    assert floor.prior_disagreement > floor_module.FLOOR_AGREEMENT
    assert any("cannot be trusted" in r.message for r in caplog.records)


def test_posture_vertical_of_a_walk_is_near_the_true_vertical(scene):
    body, camera, qpos = scene
    up = floor_module.posture_vertical(body, qpos, camera, np.ones(len(qpos), bool))
    assert angle_degrees(up, camera.R[:, 2]) < 5.0


def kicking_back(body, frames, fps=30.0):
    """A caricature of a run: at 3 m/s along x, standing on one foot while the other is kicked up behind
    (0.8 m up, 0.5 m back), the legs swapping every 10 frames."""
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    step = np.zeros((frames, body.nv))
    kicking = (np.arange(frames) // 10) % 2
    for i, side in enumerate(("left", "right")):
        step[:, body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = 0.6 * (kicking == i)
        step[:, body.dof_address[body.joint_index[f"{side}_knee"]]] = 1.8 * (kicking == i)
    q = kin.integrate(body, q, step)
    q[:, 0] += 3.0 * np.arange(frames) / fps
    soles = kin.forward_kinematics(body, q).points[:, body.point_index(CONTACT_POINTS)]
    q[:, 2] -= soles[..., 2].min()
    return q


def test_a_runners_trailing_foot_does_not_lean_the_posture_or_the_floor(scene):
    """The middle of all four sole points trails a runner (the kicked-up foot), so the axis from it to the
    centre of mass leans forward; the axis from the support (the lowest points) does not, and the feet's floor
    is kept and trusted."""
    body, camera, _ = scene
    qpos = kicking_back(body, 60)
    valid = np.ones(len(qpos), bool)
    soles = camera.to_camera(kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)])
    up = camera.R[:, 2]
    middle = floor_module.posture_vertical(body, qpos, camera, valid)
    support = floor_module.posture_vertical(body, qpos, camera, valid, floor_module.lowest_points(soles, up, valid))
    assert angle_degrees(middle, up) > 15.0 and angle_degrees(support, up) < 8.0
    floor = floor_module.estimate_floor(body, qpos, camera, 30.0, valid)
    assert floor.trusted and angle_degrees(floor.normal, up) < 2.0


def test_robust_offset_ignores_a_few_points_far_off_the_plane():
    rng = np.random.default_rng(0)
    normal = np.array([0.0, -0.9, 0.3])
    normal /= np.linalg.norm(normal)
    points = rng.normal(size=(200, 3))
    points -= np.outer(points @ normal + 1.5, normal)  # on the plane normal . x + 1.5 = 0
    points[:20] += 0.5 * normal  # a lifted foot
    assert robust_offset(points, normal) == pytest.approx(1.5, abs=0.01)


def test_a_lone_detection_far_behind_the_person_is_no_evidence_of_the_floor(scene):
    """A single valid frame between frames without a person (held at its pose, as the online warm-up holds its
    first one), 8 m deeper and 1.5 m lower than the person who then walks in: its feet have no measured speed,
    are not taken as resting on the floor, and do not lean the floor."""
    body, camera, walk = scene
    lone = walk[:1].copy()
    lone[:, 1] += 8.0  # away from the camera, which looks along +y
    lone[:, 2] -= 1.5
    qpos = np.concatenate([np.repeat(lone, 10, axis=0), walk[:30]])
    valid = np.zeros(len(qpos), bool)
    valid[5] = valid[10:] = True
    floor = floor_module.estimate_floor(body, qpos, camera, 30.0, valid)
    assert floor.trusted and angle_degrees(floor.normal, camera.R[:, 2]) < 2.0


def test_feet_outside_the_picture_are_no_evidence_of_the_floor(scene):
    """The first half of a walk with its feet fitted 0.3 m under the floor where the detector placed them below
    the picture's edge: given which sole points were seen, the floor is the seen feet's; without, it is not."""
    body, camera, qpos = scene
    qpos = qpos.copy()
    qpos[:45, 2] -= 0.3
    seen = np.ones((len(qpos), 4), bool)
    seen[:45] = False
    valid = np.ones(len(qpos), bool)
    guessed = floor_module.estimate_floor(body, qpos, camera, 30.0, valid)
    floor = floor_module.estimate_floor(body, qpos, camera, 30.0, valid, seen)
    soles = camera.to_camera(kin.forward_kinematics(body, qpos[45:]).points[:, body.point_index(CONTACT_POINTS)])
    assert np.abs(soles.reshape(-1, 3) @ floor.normal + floor.offset).min() < 0.01
    assert floor.inlier_fraction > 0.9 and guessed.inlier_fraction < floor.inlier_fraction


def test_a_sole_point_is_seen_inside_the_picture_with_confidence():
    keypoints = np.zeros((3, 33, 3))
    keypoints[..., :2] = (100.0, 200.0)
    keypoints[..., 2] = 0.9
    keypoints[1, LANDMARK_INDEX["right_heel"], 1] = 481.0  # below a 640 x 480 picture
    keypoints[2, LANDMARK_INDEX["left_foot_index"], 2] = 0.05  # inside, unsure: its ankle decides
    keypoints[2, LANDMARK_INDEX["left_ankle"], 0] = -5.0  # left of the picture
    seen = floor_module.seen_sole_points(keypoints, (640, 480), 0.1)
    assert seen.tolist() == [[True] * 4, [True, True, False, True], [True, False, True, True]]


def test_feet_never_seen_give_a_floor_that_is_not_trusted(scene, caplog):
    body, camera, qpos = scene
    valid = np.ones(len(qpos), bool)
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        floor = floor_module.estimate_floor(body, qpos, camera, 30.0, valid, np.zeros((len(qpos), 4), bool))
    as_if_seen = floor_module.estimate_floor(body, qpos, camera, 30.0, valid)
    assert not floor.trusted and floor.source == "unseen feet"
    assert np.array_equal(floor.plane, as_if_seen.plane) and as_if_seen.trusted
    assert any("outside the picture" in r.message for r in caplog.records)


def test_a_detector_without_feet_keypoints_sees_the_soles_by_the_ankles():
    """COCO's 17 joints have no heel or toe (NaN in an observations file): the soles count as seen where their
    ankle is inside the picture."""
    keypoints = np.full((2, 33, 3), np.nan)
    for side in ("left", "right"):
        keypoints[:, LANDMARK_INDEX[f"{side}_ankle"]] = (300.0, 400.0, 0.8)
    keypoints[1, LANDMARK_INDEX["left_ankle"], 1] = 500.0  # below a 640 x 480 picture
    seen = floor_module.seen_sole_points(keypoints, (640, 480), 0.1)
    assert seen.tolist() == [[True] * 4, [False, False, True, True]]


def test_seen_points_lowest_along_the_first_vertical_only_give_the_unseen_feet_floor(scene, monkeypatch):
    """The one seen sole point rests on the floor along the posture's first guess, but along the vertical that
    estimate_floor settles on it is not among the lowest: no floor point is left, and the floor is the fitted
    feet's, untrusted (not a fit to no points)."""
    body, camera, qpos = scene
    up, tilted = camera.R[:, 2], rotate_about_x(camera.R[:, 2], 60.0)
    calls = iter(range(1000))
    monkeypatch.setattr(floor_module, "posture_vertical", lambda *args: up if next(calls) == 0 else tilted)
    soles = camera.to_camera(kin.forward_kinematics(body, qpos[:1]).points[0, body.point_index(CONTACT_POINTS)])
    seen = np.zeros((len(qpos), 4), bool)
    seen[0, np.argmax(soles @ tilted)] = True
    floor = floor_module.estimate_floor(body, qpos, camera, 30.0, np.ones(len(qpos), bool), seen)
    assert floor.source == "unseen feet" and not floor.trusted and np.isfinite(floor.plane).all()
