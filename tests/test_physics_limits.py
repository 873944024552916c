"""PhysCap at any frame rate, with bounded forces, and with the frames its contact model cannot explain flagged and
handed back as the kinematic motion (issue 17)."""

import numpy as np
import pytest

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.body.rotations import quat_exp, quat_multiply
from physmocap.config import PhysicsSettings
from physmocap.dynamics.physcap import integration_steps, stability_limit
from physmocap.dynamics.stage import PhysicsStream, run_physcap

G = 9.81


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.75), 72.0)


def swaying(body, fps, seconds=2.5):
    """Standing on both feet, arms swinging and the trunk bending: a smooth motion sampled at `fps`. Returns
    the times (T,) and poses (T, nq)."""
    t = np.arange(int(round(seconds * fps)) + 1) / fps
    q = np.repeat(body.rest_qpos[None], len(t), axis=0)
    adr = {name: body.mujoco_model().joint(name).qposadr[0] for name in ("left_shoulder", "right_shoulder", "spine")}
    for k, time in enumerate(t):
        arm = 0.4 * np.sin(2 * np.pi * 0.8 * time)
        for name, sign in (("left_shoulder", 1.0), ("right_shoulder", -1.0)):
            a = adr[name]
            q[k, a:a + 4] = quat_multiply(q[k, a:a + 4], quat_exp(np.array([sign * arm, 0.0, 0.0])))
        a = adr["spine"]
        q[k, a:a + 4] = quat_multiply(q[k, a:a + 4], quat_exp(np.array([0.0, 0.12 * np.sin(np.pi * time), 0.0])))
    return t, q


def test_the_step_follows_the_frame_interval():
    settings = PhysicsSettings()
    longest = settings.step_stability_share * stability_limit(settings)
    for fps, steps in ((8, 12), (10, 10), (24, 4), (25, 4), (30, 4), (60, 2), (120, 1)):
        n, step = integration_steps(settings, fps)
        assert n == steps and step <= longest and n * step == pytest.approx(1.0 / fps)
    legacy = PhysicsSettings(step_stability_share=None)
    assert integration_steps(legacy, 10) == (4, pytest.approx(0.025))


def test_the_step_limit_follows_the_stiffest_gains():
    """Semi-implicit Euler on x'' = -kp x - kd x' is stable while kp h^2 + 2 kd h < 4: the limit is where the
    stiffest DOF reaches 4, and stiffer gains shorten the steps."""
    settings = PhysicsSettings()
    h = stability_limit(settings)
    kp, kd = settings.kp_root_translation, settings.kd_root_translation  # the stiffest pair of the defaults
    assert kp * h * h + 2 * kd * h == pytest.approx(4.0)
    assert settings.kp_joint * h * h + 2 * settings.kd_joint * h < 4.0
    stiff = PhysicsSettings(kp_joint=4 * settings.kp_joint, kd_joint=2 * settings.kd_joint)
    assert stability_limit(stiff) < h and integration_steps(stiff, 30)[0] > integration_steps(settings, 30)[0]
    assert stability_limit(PhysicsSettings(kp_joint=0.0, kd_joint=0.0, kp_root_rotation=0.0, kd_root_rotation=0.0,
                                           kp_root_translation=0.0, kd_root_translation=0.0, kp_root_horizontal=0.0,
                                           kd_root_horizontal=0.0)) == float("inf")


def test_the_same_motion_at_10_24_30_and_60_fps_gives_the_same_physics(body):
    weight = body.mass * G
    points = {}
    for fps in (10, 24, 30, 60):
        t, q = swaying(body, fps)
        contacts = np.ones((len(t), 4), bool)
        physics = run_physcap(body, q, fps, contacts, np.zeros(len(t), bool), PhysicsSettings())
        assert np.isfinite(physics.qpos).all() and np.isfinite(physics.grf).all()
        assert np.abs(physics.grf.sum(axis=1)).max() < 2.0 * weight  # a gentle motion: no force spikes
        assert not physics.unexplained.any()
        points[fps] = t, kin.forward_kinematics(body, physics.qpos).points
    reference_times, reference = points[60]
    for fps in (10, 24, 30):
        t, p = points[fps]
        common = [i for i, time in enumerate(t) if time >= 0.5 and np.isclose(reference_times, time).any()]
        match = [int(np.argmin(np.abs(reference_times - t[i]))) for i in common]
        assert len(common) >= 4
        assert np.linalg.norm(p[common] - reference[match], axis=-1).max() < 0.01, fps


