"""The physics' held feet planted on their spots (dynamics/planting.py). Offline (`leashed_spots`,
`plant_held_feet`): a contact that drifts within the reach stands still, one that drifts farther slides only by the
excess, frames without a planted or easing point and frozen frames are left exactly as they were, a point eases
onto and off its spot without a jump, and the spot is where the kinematic input stood the foot relative to the
pelvis. Online (`OutputPlanter`): the same causally, the body following its feet."""

from __future__ import annotations

import numpy as np

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.contacts.flights import ease_frames, edge_easing
from physmocap.dynamics.planting import LegMover, OutputPlanter, leashed_spots, plant_held_feet

FPS = 30.0


def test_a_point_eases_towards_the_nearer_contact_with_that_contact_s_weight():
    assert [ease_frames(fps) for fps in (8, 10, 24, 30, 60, 120)] == [1, 1, 2, 3, 6, 12]  # 0.1 s at any rate
    held = np.zeros((14, 1), bool)
    held[2:5, 0] = held[10:12, 0] = True  # frames 5-9 lie between the two contacts; 0-1 and 12-13 beside one
    weights, edges = edge_easing(held, 30.0)  # 3 frames
    np.testing.assert_allclose(weights[:, 0], [0.5, 0.75, 1, 1, 1, 0.75, 0.5, 0.25, 0.5, 0.75, 1, 1, 0.75, 0.5])
    # Held frames take their own value; frame 7, as near to both edges (3 frames), takes the earlier contact's.
    assert edges[:, 0].tolist() == [2, 2, 2, 3, 4, 4, 4, 4, 10, 10, 10, 11, 11, 11]
    weights, edges = edge_easing(held, 10.0)  # 1 frame
    assert weights[7, 0] == 0.0 and edges[7, 0] == -1 and edges[5, 0] == 4 and weights[5, 0] == 0.5


def test_spots_stay_within_reach_and_still_when_the_drift_is_small():
    small = np.stack([np.linspace(0.0, 0.015, 20), np.zeros(20)], axis=1)
    spots = leashed_spots(small, 0.02)
    assert np.allclose(spots, [0.0075, 0.0])  # one spot, the middle of the path
    large = np.stack([np.linspace(0.0, 0.2, 30), np.linspace(0.0, -0.05, 30)], axis=1)
    spots = leashed_spots(large, 0.02)
    assert np.linalg.norm(spots - large, axis=1).max() <= 0.02 + 1e-12
    travelled = np.linalg.norm(np.diff(spots, axis=0), axis=1).sum()
    path = np.linalg.norm(np.diff(large, axis=0), axis=1).sum()
    assert travelled <= path - 0.02 + 1e-9  # each end starts half the reach along the path


def gliding_stance(frames: int, speed: float) -> tuple:
    """A standing body whose whole pose glides along x at `speed` m/s (its feet with it), the body model, and
    every contact point held from frame 10 to frame frames - 10."""
    body = build_body_model(template_lengths(1.70), 70.0)
    qpos = np.tile(body.rest_qpos, (frames, 1))
    qpos[:, 2] -= kin.forward_kinematics(body, body.rest_qpos[None]).points[0, body.point_index(CONTACT_POINTS),
                                                                           2].min()
    qpos[:, 0] += speed * np.arange(frames) / FPS
    contacts = np.zeros((frames, 4), bool)
    contacts[10:frames - 10] = True
    return body, qpos, contacts


def foot_points(body, qpos: np.ndarray) -> np.ndarray:
    return kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)]


def test_a_drift_within_reach_is_planted_and_far_frames_are_untouched():
    body, qpos, contacts = gliding_stance(50, 0.02)  # 2 cm/s: 2 cm over the 30 held frames
    planted = plant_held_feet(body, qpos, contacts, FPS, 0.03, np.zeros(50, bool), qpos)
    points = foot_points(body, planted)[10:40]
    assert np.abs(points - points[0]).max() < 1e-3  # every held point stands still
    assert np.array_equal(planted[:6], qpos[:6]) and np.array_equal(planted[44:], qpos[44:])  # beyond the ease
    assert np.isfinite(planted).all()


