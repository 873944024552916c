"""Rempe's kinematic stage before the trajectory optimisation (B.4, on the shared fitter) and the full-body IK
after it (C.4)."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.body.rotations import quat_exp, quat_multiply
from physmocap.body.support import STEP_HEIGHT
from physmocap.camera import Camera, Floor
from physmocap.config import FitSettings, Settings, TrajoptSettings
from physmocap.kinematics.fit import MARKERS
from physmocap.kinematics.refine import (
    _contact_floor,
    added_contacts,
    blend_window,
    false_flights,
    fit_contact_floor,
    fitted_observations,
    flip_windows,
    flipped_steps,
    refine_kinematics,
    resting_points,
    slipping_contacts,
    tilt_axes,
    wrapped_flips,
    wrapping_joints,
)
from physmocap.kinematics.stage import fit_motion
from physmocap.trajopt.ik import ik_targets, solve_ik
from physmocap.trajopt.reduced import reduced_motion
from test_fit import observe

FPS = 30.0


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.75), 72.0)


@pytest.fixture(scope="module")
def camera():
    cam = Camera.from_settings((1280, 720), fov=60)
    pitch = np.radians(8)
    R = np.array([[1, 0, 0], [0, -np.sin(pitch), -np.cos(pitch)], [0, np.cos(pitch), -np.sin(pitch)]])
    return cam.with_extrinsics(R, -R @ np.array([0.3, -4.0, 1.2]))


def one_leg_stance(body, frames):
    """Standing on the right foot, the left foot lifted 20-30 cm (hip and knee bent), arms swinging; the body
    rolled over the standing foot (hips rolled back), as a person must to stay on it."""
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    step = np.zeros((frames, body.nv))
    t = np.arange(frames) / FPS
    step[:, 3] = 0.11
    for side in ("left", "right"):
        step[:, body.dof_address[body.joint_index[f"{side}_hip"]] + 2] = 0.11
    step[:, body.dof_address[body.joint_index["left_hip"]] + 1] = -0.9
    step[:, body.dof_address[body.joint_index["left_knee"]]] = 1.6
    step[:, body.dof_address[body.joint_index["left_ankle"]] + 1] = 0.5
    for side, sign in (("left", 1.0), ("right", -1.0)):
        step[:, body.dof_address[body.joint_index[f"{side}_shoulder"]]] = sign * (1.2 + 0.3 * np.sin(4 * t))
    return kin.integrate(body, q, step)


def test_refine_puts_contacts_on_a_refitted_floor_and_drops_outliers(body, camera):
    rng = np.random.default_rng(0)
    truth = one_leg_stance(body, 45)
    obs = observe(body, truth, camera)
    obs.keypoints_2d[..., :2] += rng.normal(scale=2.0, size=obs.keypoints_2d[..., :2].shape)
    obs.landmarks_3d += rng.normal(scale=0.02, size=obs.landmarks_3d.shape)
    motion = fit_motion(obs, Settings().replace("body", height=body.height, mass=body.mass))
    contacts = np.ones((45, 4), bool)
    contacts[15:, :2] = False  # the lifted left foot wrongly labelled in contact for the first 15 frames
    refined = refine_kinematics(obs, motion, contacts, FitSettings(), TrajoptSettings())
    # The lifted foot's labels (13-30 cm up) are the floor's outliers and are dropped; the standing foot's kept.
    assert refined.contacts[:, 2:].mean() > 0.9 and not refined.contacts[:, :2].any()
    assert np.array_equal(refined.relabelled, contacts & ~refined.contacts)
    m = refined.motion
    soles = kin.forward_kinematics(m.body, m.qpos).points[:, m.body.point_index(CONTACT_POINTS)]
    kept = refined.contacts
    assert np.abs(soles[kept][:, 2]).max() < 0.015  # on the new floor z = 0
    before = kin.forward_kinematics(motion.body, motion.qpos).points[:, motion.body.point_index(CONTACT_POINTS)]
    still = lambda p: np.linalg.norm(np.diff(p[:, 2:], axis=0), axis=-1).mean()  # noqa: E731
    assert still(soles) < 0.5 * still(before)
    # The refitted floor is the true one: the world's up seen from the camera agrees.
    assert np.degrees(np.arccos(np.clip(m.camera.R[:, 2] @ camera.R[:, 2], -1, 1))) < 3.0
    # The pose stays as close to the observations as before.
    assert np.nanmedian(m.reprojection_error) < np.nanmedian(motion.reprojection_error) + 1.0


def test_dropped_labels_are_offered_back_only_on_a_trusted_floor(body, camera, monkeypatch):
    """False flights get the floor's dropped labels back (`false_flights`' outliers) on a trusted floor only: on one
    levelled with the posture against its feet, their heights do not tell a wrong label."""
    import dataclasses

    from physmocap.kinematics import refine as refine_module

    obs = observe(body, one_leg_stance(body, 20), camera)
    motion = fit_motion(obs, Settings().replace("body", height=body.height, mass=body.mass))
    offered = []
    original = refine_module.added_contacts
    monkeypatch.setattr(refine_module, "added_contacts",
                        lambda *args: offered.append(args[6] is not None) or original(*args))
    for trusted in (True, False):
        floor = dataclasses.replace(motion.floor, trusted=trusted)
        refine_kinematics(obs, dataclasses.replace(motion, floor=floor), np.ones((20, 4), bool), FitSettings(),
                          TrajoptSettings())
    assert offered == [True, False]


def test_refine_reports_the_progress_of_both_fits(body, camera, monkeypatch):
    from physmocap.kinematics import fit as fit_module

    monkeypatch.setattr(fit_module, "ASSEMBLY_FRAMES", 8)  # progress within each pass too
    obs = observe(body, one_leg_stance(body, 20), camera)
    motion = fit_motion(obs, Settings().replace("body", height=body.height, mass=body.mass))
    bars = {}

    def factory(name, total, unit="frames"):
        bars[name] = (unit, total, [])
        return lambda done, total_now: bars[name][2].append((done, total_now))

    refine_kinematics(obs, motion, np.ones((20, 4), bool), FitSettings(), TrajoptSettings(), progress=factory)
    assert list(bars) == ["refine 1/2", "refine 2/2"]
    for unit, planned, calls in bars.values():
        done = [d for d, _ in calls]
        assert unit == "frame passes" and planned == 20 * (FitSettings().offline_iterations + 1)
        assert done == sorted(done) and len(set(done)) > 3 and calls[-1] == (done[-1], done[-1])
        assert all(d < total for d, total in calls[:-1])


def test_ik_reaches_the_contact_points_and_keeps_the_upper_body(body):
    rng = np.random.default_rng(1)
    q = one_leg_stance(body, 20)
    red = reduced_motion(body, q, FPS)
    com = red.com + np.array([0.03, -0.02, -0.02])  # the optimiser moved the COM
    feet = red.feet.copy()
    feet[:, 2:] += rng.normal(scale=0.005, size=feet[:, 2:].shape) + np.array([0.02, 0.0, 0.0])
    settings = TrajoptSettings()
    targets = ik_targets(body, q, red, com, red.euler, feet, settings)
    out = solve_ik(body, targets, FPS, settings)
    pts = kin.forward_kinematics(body, out).points
    assert np.abs(pts[:, body.point_index(CONTACT_POINTS)] - feet).max() < 0.01
    head, wrist = body.point_index(["head", "left_wrist"])
    for k in (head, wrist):  # the upper body follows the COM's move
        expected = kin.forward_kinematics(body, q).points[:, k] + (com - red.com)
        assert np.abs(pts[:, k] - expected).max() < 0.01


def test_upper_body_turns_by_the_physics_change_of_orientation_not_the_roots_noise(body):
    """The input's root orientation may shake from frame to frame where its joints do not (the fit trades the
    pelvis's turn against the hips' and spine's): the upper body turns by the optimised orientation's change from
    the fit stage's smoothed one, so a solution that only smoothed the root leaves the upper body as it was."""
    rng = np.random.default_rng(3)
    q = one_leg_stance(body, 20)
    red = reduced_motion(body, q, FPS)
    noisy = dataclasses.replace(red, rotation=red.rotation @ Rotation.from_rotvec(
        rng.normal(scale=np.radians(2.0), size=(20, 3))).as_matrix())
    settings = TrajoptSettings()
    names = [b for _, b in MARKERS]
    nose = names.index("nose")
    fitted = ik_targets(body, q, noisy, red.com, red.euler, red.feet, settings, fitted_euler=red.euler)
    assert np.abs(fitted.markers[:, nose] - kin.forward_kinematics(body, q).points[:, body.point_index(["nose"])[0]]
                  ).max() < 1e-9
    leaning = red.euler + np.array([0.0, np.radians(5.0), 0.0])  # the physics leans the body 5 degrees forward
    turned = ik_targets(body, q, noisy, red.com, leaning, red.feet, settings, fitted_euler=red.euler)
    offset = fitted.markers[:, nose] - red.com
    moved = turned.markers[:, nose] - red.com
    angle = np.degrees(np.arccos(np.sum(offset * moved, axis=1) / np.linalg.norm(offset, axis=1)
                                 / np.linalg.norm(moved, axis=1)))
    assert np.allclose(angle, 5.0, atol=0.5)
    raw = ik_targets(body, q, noisy, red.com, red.euler, red.feet, settings)  # against the noisy root
    assert np.abs(raw.markers[:, nose] - fitted.markers[:, nose]).max() > 0.01