def test_a_contact_label_switches_at_the_same_instant_at_any_frame_rate(body):
    """Contacts are decided per integration step from the frame nearest the step's middle: a label that turns
    off at 0.5 s takes effect within half a step of 0.5 s - half a frame interval, not a whole frame early."""
    from physmocap.dynamics.physcap import PhysCapTracker

    settings = PhysicsSettings(foot_lock="never")  # only the labels, not floor collisions, make contacts
    for fps in (10.0, 24.0, 60.0):
        tracker = PhysCapTracker(body, settings, fps, record=True)
        tracker.reset(body.rest_qpos, np.zeros(body.nv))
        zero = np.zeros(body.nv)
        records = []
        for k in range(int(fps) + 1):
            contacts = np.full(4, k / fps < 0.5 - 1e-9)
            records += tracker.track(body.rest_qpos, zero, zero, contacts).records
        first_off = next(i for i, r in enumerate(records) if not r.active.any())
        switch = (first_off + 0.5) * tracker.dt - 1.0 / fps  # the first step's middle; frame 0 ends at 0 s
        assert abs(switch - (0.5 - 0.5 / fps)) <= 0.5 * tracker.dt + 1e-9, fps


def ballistic_jump(body, fps: float, frames: int, takeoff: int, flight: float):
    """Standing, then a flight of `flight` seconds from frame `takeoff` along the parabola that leaves and meets
    standing height (take-off speed g flight / 2), the feet called in contact outside the flight. Returns the
    poses (frames, nq), contacts (frames, 4) and the flight frames (frames,)."""
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    t = (np.arange(frames) - takeoff) / fps
    air = (t > 0) & (t < flight)
    q[air, 2] += 0.5 * G * flight * t[air] - 0.5 * G * t[air] ** 2
    return q, np.repeat(~air[:, None], 4, axis=1), air


def test_at_10_fps_a_jump_stays_finite_and_bounded(body):
    fps, frames = 10.0, 30
    q, contacts, _ = ballistic_jump(body, fps, frames, takeoff=10, flight=0.5)
    physics = run_physcap(body, q, fps, contacts, np.zeros(frames, bool), PhysicsSettings())
    bound = PhysicsSettings().max_force * body.mass * G
    assert np.isfinite(physics.qpos).all() and np.isfinite(physics.grf).all() and np.isfinite(physics.residual).all()
    assert np.linalg.norm(physics.grf.sum(axis=1), axis=1).max() <= bound * (1 + 1e-9)
    assert np.linalg.norm(physics.residual[:, :3], axis=1).max() <= bound * (1 + 1e-9)


def raised(body, fps=30.0, frames=120, start=40, end=80, height=0.3):
    """Standing still, lifted `height` above the floor from frame `start` to `end` (ramps of 12 frames, a step up
    onto a box) with the feet still called in contact: something other than the floor carries the body. Returns
    poses and the frames lifted by more than half the height."""
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    lift = np.clip(np.minimum(np.arange(frames) - start, end - np.arange(frames)) / 12.0, 0.0, 1.0) * height
    q[:, 2] += lift
    return q, lift > height / 2