def test_a_long_drift_slides_by_the_excess_and_eases_without_a_jump():
    body, qpos, contacts = gliding_stance(60, 0.3)  # 30 cm/s: 12 cm over the 40 held frames
    before = foot_points(body, qpos)
    planted = plant_held_feet(body, qpos, contacts, FPS, 0.02, np.zeros(60, bool), qpos)
    after = foot_points(body, planted)
    assert np.abs(after[10:50, :, :2] - before[10:50, :, :2]).max() < 0.02 + 2e-3  # within the reach (+ IK)
    step = np.linalg.norm(np.diff(after[..., :2], axis=0), axis=-1)
    glide = 0.3 / FPS * 39  # m, each point's path over the held frames
    assert (step[10:49].sum(axis=0) < glide - 0.02 + 2e-3).all()  # half the reach taken off at each end
    assert step.max() < 2 * 0.3 / FPS  # easing on and off: no jump beyond twice a frame's glide


def test_frozen_frames_are_left_as_they_were():
    body, qpos, contacts = gliding_stance(50, 0.3)
    frozen = np.zeros(50, bool)
    frozen[20:30] = True
    planted = plant_held_feet(body, qpos, contacts, FPS, 0.02, frozen, qpos)
    assert np.array_equal(planted[20:30], qpos[20:30])
    assert not np.array_equal(planted[12:18], qpos[12:18])  # the contacts beside them are planted


def test_a_foot_is_planted_where_the_input_stood_it_relative_to_the_pelvis():
    """The output's left foot landed 4 cm ahead of its input's (the tracker's overshoot): it is planted back on the
    input's spot. A whole output 3 cm ahead of its input (pelvis and feet) keeps its feet where they are."""
    body, reference, contacts = gliding_stance(50, 0.0)
    mover = LegMover(body.mujoco_model())
    mover.contact_points(reference[0])
    ahead = mover.moved(reference[0], [[0.04, 0.0], [0.04, 0.0], [0.0, 0.0], [0.0, 0.0]])
    overshot = np.tile(ahead, (50, 1))
    assert np.abs(foot_points(body, overshot)[25, :2, 0] - foot_points(body, reference)[25, :2, 0] - 0.04).max() < 2e-3
    planted = plant_held_feet(body, overshot, contacts, FPS, 0.02, np.zeros(50, bool), reference)
    on_spot = foot_points(body, planted)[10:40, :, :2] - foot_points(body, reference)[10:40, :, :2]
    assert np.abs(on_spot).max() < 2e-3
    shifted = reference.copy()
    shifted[:, 0] += 0.03
    kept = plant_held_feet(body, shifted, contacts, FPS, 0.02, np.zeros(50, bool), reference)
    assert np.abs(foot_points(body, kept) - foot_points(body, shifted)).max() < 1e-6


def test_online_output_planter_holds_causally_and_lets_go_smoothly():
    """OutputPlanter (online): a standing body that glides 1.75 cm while its feet are held has them stand where
    they touched down (the whole body following them), and once let go (or frozen) the shift fades instead of
    jumping."""
    body, qpos, contacts = gliding_stance(60, 0.015)
    planter = OutputPlanter(body.mujoco_model(), FPS, 0.02)
    frozen = np.zeros(60, bool)
    frozen[45:] = True  # handed back to the kinematics from frame 45: nothing is held there
    planted = np.array([planter.plant(q, held, bool(f)) for q, held, f in zip(qpos, contacts, frozen, strict=True)])
    before, after = foot_points(body, qpos), foot_points(body, planted)
    assert np.array_equal(planted[:10], qpos[:10])  # nothing held yet: the pose as it came
    assert np.abs(after[10:45, :, :2] - after[10, :, :2]).max() < 1e-3  # held: standing where they touched down
    pelvis_moved = planted[10:45, :2] - qpos[10:45, :2]
    assert np.abs(pelvis_moved[-1, 0] + 0.015 * 34 / FPS) < 2e-3  # the body follows its feet back
    offsets = np.linalg.norm(after[44:, :, :2] - before[44:, :, :2], axis=-1).max(axis=1)
    assert offsets[0] > 0.01 and offsets[-1] < 0.1 * offsets[0] and (np.diff(offsets) <= 1e-9).all()  # fading
    assert np.linalg.norm(np.diff(after[..., :2], axis=0), axis=-1).max() < 0.01  # no jump