def test_contact_floor_is_robust_and_keeps_its_tilt_when_points_lie_on_a_line():
    rng = np.random.default_rng(2)
    normal = np.array([0.1, -0.95, -0.2])
    normal /= np.linalg.norm(normal)
    # Points along one line on the plane n . x + 3 = 0 (one planted foot), plus 20% lifted 15-30 cm.
    along = np.cross(normal, [1.0, 0.0, 0.0])
    base = -3.0 * normal + 0.5 * np.cross(normal, along)
    line = base + np.outer(rng.uniform(-0.1, 0.1, 80), along) + rng.normal(scale=0.005, size=(80, 3))
    lifted = base + 0.3 * along + np.outer(rng.uniform(0.15, 0.3, 20), normal)
    points = np.concatenate([line, lifted])
    settings = TrajoptSettings()
    floor, inliers = fit_contact_floor(points, normal + np.array([0.02, 0.0, 0.03]), 0.1,
                                       settings.floor_roll_prior, settings.floor_pitch_prior)
    assert np.degrees(np.arccos(floor.normal @ normal)) < 3.0
    assert abs(floor.offset - 3.0) < 0.02
    assert inliers[:80].all() and not inliers[80:].any()


def rolled(normal, degrees):
    """normal turned about the camera's viewing direction (z) by `degrees`."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ normal


def test_contact_floor_takes_its_roll_from_the_feet_and_stays_level_where_they_leave_it_free():
    rng = np.random.default_rng(3)
    settings = TrajoptSettings()
    fit = lambda pts, up, roll, pitch: fit_contact_floor(pts, up, 0.05, roll, pitch)[0].normal  # noqa: E731
    angle = lambda n, m: np.degrees(np.arccos(np.clip(n @ m, -1.0, 1.0)))  # noqa: E731
    normal = np.array([0.0, -0.99, -0.1])
    normal /= np.linalg.norm(normal)
    lean = rolled(normal, 8.0)  # the prior: the body's axis of a person leaning sideways
    across, along = tilt_axes(normal)
    # Feet 30 cm apart across the image, over 1 m in depth, 1 cm noise, on the floor 3 m below-ahead.
    spread = np.outer(rng.uniform(-0.15, 0.15, 150), across) + np.outer(rng.uniform(-0.5, 0.5, 150), along)
    points = -3.0 * normal + spread + rng.normal(scale=0.01, size=(150, 3))
    assert angle(fit(points, lean, settings.floor_roll_prior, settings.floor_pitch_prior), normal) < 2.5
    # The feet take most of the 8 degree lean out; as strong a prior on the roll as on the pitch keeps most of it.
    assert angle(fit(points, lean, settings.floor_pitch_prior, settings.floor_pitch_prior), normal) > 4.0
    # Feet along one line in depth leave the roll to the prior: a level prior gives a level floor.
    line = -3.0 * normal + np.outer(rng.uniform(-0.5, 0.5, 150), along) + rng.normal(scale=0.01, size=(150, 3))
    assert angle(fit(line, normal, settings.floor_roll_prior, settings.floor_pitch_prior), normal) < 1.0


def running_soles(frames):
    """(T, 4, 3) world heel and toe points of a run along x at 3 m/s: one foot planted (0.5 cm noise) while the
    other swings 20-40 cm up, a new foot every 8 frames; 12 swinging toe points graze 4 cm under the floor (a
    fit's foot through it), so that the true floor sinks 5% of the points by more than refine.SINK_DEPTH."""
    rng = np.random.default_rng(4)
    soles = np.zeros((frames, 4, 3))
    contacts = np.zeros((frames, 4), bool)
    for f in range(frames):
        step = f // 8
        planted = 2 * (step % 2)
        x0 = 3.0 * step * 8 / FPS - 1.8
        for side in (0, 2):
            lateral = -0.1 if side == 0 else 0.1
            if side == planted:
                soles[f, side] = [x0, lateral, 0.0]
                soles[f, side + 1] = [x0 + 0.2, lateral, 0.0]
                soles[f, side:side + 2] += rng.normal(scale=0.005, size=(2, 3))
                contacts[f, side:side + 2] = True
            else:
                x = 3.0 * f / FPS - 1.8
                soles[f, side] = [x - 0.1, lateral, rng.uniform(0.2, 0.4)]
                soles[f, side + 1] = [x + 0.1, lateral, rng.uniform(0.2, 0.4)]
    grazing = np.flatnonzero(~contacts[:, 1])[:6], np.flatnonzero(~contacts[:, 3])[:6]
    soles[grazing[0], 1, 2] = soles[grazing[1], 3, 2] = -0.04
    return soles, contacts


def test_contact_floor_replaces_a_kinematic_floor_the_feet_sink_deeper_through(camera):
    """A run: the floor through its contacts sinks 5% of the foot points 4 cm (more than SINK_DEPTH), but the
    kinematic floor, tilted 12 degrees (a run's lean taken for the vertical), sinks them far deeper: the contacts'
    floor is taken. With the true floor as the kinematic one and the swinging foot labelled in contact too, the
    contacts' floor sinks the feet deeper, and the kinematic floor is kept."""
    frames = 40
    soles, contacts = running_soles(frames)
    in_camera = camera.to_camera(soles)
    valid = np.ones(frames, bool)
    settings = TrajoptSettings()
    up = camera.R[:, 2]
    true_floor = Floor(up, -float(up @ camera.t))
    lean = np.radians(12.0)
    tilted_world = np.array([np.sin(lean), 0.0, np.cos(lean)])
    tilted = Floor(camera.R @ tilted_world, -float(camera.R @ tilted_world @ camera.t))
    floor, kept = _contact_floor(in_camera, contacts, valid, camera, tilted, False, settings)
    assert np.degrees(np.arccos(floor.normal @ true_floor.normal)) < 1.0
    assert kept[contacts].mean() > 0.95
    wrong = contacts | (soles[..., 2] > 0.3)  # swinging points labelled in contact
    floor, kept = _contact_floor(in_camera, wrong, valid, camera, true_floor, False, settings)
    assert floor is true_floor
    assert (kept == contacts).all()


def test_contact_floor_keeps_an_untrusted_floor_and_the_confidence_of_a_refitted_one(camera):
    """The kinematic stage did not trust the feet's plane (it leant from the person's posture) and levelled the
    floor with the posture: the same feet, labelled in contact, must not lean it again, and the floor says it is
    still not trusted. A trusted floor is refitted through the contacts and keeps its confidence."""
    frames = 40
    soles, contacts = running_soles(frames)
    valid = np.ones(frames, bool)
    lean = np.radians(12.0)
    tilted_world = np.array([np.sin(lean), 0.0, np.cos(lean)])
    posture = Floor(camera.R @ tilted_world, -float(camera.R @ tilted_world @ camera.t), 0.3, 1.0, 25.0, False,
                    "posture")
    floor, _ = _contact_floor(camera.to_camera(soles), contacts, valid, camera, posture, False, TrajoptSettings())
    assert floor is posture
    trusted = dataclasses.replace(posture, trusted=True, source="feet and posture")
    floor, _ = _contact_floor(camera.to_camera(soles), contacts, valid, camera, trusted, False, TrajoptSettings())
    assert np.degrees(np.arccos(floor.normal @ camera.R[:, 2])) < 1.0  # refitted onto the feet
    assert floor.trusted and floor.source == "contacts" and floor.prior_disagreement == 25.0


def on_floor(body, q):
    """q moved up or down so that its lowest heel or toe touches z = 0."""
    soles = kin.forward_kinematics(body, q).points[:, body.point_index(CONTACT_POINTS), 2]
    q = q.copy()
    q[:, 2] -= soles.min()
    return q


def test_sliding_contacts_are_dropped_and_still_ones_kept(body):
    frames = 30
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    settings = TrajoptSettings()
    labelled = np.ones((frames, 4), bool)
    assert not slipping_contacts(body, q, FPS, labelled, settings).any()
    # The body glides at twice the slip speed from frame 10 on (a hop labelled as standing, say).
    glide = q.copy()
    glide[10:, 0] += 2 * settings.contact_slip_speed * np.arange(1, frames - 9) / FPS
    slipping = slipping_contacts(body, glide, FPS, labelled, settings)
    assert slipping[12:].all() and not slipping[:9].any()
    # Only labelled contacts are ever dropped; a slower glide keeps them.
    assert not slipping_contacts(body, glide, FPS, np.zeros_like(labelled), settings).any()
    slow = q.copy()
    slow[:, 0] += 0.8 * settings.contact_slip_speed * np.arange(frames) / FPS
    assert not slipping_contacts(body, slow, FPS, labelled, settings).any()


def test_points_resting_on_the_floor_are_added_as_contacts(body):
    frames = 30
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    settings = TrajoptSettings()
    valid = np.ones(frames, bool)
    unlabelled = np.zeros((frames, 4), bool)
    heights = kin.forward_kinematics(body, q).points[0, body.point_index(CONTACT_POINTS), 2]
    low = heights < settings.rest_height
    added = resting_points(body, q, FPS, unlabelled, valid, settings)
    assert low.any() and (added == low).all()  # every sole point near the floor, at every frame
    assert not resting_points(body, q, FPS, ~unlabelled, valid, settings).any()  # nothing already labelled
    lifted = q.copy()
    lifted[:, 2] += 2 * settings.rest_height
    assert not resting_points(body, lifted, FPS, unlabelled, valid, settings).any()
    sunk = q.copy()  # under the floor is not in the air either
    sunk[:, 2] -= 0.05
    assert resting_points(body, sunk, FPS, unlabelled, valid, settings).all()
    lower = q.copy()  # a step down (STEP_HEIGHT): another level, not this floor
    lower[:, 2] -= STEP_HEIGHT + 0.05
    assert not resting_points(body, lower, FPS, unlabelled, valid, settings).any()
    # Resting for fewer frames than a phase lasts is not a contact.
    brief = lifted.copy()
    brief[10] = q[10]
    assert not resting_points(body, brief, FPS, unlabelled, valid, settings).any()
    moving = q.copy()
    moving[:, 0] += 2 * settings.rest_speed * np.arange(frames) / FPS
    assert not resting_points(body, moving, FPS, unlabelled, valid, settings).any()


def test_false_flights_get_the_points_near_the_floor_back(body):
    frames = 30
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    valid = np.ones(frames, bool)
    near = TrajoptSettings().floor_outlier_distance
    labelled = np.ones((frames, 4), bool)
    labelled[10:20] = False  # labelled in the air while the body stands still
    heights = kin.forward_kinematics(body, q).points[0, body.point_index(CONTACT_POINTS), 2]
    added = false_flights(body, q, FPS, labelled, valid, near)
    assert (added[10:20] == (heights < near)).all() and not added[:10].any() and not added[20:].any()
    # Standing on nothing (every point far above the floor) stays in the air: no contact off the floor.
    raised = q.copy()
    raised[:, 2] += 2 * near
    assert not false_flights(body, raised, FPS, labelled, valid, near).any()
    # Nor does standing on lower ground (a step down, every point far under the floor): B.4 held such points on
    # the floor and lifted a stair climber's body 35 cm there.
    lowered = q.copy()
    lowered[:, 2] -= STEP_HEIGHT + 0.05
    assert not false_flights(body, lowered, FPS, labelled, valid, near).any()
    # A real flight: the body falls freely over the run (and the frames around it, a jump's last push and first
    # landing frames), so its labels stand.
    t = np.arange(frames) / FPS - 14.5 / FPS
    flight = q.copy()
    flight[6:24, 2] += 0.5 * 9.81 * ((8.5 / FPS) ** 2 - t[6:24] ** 2)
    assert not false_flights(body, flight, FPS, labelled, valid, near).any()


def test_a_false_flight_made_by_dropping_outlying_labels_gets_those_labels_back(body):
    """The clip's last frames fitted 10 cm up (the feet drift up over the clip) while the labels keep the feet down
    and the body does not fall: the floor drops those labels as its outliers, which makes a flight. The labels and
    the centre of mass agree that the body stands, so they are given back (B.4's next fit puts the feet on the
    floor); unlabelled points far up stay in the air, and a real flight keeps its labels dropped."""
    frames = 30
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    q[:, 2] += np.linspace(0.0, 0.1, frames)
    valid = np.ones(frames, bool)
    near = TrajoptSettings().floor_outlier_distance
    labelled = np.ones((frames, 4), bool)
    labelled[24:, 2:] = False  # the right foot labelled lifted there
    kept = labelled.copy()
    kept[24:] = False  # dropped: more than `near` above the floor
    outliers = labelled & ~kept
    added = false_flights(body, q, FPS, kept, valid, near, outliers)
    assert (added == outliers).all()
    assert not false_flights(body, q, FPS, kept, valid, near).any()  # without them: only points near the floor
    t = np.arange(frames) / FPS - 27 / FPS
    jump = q.copy()
    jump[20:, 2] += 0.5 * 9.81 * ((7 / FPS) ** 2 - t[20:] ** 2)  # falling freely from frame 20 on
    assert not false_flights(body, jump, FPS, kept, valid, near, outliers).any()
    # Labels farther up than a step stand on something else (a box): not given back, nor pulled onto the floor.
    boxed = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    boxed[:, 2] += STEP_HEIGHT + 0.05
    assert not false_flights(body, boxed, FPS, kept, valid, near, outliers).any()


def test_no_contact_is_added_where_the_body_stands_on_another_level(body):
    """Standing still, unlabelled, first on the floor, then on ground 1.3 m below it (the man who stepped off the
    box the floor was found on): the resting points are given back on the floor only; under it they stay the
    floor's outliers, which B.4 would otherwise pull up to it."""
    frames = 40
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    q[20:, 2] -= 1.3
    unlabelled = np.zeros((frames, 4), bool)
    added = added_contacts(body, q, FPS, unlabelled, np.ones(frames, bool), TrajoptSettings())
    assert added[:20].any(axis=1).all() and not added[20:].any()


def test_a_false_flight_adds_no_point_that_slides(body):
    """Labelled all in the air for 10 frames while the body does not fall: standing still, the points near the floor
    are added; gliding at 2 m/s (a run's landing foot swinging in low), none is, since B.4 drops a labelled
    contact sliding faster than contact_slip_speed (measured: added there, they pinned a run's swinging foot 2-3
    frames before it landed, and B.4's error grew 8% over the plain fit's)."""
    frames = 30
    settings = TrajoptSettings()
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    labelled = np.ones((frames, 4), bool)
    labelled[10:20] = False
    valid = np.ones(frames, bool)
    standing = added_contacts(body, q, FPS, labelled, valid, settings)
    assert standing[10:20].any(axis=1).all()
    gliding = q.copy()
    gliding[:, 0] += 2 * settings.contact_slip_speed * np.arange(frames) / FPS
    assert false_flights(body, gliding, FPS, labelled, valid, settings.floor_outlier_distance).any()
    assert not added_contacts(body, gliding, FPS, labelled, valid, settings).any()


def test_a_runs_short_flights_stay_flights_though_the_fit_smooths_them(body):
    """A run's COM height: 0.2 s stances pushing at up to 2 g, then 0.13 s flights in free fall, smoothed over 3
    frames as a fit's velocity terms do. The velocities at a flight's two ends show about half of gravity's drop
    (the stance's push is in them); the curvature over the flight shows most of it, and the flights stand."""
    frames, gravity = 40, 9.81
    period = 0.2 + 0.4 / 3
    phase = np.mod(np.arange(frames) / FPS, period)
    flight = phase >= 0.2
    acc = np.where(flight, -gravity, -gravity + gravity * period / 0.2 * (1 - np.cos(2 * np.pi * phase / 0.2)))
    speed = np.cumsum(acc) / FPS
    height = np.cumsum(speed - speed.mean()) / FPS
    height = np.convolve(np.pad(height, 1, mode="edge"), np.ones(3) / 3, mode="valid")
    q = on_floor(body, np.repeat(body.rest_qpos[None], frames, axis=0))
    q[:, 2] += height - height.min()
    labelled = np.ones((frames, 4), bool)
    labelled[flight] = False
    near = 1.0  # every point counts as near the floor: only the verdict is tested
    assert not false_flights(body, q, FPS, labelled, np.ones(frames, bool), near).any()


def test_refinement_fits_the_observations_the_kinematic_stage_corrected():
    from types import SimpleNamespace

    from physmocap.landmarks import LANDMARK_INDEX
    from physmocap.motion import Observations

    rng = np.random.default_rng(3)
    obs = Observations(rng.uniform(0, 500, (6, 33, 3)), rng.normal(size=(6, 33, 3)), FPS, (640, 480))
    swaps = np.array([False, True, True, False, False, False])
    fit = FitSettings(rescale_landmark_depth=False)
    out = fitted_observations(obs, SimpleNamespace(foot_swaps=swaps), fit)
    left, right = LANDMARK_INDEX["left_heel"], LANDMARK_INDEX["right_heel"]
    assert np.array_equal(out.keypoints_2d[swaps, left], obs.keypoints_2d[swaps, right])
    assert np.array_equal(out.landmarks_3d[swaps, right], obs.landmarks_3d[swaps, left])
    assert np.array_equal(out.keypoints_2d[~swaps], obs.keypoints_2d[~swaps])


def test_flipped_steps_find_a_joint_turned_through_a_half_turn(body):
    """The bent leg twisted half a turn about the thigh from frame 10 on swings its shin across in one step, which
    the fitted motion does not take; a jump both motions take, and steps next to a frame without a person, are
    motion, not flips."""
    fitted = one_leg_stance(body, 20)
    fitted[15:, 0] += 0.5  # a jump of the whole body (a detector's), in both
    refined = fitted.copy()
    hip = body.qpos_address[body.joint_index["left_hip"]]
    refined[10:, hip:hip + 4] = quat_multiply(refined[10:, hip:hip + 4], quat_exp(np.array([0.0, 0.0, np.pi])))
    valid = np.ones(20, bool)
    np.testing.assert_array_equal(np.flatnonzero(flipped_steps(body, fitted, refined, valid)), [9])
    valid[10] = False
    assert not flipped_steps(body, fitted, refined, valid).any()


def test_wrapping_joints_find_a_joint_turning_through_a_half_turn(body):
    """A hip turning steadily about one axis from 0.8 pi to 1.2 pi from rest passes to the log's other branch once,
    between the frames either side of pi; the same turn from 0.4 pi to 0.8 pi never does. A flip of the knee, which
    the hip moves, next to that step is the wrapped angles' doing; a flip of the other knee is not."""
    hip = body.qpos_address[body.joint_index["left_hip"]]
    ball = list(kin.tables(body).ball_bodies)
    axis = np.array([0.0, 0.6, 0.8])
    for start, crossing in ((0.8 * np.pi, [4]), (0.4 * np.pi, [])):
        qpos = one_leg_stance(body, 10)
        angles = start + np.arange(10) * 0.4 * np.pi / 9
        qpos[:, hip:hip + 4] = quat_exp(angles[:, None] * axis)
        wrapping = wrapping_joints(body, qpos)
        expected = [[t, ball.index(body.joint_index["left_hip"])] for t in crossing]
        np.testing.assert_array_equal(np.argwhere(wrapping), np.reshape(expected, (-1, 2)))
    flips = np.zeros((9, len(body.point_names)), bool)
    flips[5, body.point_index(["left_knee"])] = True
    np.testing.assert_array_equal(np.flatnonzero(wrapped_flips(body, qpos, qpos, flips)), [])  # 0.4-0.8 pi
    qpos[:, hip:hip + 4] = quat_exp((0.8 * np.pi + np.arange(10) * 0.4 * np.pi / 9)[:, None] * axis)
    np.testing.assert_array_equal(np.flatnonzero(wrapped_flips(body, qpos, qpos, flips)), [5])
    flips[5] = False
    flips[5, body.point_index(["right_knee"])] = True
    assert not wrapped_flips(body, qpos, qpos, flips).any()


def test_flip_windows_reach_a_second_either_side_and_merge():
    np.testing.assert_array_equal(flip_windows(np.arange(99) == 50, 10.0), [(40, 62)])
    np.testing.assert_array_equal(flip_windows(np.isin(np.arange(99), [3, 15, 80]), 10.0), [(0, 27), (70, 92)])


def test_blend_window_joins_the_solved_stretch_to_the_motion_around_it(body):
    """Inside the window the solved poses, blended in over `frames` at an end that is not the clip's; outside it
    the motion untouched."""
    qpos = np.repeat(body.rest_qpos[None], 30, axis=0)
    solved = qpos[10:20].copy()
    solved[:, 0] += 1.0
    out = blend_window(body, qpos, solved, 10, 20, 3)
    np.testing.assert_allclose(out[10:20, 0], [0.25, 0.5, 0.75, 1, 1, 1, 1, 0.75, 0.5, 0.25])
    np.testing.assert_array_equal(out[:10], qpos[:10])
    np.testing.assert_array_equal(out[20:], qpos[20:])
    np.testing.assert_allclose(blend_window(body, qpos, solved, 0, 10, 3)[:10, 0], [1] * 7 + [0.75, 0.5, 0.25])


def test_a_refinement_that_flips_a_joint_is_solved_again_with_the_angles_unwrapped(body, camera, monkeypatch,
                                                                                     caplog):
    from physmocap.kinematics import refine as refine_module

    obs = observe(body, one_leg_stance(body, 20), camera)
    motion = fit_motion(obs, Settings().replace("body", height=body.height, mass=body.mass))
    unwrapped = []
    fitter_class = refine_module.KinematicFitter

    def fitter(*args, unwrap_angles=False, **kwargs):
        unwrapped.append(unwrap_angles)
        return fitter_class(*args, unwrap_angles=unwrap_angles, **kwargs)

    monkeypatch.setattr(refine_module, "KinematicFitter", fitter)
    plain = refine_kinematics(obs, motion, np.ones((20, 4), bool), FitSettings(), TrajoptSettings())
    assert unwrapped == [False, False]  # no flip: solved once
    calls = []

    def first_flips(body, fitted, refined, valid):
        calls.append(refined)
        flips = np.zeros((len(refined) - 1, len(body.point_names)), bool)
        flips[4] = len(calls) == 1
        return flips

    monkeypatch.setattr(refine_module, "flipped_points", first_flips)
    unwrapped.clear()
    with caplog.at_level("INFO", logger="physmocap"):
        kept = refine_kinematics(obs, motion, np.ones((20, 4), bool), FitSettings(), TrajoptSettings())
    assert unwrapped == [False, False]  # no joint passes a half turn there: not the wrapped angles' doing
    assert "not through a half turn: kept" in caplog.text
    np.testing.assert_array_equal(kept.motion.qpos, calls[0])
    calls.clear()
    monkeypatch.setattr(refine_module, "wrapped_flips", lambda body, fitted, refined, flips: flips.any(axis=1))
    unwrapped.clear()
    with caplog.at_level("INFO", logger="physmocap"):
        again = refine_kinematics(obs, motion, np.ones((20, 4), bool), FitSettings(), TrajoptSettings())
    assert unwrapped == [False, False, True]  # the last fit again, over the flip's window (here the whole clip)
    assert "solved again there with the joint angles unwrapped" in caplog.text
    np.testing.assert_array_equal(again.motion.qpos, calls[1])
    assert np.allclose(again.motion.qpos, plain.motion.qpos, atol=1e-2)  # no half turn here: nearly the same