def test_a_body_carried_off_the_floor_is_flagged_and_handed_back_as_the_kinematic_motion(body):
    q, lifted = raised(body)
    contacts = np.ones((len(q), 4), bool)
    physics = run_physcap(body, q, 30.0, contacts, np.zeros(len(q), bool), PhysicsSettings())
    flagged = physics.unexplained
    assert flagged[lifted].mean() > 0.8  # the supported segment, less the diagnosis' delay
    assert not flagged[:35].any() and not flagged[-20:].any()  # standing on the floor
    root = physics.qpos[:, :3]
    middle = np.flatnonzero(lifted)[len(np.flatnonzero(lifted)) // 2]
    assert np.linalg.norm(root[middle] - q[middle, :3]) < 0.01  # the kinematic motion, not a fall
    step = np.linalg.norm(np.diff(root, axis=0), axis=1)
    kinematic_step = np.linalg.norm(np.diff(q[:, :3], axis=0), axis=1)
    # Blended in and out: the character, lagging the lift by several cm when the flag rises, is caught up over
    # unexplained_blend, never in one frame
    lag = np.linalg.norm(root - q[:, :3], axis=1).max()
    assert lag > 0.04 and step.max() < kinematic_step.max() + 0.6 * lag
    assert physics.unexplained.dtype == bool


def test_with_the_whole_clip_every_flagged_frame_is_the_kinematic_motion(body):
    q, _ = raised(body)
    contacts, still = np.ones((len(q), 4), bool), np.zeros(len(q), bool)
    causal = run_physcap(body, q, 30.0, contacts, still, PhysicsSettings())
    whole = run_physcap(body, q, 30.0, contacts, still, PhysicsSettings(), whole_clip=True)
    np.testing.assert_array_equal(whole.unexplained, causal.unexplained)  # the same simulation and flags
    flagged = whole.unexplained
    assert flagged.any()
    whole_miss = np.linalg.norm(whole.qpos[flagged, :3] - q[flagged, :3], axis=1)
    causal_miss = np.linalg.norm(causal.qpos[flagged, :3] - q[flagged, :3], axis=1)
    assert whole_miss.max() < 1e-9 < causal_miss.max()  # the causal stream only starts handing back there


def test_ordinary_standing_and_a_ballistic_jump_are_not_flagged(body):
    fps, frames = 30.0, 60
    # A jump whose take-off and landing are pushed by the feet: the root rises and falls along a smooth
    # parabola joined to standing by the flight's own ends, contacts called down to the frame of take-off.
    q, contacts, air = ballistic_jump(body, fps, frames, takeoff=20, flight=0.4)
    physics = run_physcap(body, q, fps, contacts, np.zeros(frames, bool), PhysicsSettings())
    assert not physics.unexplained[:18].any() and not physics.unexplained[40:].any()
    assert not physics.unexplained[air][2:-2].any()  # mid-flight follows gravity


def kneeling(body, knee_height):
    """The rest pose lowered onto the left knee (at knee_height m above the floor, its shin flat behind, the toe on
    the floor) with the right thigh forward and its foot flat on the floor: a kneel, or with a higher knee a deep
    lunge. The right hip's and left ankle's angles are found by bisection so that both feet reach the floor."""
    model = body.mujoco_model()
    heights = {name: body.point_names.index(name) for name in ("left_knee", "left_toe", "right_heel")}

    def pose(hip_angle, ankle_angle):
        q = body.rest_qpos.copy()
        q[model.joint("left_knee").qposadr[0]] = q[model.joint("right_knee").qposadr[0]] = np.pi / 2
        for joint, rotation in (("right_hip", -hip_angle), ("left_ankle", ankle_angle)):
            a = model.joint(joint).qposadr[0]
            q[a:a + 4] = quat_multiply(q[a:a + 4], quat_exp(np.array([0.0, rotation, 0.0])))
        z = kin.forward_kinematics(body, q[None]).points[0, :, 2]
        q[2] -= z[heights["left_knee"]] - knee_height
        return q, z - z[heights["left_knee"]] + knee_height

    def bisect(height_of, low, high):  # the angle in [low, high] where the point (rising with it) meets the floor
        for _ in range(40):
            middle = 0.5 * (low + high)
            low, high = (middle, high) if height_of(middle) < 0.0 else (low, middle)
        return 0.5 * (low + high)

    hip = bisect(lambda a: pose(a, 1.2)[1][heights["right_heel"]], 1.0, 2.2)
    ankle = bisect(lambda a: pose(hip, a)[1][heights["left_toe"]], 0.0, 1.6)
    return pose(hip, ankle)[0]


def test_a_body_resting_on_a_knee_is_flagged_and_the_same_lunge_above_the_floor_is_not(body):
    """Standing, then down onto the left knee for a second: the knee carries weight that no sole point can, which
    the upward force alone does not show (the feet stand within reach of the floor). The same pose held 10 cm
    higher is a lunge the feet explain (the descent itself may be flagged in both: it stops abruptly)."""
    fps, T = 30.0, 90
    flagged = {}
    for height in (0.02, 0.12):
        low = kneeling(body, height)
        share = np.clip((np.arange(T) - 20) / 15.0, 0.0, 1.0) * np.clip((75 - np.arange(T)) / 15.0, 0.0, 1.0)
        q = np.array([body.rest_qpos + s * (low - body.rest_qpos) for s in share])
        q[:, 3:7] = body.rest_qpos[3:7]  # the root keeps its orientation (a blend of quaternions is not one)
        flagged[height] = run_physcap(body, q, fps, np.ones((T, 4), bool), np.zeros(T, bool), PhysicsSettings(),
                                      refined_input=True).unexplained
        assert not flagged[height][:20].any()
    assert flagged[0.02][36:60].all()
    assert not flagged[0.12][36:60].any()


def test_a_drop_off_the_floors_edge_is_flagged_once_the_feet_pass_under_the_floor(body):
    """Standing on a box (the floor the clip found), then stepping off its edge and falling 1.3 m to the ground: the
    feet pass under the box's plane frames before the centre of mass does. From the frame every (unlabelled) sole
    point lies deeper than a resting point would, the body stands on another level; the character does not land
    on the box's plane (it did, at 7.4 body weights, on one retargeted video)."""
    from physmocap.body.support import RESTING_HEIGHT, under_the_floor, unexplained_frames

    fps, T = 30.0, 40
    q = np.repeat(body.rest_qpos[None], T, axis=0)
    t = np.maximum(np.arange(T) - 20, 0) / fps
    q[:, 2] -= np.minimum(0.5 * G * t**2, 1.3)
    pose = kin.forward_kinematics(body, q)
    com = kin.center_of_mass(body, pose)
    soles = pose.points[:, body.point_index(CONTACT_POINTS), 2].min(axis=1)
    contacts = np.zeros((T, 4), bool)
    contacts[:21] = True  # standing, then off the edge
    flagged = unexplained_frames(body.point_names, pose.points, com, contacts)
    assert not flagged[:20].any()
    deep = soles < -RESTING_HEIGHT
    assert (flagged == deep).all() and (deep & (com[:, 2] > 0.0)).any()  # before the COM is under the floor
    physics = run_physcap(body, q, fps, contacts, np.zeros(T, bool), PhysicsSettings(), refined_input=True)
    assert physics.unexplained[deep].all() and not physics.grf[deep].any()
    # Feet labelled in contact are the contact model's to hold, however deep a fit sank them.
    held = under_the_floor(body.point_names, pose.points, com, np.ones((T, 4), bool))
    assert (held == (com[:, 2] < 0.0)).all()


def test_a_foot_on_lower_ground_while_the_other_stands_on_the_floor_is_another_level(body):
    """A stair climber: one foot labelled on the floor (a step), the other unlabelled and 0.2 m under it (the step
    below, where its labels were the floor's outliers). That foot carries weight the floor cannot give: the frames
    are flagged and no force is claimed there, where the foot on the floor was left to carry the body alone."""
    from physmocap.body.support import RESTING_HEIGHT, under_the_floor

    fps, T = 30.0, 30
    q = np.repeat(body.rest_qpos[None], T, axis=0)
    pose = kin.forward_kinematics(body, q)
    com = kin.center_of_mass(body, pose)
    points = pose.points.copy()
    left = body.point_index(("left_heel", "left_toe"))
    points[10:20][:, left, 2] -= 0.2 + (points[10:20][:, left, 2]).min()  # the left foot on the step below
    contacts = np.zeros((T, 4), bool)
    contacts[:, 2:] = True  # the right foot labelled on the floor throughout
    flagged = under_the_floor(body.point_names, points, com, contacts)
    assert flagged[10:20].all() and not flagged[:10].any() and not flagged[20:].any()
    contacts[10:20, 0] = True  # labelled, the foot is the contact model's to hold
    assert not under_the_floor(body.point_names, points, com, contacts).any()
    shallow = pose.points.copy()  # a foot a little under the floor, as a fit leaves one, is not another level
    shallow[:, left, 2] -= (shallow[:, left, 2]).min() + 0.5 * RESTING_HEIGHT
    assert not under_the_floor(body.point_names, shallow, com, np.zeros((T, 4), bool)).any()
    # The physics keeps the kinematic motion there and claims no force.
    lowered = q.copy()
    lowered[10:20, 2] -= 0.2  # the body on the step below; only the right foot labelled, lifted onto the floor
    only_right = np.zeros((T, 4), bool)
    only_right[:, 2:] = True
    physics = run_physcap(body, lowered, fps, only_right, np.zeros(T, bool), PhysicsSettings(), refined_input=True)
    assert physics.unexplained[10:20].all() and not physics.grf[10:20].any()


def test_no_restart_for_a_stretch_too_short_to_judge_between_two_unexplainable_ones(body):
    """Standing, with two stretches under the floor (another level) two frames apart: the character does not
    restart for those two frames, which the diagnosis (unexplained_time) could not judge; they keep the kinematic
    motion, flagged, with no force. After the second stretch it restarts and carries the body again."""
    fps, T = 30.0, 80
    q = np.repeat(body.rest_qpos[None], T, axis=0)
    q[20:30, 2] -= 1.5
    q[32:46, 2] -= 1.5
    physics = run_physcap(body, q, fps, np.ones((T, 4), bool), np.ones(T, bool), PhysicsSettings(),
                          refined_input=True)
    assert physics.unexplained[20:46].all() and not physics.grf[20:46].any()
    assert not physics.unexplained[60:].any() and physics.grf[60:].any()


def test_offline_the_hand_back_is_centred_on_the_flagged_stretch(body):
    """Frames 10-12 flagged at 10 fps with a 0.2 s blend: handed over fully there, half-way one frame either side,
    untouched two frames away (the causal stream only starts at frame 10)."""
    from physmocap.dynamics.stage import centred_hand_back

    targets = np.repeat(body.rest_qpos[None], 30, axis=0)
    tracked = targets.copy()
    tracked[:, 0] += 0.1
    flagged = np.zeros(30, bool)
    flagged[10:13] = True
    out = centred_hand_back(body.mujoco_model(), tracked, targets, flagged, 10.0, 0.2)
    np.testing.assert_allclose(out[7:16, 0], [0.1, 0.1, 0.05, 0, 0, 0, 0.05, 0.1, 0.1], atol=1e-12)
    np.testing.assert_array_equal(out[:, 1:], targets[:, 1:])
    np.testing.assert_array_equal(centred_hand_back(body.mujoco_model(), tracked, targets, np.zeros(30, bool), 10.0,
                                                    0.2), tracked)


def test_non_finite_or_huge_forces_are_bounded_and_flagged(body, monkeypatch):
    from physmocap.dynamics import physcap

    q = np.repeat(body.rest_qpos[None], 20, axis=0)
    original = physcap.PhysCapTracker.track

    def exploding(self, *args):
        frame = original(self, *args)
        frame.contact_forces[0] = [np.nan, 0.0, 1e9]
        frame.residual[2] = 1e12
        return frame

    monkeypatch.setattr(physcap.PhysCapTracker, "track", exploding)
    physics = run_physcap(body, q, 30.0, np.ones((20, 4), bool), np.zeros(20, bool), PhysicsSettings())
    bound = PhysicsSettings().max_force * body.mass * G
    assert np.isfinite(physics.grf).all() and np.isfinite(physics.residual).all()
    assert np.linalg.norm(physics.residual[:, :3], axis=1).max() <= bound * (1 + 1e-9)
    assert physics.unexplained.all()
    assert np.isfinite(physics.qpos).all()


def test_the_result_file_carries_the_unexplained_frames(body, tmp_path):
    import dataclasses

    from physmocap.camera import Camera, Floor
    from physmocap.kinematics.calibration import Calibration
    from physmocap.kinematics.stage import KinematicMotion
    from physmocap.result import build_result, load_result, save_result
    from test_fit import observe

    q, _ = raised(body)
    T = len(q)
    camera = Camera.from_settings((1280, 720), fov=60)
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    camera = camera.with_extrinsics(R, -R @ np.array([0.0, -4.0, 1.0]))
    motion = KinematicMotion(body, Calibration(body.lengths, 1.0, 30, ()), camera,
                             Floor(R[:, 2], float(-R[:, 2] @ camera.t)), q, np.zeros(T), np.ones(T, bool), 0.0, False)
    obs = observe(body, q, camera)
    contacts, stationary = np.ones((T, 4), bool), np.zeros(T, bool)
    physics = run_physcap(body, q, 30.0, contacts, stationary, PhysicsSettings())
    assert physics.unexplained.any()
    save_result(tmp_path / "result.npz", build_result(obs, motion, {}, {}, contacts, stationary, physics))
    np.testing.assert_array_equal(load_result(tmp_path / "result.npz")["physics_unexplained"], physics.unexplained)
    # Without physics, or physics read back from an older cache that did not keep the flags: none flagged.
    assert not build_result(obs, motion, {}, {}, contacts, stationary)["physics_unexplained"].any()
    older = dataclasses.replace(physics, unexplained=None)
    assert build_result(obs, motion, {}, {}, contacts, stationary, older)["physics_unexplained"].dtype == bool


def test_refined_kinematics_are_tracked_without_lifting_their_targets(body):
    # B.4 placed the feet: a fit 3 cm under the floor is lifted out of it, refined kinematics are not (the floor
    # holds the character up, 3 cm above the target its PD tracks, on the feet).
    q = standing(body, 40)
    q[:, 2] -= 0.03
    weight = body.mass * G
    for refined_input, lift in ((False, 0.03), (True, 0.0)):
        stream = PhysicsStream(body, PhysicsSettings(), 30.0, refined_input=refined_input)
        for pose in q:
            _, frame, _ = stream.push(pose, np.ones(4, bool), False)
        tracked_target = stream.tracker._previous_target  # the pose the PD tracked in the last frame
        assert abs(tracked_target[2] - q[-1, 2] - lift) < 0.003
        assert abs(frame.contact_forces[:, 2].sum() - weight) < 0.05 * weight
        assert abs(frame.residual[2]) < 0.02 * weight


def standing(body, frames):
    return np.repeat(body.rest_qpos[None], frames, axis=0)


def test_every_number_in_the_result_file_is_finite_with_personless_frames(body, tmp_path):
    """A run whose observations hold frames without a person (no keypoints, NaN as another detector writes them)
    writes only finite numbers; where the reprojection error could not be measured the file says so in
    reprojection_measured instead of writing NaN."""
    from physmocap.camera import Camera
    from physmocap.config import Settings
    from physmocap.motion import Observations
    from physmocap.pipeline import run_capture
    from test_fit import observe

    _, q = swaying(body, 30.0, seconds=2.0)
    camera = Camera.from_settings((1280, 720), fov=60)
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    camera = camera.with_extrinsics(R, -R @ np.array([0.0, -4.0, 1.0]))
    obs = observe(body, q, camera)
    gone = np.zeros(len(q), bool)
    gone[25:33] = True
    keypoints, landmarks = obs.keypoints_2d.copy(), obs.landmarks_3d.copy()
    keypoints[gone], landmarks[gone] = np.nan, np.nan
    path = tmp_path / "observations.npz"
    Observations(keypoints, landmarks, obs.fps, obs.image_size, camera_K=obs.camera_K, valid=~gone,
                 invalid_reason=np.where(gone, "no person", "")).save(path)
    run_capture(tmp_path / "run", Settings(), observations=path, overlay=False)
    with np.load(tmp_path / "run" / "result.npz") as result:
        for key in result.files:
            values = result[key]
            if values.dtype.kind in "fc":
                assert np.isfinite(values).all(), key
        measured = result["reprojection_measured"]
        assert not measured[gone].any() and measured[~gone].all()
        assert (result["reprojection_error"][measured] > 0).all()


def test_a_start_hovering_above_the_floor_begins_on_it_instead_of_falling(body):
    """The fit's first frames hover 7 cm above the floor and come down over 8 frames with no contact labelled (as
    B.4 leaves a real clip's start): the character starts on the floor and follows the feet down, instead of
    falling onto it and landing at several body weights."""
    fps, frames = 60.0, 60
    q = standing(body, frames)
    q[:, 2] += np.clip(0.07 * (1 - np.arange(frames) / 8), 0.0, None)
    contacts = np.ones((frames, 4), bool)
    contacts[:8] = False
    weight = body.mass * G
    for settings, bound in ((PhysicsSettings(start_drop_time=None), None), (PhysicsSettings(), 1.2)):
        physics = run_physcap(body, q, fps, contacts, np.zeros(frames, bool), settings, refined_input=True)
        largest = np.linalg.norm(physics.grf.sum(axis=1), axis=-1).max() / weight
        soles = kin.forward_kinematics(body, physics.qpos).points[:, body.point_index(CONTACT_POINTS), 2]
        if bound is None:
            assert largest > 2.0 and soles[0].min() > 0.05  # the fall this guards against
        else:
            assert largest < bound and np.abs(soles[:10].min(axis=1)).max() < 0.005


def seated_then_squatting(body):
    """(137, nq) poses at 30 fps, feet on the floor: standing 1 s, seated 1.5 s (thighs level, knees bent square),
    standing 1 s, the same posture 0.4 s (a squat to scoop), standing."""
    spans = [(False, 30), (True, 45), (False, 30), (True, 12), (False, 20)]
    sitting = np.concatenate([np.full(n, s) for s, n in spans])
    step = np.zeros((len(sitting), body.nv))
    for side in ("left", "right"):
        step[sitting, body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = -np.pi / 2
        step[sitting, body.dof_address[body.joint_index[f"{side}_knee"]]] = np.pi / 2
    q = kin.integrate(body, np.repeat(body.rest_qpos[None], len(sitting), axis=0), step)
    q[:, 2] -= kin.forward_kinematics(body, q).points[:, body.point_index(CONTACT_POINTS), 2].min(axis=1)
    return q


def test_a_body_seated_for_a_second_is_flagged_and_a_brief_squat_is_not(body):
    """Thighs level with the knees bent square, for 1.5 s (seated on a stool) and for 0.4 s (a squat to scoop):
    a seat carries a seated body, which the contact model has no point for (the feet claimed the whole weight on
    CMU's stool clips). The seated stretch is flagged and claims no force; the brief one is the feet's."""
    from physmocap.body.support import SEATED_TIME, seated_frames

    fps = 30.0
    q = seated_then_squatting(body)
    points = kin.forward_kinematics(body, q).points
    seated = seated_frames(body.point_names, points, fps, np.ones(len(q), bool))
    assert seated[30:75].all() and seated.sum() == 45 and 12 < SEATED_TIME * fps
    assert not seated_frames(body.point_names, points, fps, np.arange(len(q)) != 50)[30:75].any()  # a gap splits it
    contacts = np.ones((len(q), 4), bool)
    physics = run_physcap(body, q, fps, contacts, np.ones(len(q), bool), PhysicsSettings(), refined_input=True)
    assert physics.unexplained[30:75].all() and not physics.grf[30:75].any()
    assert not physics.unexplained[110:117].any()  # the brief squat, away from its blends


def test_online_a_body_seated_for_a_second_is_flagged_from_then_on(body):
    """Causally the stream cannot know a seated stretch's length before it has lasted: it flags the seated frames
    from SEATED_TIME on, and the brief squat never."""
    from physmocap.body.support import SEATED_TIME

    fps = 30.0
    q = seated_then_squatting(body)
    physics = run_physcap(body, q, fps, np.ones((len(q), 4), bool), np.zeros(len(q), bool), PhysicsSettings())
    after = 30 + int(np.ceil(SEATED_TIME * fps)) - 1  # the seated stretch's first SEATED_TIME, this frame included
    # (the test's sit and stand are one-frame jumps, which the other checks flag for a few frames after each)
    assert physics.unexplained[after:75].all() and not physics.unexplained[40:after].any()
    assert not physics.unexplained[110:117].any()  # the brief squat


def test_the_streams_float_thigh_test_agrees_with_the_array_one():
    from physmocap.body.support import thighs_level, thighs_level_now

    rng = np.random.default_rng(3)
    points = rng.normal(size=(500, 4, 3))
    assert [thighs_level_now(*p.tolist()) for p in points] == thighs_level(points).tolist()
    assert thighs_level(points).any() and not thighs_level(points).all()
