import dataclasses

import numpy as np
import pytest

from conftest import assert_frame_terms_jacobian, random_poses
from physmocap import metrics
from physmocap.body import kinematics as kin
from physmocap.camera import Camera
from physmocap.config import FitSettings, Settings
from physmocap.kinematics.calibration import calibrate
from physmocap.kinematics.fit import MARKER_LANDMARKS, MARKERS, FitTargets, KinematicFitter, _soft_excess
from physmocap.kinematics.online import steps_per_frame
from physmocap.kinematics.stage import fit_motion, reprojection_errors
from physmocap.kinematics.targets import make_targets
from physmocap.motion import Observations


def walking_motion(body, frames, fps=30.0, stride_hz=0.9, turn=0.0):
    """A smooth motion: walking forward past the camera while swinging the legs and arms (a stride every
    1 / stride_hz s), turned 0.3 rad about the vertical and turning on at `turn` rad/s."""
    t = np.arange(frames) / fps
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    step = np.zeros((frames, body.nv))
    phase = 2 * np.pi * stride_hz * t
    step[:, 5] = 0.3 + turn * t
    for side, sign in (("left", 1.0), ("right", -1.0)):
        step[:, body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = 0.4 * sign * np.sin(phase)
        step[:, body.dof_address[body.joint_index[f"{side}_knee"]]] = 0.5 + 0.4 * np.sin(phase + sign)
        step[:, body.dof_address[body.joint_index[f"{side}_shoulder"]]] = sign * 1.3
        step[:, body.dof_address[body.joint_index[f"{side}_elbow"]]] = 0.3
    q = kin.integrate(body, q, step)
    q[:, 0] += 1.2 * t
    return q


def observe(body, qpos, camera, fps=30.0):
    """Perfect observations of the model's own markers."""
    pts = kin.forward_kinematics(body, qpos).points[:, body.point_index([b for _, b in MARKERS])]
    T = len(qpos)
    k2 = np.zeros((T, 33, 3))
    k3 = np.zeros((T, 33, 3))
    k2[:, MARKER_LANDMARKS, :2] = camera.project(pts)
    k2[:, MARKER_LANDMARKS, 2] = 0.95
    pelvis = kin.forward_kinematics(body, qpos).points[:, 0]
    k3[:, MARKER_LANDMARKS] = (pts - pelvis[:, None]) @ camera.R.T
    # The face and hand landmarks that the calibration measures but the fit does not use.
    return Observations(k2, k3, fps, camera.image_size, camera_K=camera.K)


@pytest.fixture(scope="module")
def camera():
    cam = Camera.from_settings((1280, 720), fov=60)
    # Camera 4 m in front of the walker, 1.2 m high, looking slightly down.
    pitch = np.radians(8)
    R = np.array([[1, 0, 0], [0, -np.sin(pitch), -np.cos(pitch)], [0, np.cos(pitch), -np.sin(pitch)]])
    center = np.array([0.5, -4.0, 1.2])
    return cam.with_extrinsics(R, -R @ center)


def _targets(body, qpos, camera, rng):
    T = len(qpos)
    M = len(MARKERS)
    points = kin.forward_kinematics(body, qpos).points
    pts = points[:, body.point_index([b for _, b in MARKERS])]
    pelvis = points[:, body.point_index(["pelvis"])]  # the fit's 3D targets are relative to the pelvis point
    return FitTargets(camera.project(pts) + rng.normal(scale=3, size=(T, M, 2)), rng.uniform(0.5, 1, (T, M)),
                      pts - pelvis + rng.normal(scale=0.02, size=(T, M, 3)), rng.uniform(0.3, 1, (T, M)),
                      np.full(T, 4.0))


def test_frame_terms_jacobian_matches_finite_differences(body, camera):
    rng = np.random.default_rng(0)
    q = random_poses(body, 3, rng, scale=0.5)
    # Robust weights are held fixed within a linearisation: compare the Jacobian with them off.
    fitter = KinematicFitter(body, camera, FitSettings(weight_prior=0.3, robust_2d=0, robust_3d=0), 30.0)
    targets = _targets(body, q, camera, rng)
    # push some hinges beyond their limits so that the limit term is active, others into its rounded band
    q[:, body.qpos_address[body.joint_index["left_knee"]]] = -0.3
    q[:, body.qpos_address[body.joint_index["right_knee"]]] = np.radians(-5) + np.array([-0.1, 0.05, 0.15])
    q[:, body.qpos_address[body.joint_index["left_elbow"]]] = np.radians(155) + np.array([-0.15, 0.0, 0.12])
    assert_frame_terms_jacobian(fitter, q, targets)


def test_soft_limit_excess_is_rounded_only_within_its_band():
    excess = np.linspace(-0.5, 0.5, 1001)
    value, slope = _soft_excess(excess, 0.2)
    far = np.abs(excess) >= 0.2
    assert np.allclose(value[far], np.maximum(excess[far], 0.0))
    assert np.all(value >= np.maximum(excess, 0.0)) and np.all(np.diff(value) >= 0)
    assert np.allclose(np.gradient(value, excess)[1:-1], slope[1:-1], atol=2e-3)  # continuous slope, no kink
    kink, kink_slope = _soft_excess(excess, 0.0)
    assert np.array_equal(kink, np.maximum(excess, 0.0)) and np.array_equal(kink_slope, (excess > 0) * 1.0)


def test_temporal_signal_jacobians_match_finite_differences(body, camera):
    rng = np.random.default_rng(1)
    q = random_poses(body, 2, rng)
    fitter = KinematicFitter(body, camera, FitSettings(weight_velocity=0.1, weight_com_acceleration=1.0), 25.0)
    targets = _targets(body, q, camera, rng)
    targets.contacts = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])

    def all_signals(q):
        points, jac = fitter.evaluate(q)
        return fitter.temporal_signals(points, jac) + fitter.com_signals(
            points, jac, targets.with_free_fall(np.array([0.0, 0.0, 1.0]), 25.0))

    signals = all_signals(q)
    assert len(signals) == 4
    eps = 1e-6
    for k in range(body.nv):
        step = np.zeros((2, body.nv))
        step[:, k] = eps
        plus = all_signals(fitter.integrate(q, step))
        minus = all_signals(fitter.integrate(q, -step))
        for (_, J, _, _), (vp, _, _, _), (vm, _, _, _) in zip(signals, plus, minus, strict=True):
            assert np.allclose((vp - vm) / (2 * eps), J[..., k], atol=1e-7)


def test_centre_of_mass_term_smooths_the_centre_of_mass_not_the_pose(body, camera):
    """The whole-clip fit of a noisy walk with the centre of mass's acceleration penalised (no contacts given: drawn
    towards no acceleration): the force its centre of mass implies (m (z'' + g), second differences) is far
    steadier, the pose as good."""
    spread, error = {}, {}
    for weight in (0.0, 100.0):
        motion, truth = fit_noisy_walk(body, camera, 30.0, 3, np.random.default_rng(3),
                                       Settings().replace("fit", weight_com_acceleration=weight))
        pose, true = kin.forward_kinematics(motion.body, motion.qpos), kin.forward_kinematics(body, truth).points
        vertical = kin.center_of_mass(motion.body, pose) @ camera.R[:, 2]
        spread[weight] = np.std(np.diff(vertical, 2)[5:-5]) * 30.0 ** 2 / metrics.GRAVITY  # body weights
        error[weight] = np.linalg.norm((pose.points - pose.points[:, :1]) - (true - true[:, :1]), axis=-1).mean()
    assert spread[100.0] < 0.5 * spread[0.0]
    assert error[100.0] < 1.05 * error[0.0]


def test_free_fall_path_accelerates_at_gravity_in_flight_only(body, camera):
    """The centre of mass's term draws it towards gravity's acceleration on observed frames without a foot in
    contact (a jump's arc is not flattened), towards none on frames in contact or unobserved."""
    rng = np.random.default_rng(5)
    targets = _targets(body, random_poses(body, 8, rng), camera, rng)
    targets.contacts = np.zeros((8, 4))
    targets.contacts[:3, 0] = targets.contacts[6:, 2] = 1.0
    targets.weight_2d[4] = targets.weight_3d[4] = 0.0  # frame 4 unseen
    up = np.array([0.0, 0.0, 1.0])
    second = np.diff(targets.with_free_fall(up, 30.0).free_fall, 2, axis=0) * 30.0**2  # at frames 1 .. 6
    assert np.allclose(second[:, 2], [0.0, 0.0, -metrics.GRAVITY, 0.0, -metrics.GRAVITY, 0.0])
    assert np.allclose(second[:, :2], 0.0)


@pytest.mark.parametrize("frames", [1, 2, 5, 8])
def test_block_banded_solver_matches_dense_solve(frames):
    rng = np.random.default_rng(frames)
    nv = 6
    A = rng.normal(size=(frames * nv + 4, frames * nv))
    H_dense = A.T @ A + np.eye(frames * nv)
    # keep only the bands of up to two frames apart, the structure the fitter produces
    band = np.abs(np.subtract.outer(np.arange(frames * nv) // nv, np.arange(frames * nv) // nv)) <= 2
    H_dense = np.where(band, H_dense, 0.0) + 10 * frames * np.eye(frames * nv)
    H = np.zeros((3, frames, nv, nv))
    for k in range(3):
        for s in range(frames - k):
            H[k, s] = H_dense[s * nv:(s + 1) * nv, (s + k) * nv:(s + k + 1) * nv]
    g = rng.normal(size=(frames, nv))
    damping = 0.1
    scale = rng.uniform(0.5, 2.0, size=nv)
    expected = np.linalg.solve(H_dense + damping * np.diag(np.tile(scale, frames)) + 1e-9 * np.eye(frames * nv),
                               -g.ravel())
    assert np.allclose(KinematicFitter._solve_banded(g, H, damping, scale).ravel(), expected, atol=1e-9)


@pytest.mark.parametrize("online", [False, True])
def test_fit_recovers_a_known_motion_from_its_projections(body, camera, online):
    truth = walking_motion(body, 40)
    obs = observe(body, truth, camera)
    settings = Settings(online=online).replace("body", height=body.height, mass=body.mass)
    up = camera.R[:, 2]  # the world's z axis in camera coordinates: the floor is up . (x - t) = 0
    settings = settings.replace("camera", floor=tuple(np.append(up, -up @ camera.t)))
    motion = fit_motion(obs, settings)
    assert np.nanmedian(reprojection_errors(motion.body, motion.camera, motion.qpos, obs)) < 2.0
    fitted = kin.forward_kinematics(motion.body, motion.qpos).points[:, :20]
    true = kin.forward_kinematics(body, truth).points[:, :20]
    # The fit's world has its origin below the first pelvis: compare in the camera frame.
    error = np.linalg.norm(motion.camera.to_camera(fitted) - camera.to_camera(true), axis=-1)
    assert np.median(error) < 0.03
    # The floor given is the true one: the soles touch z = 0 in the fitted world too.
    soles = kin.forward_kinematics(motion.body, motion.qpos).points[:, motion.body.point_index(
        ["left_heel", "left_toe", "right_heel", "right_toe"])]
    true_soles = kin.forward_kinematics(body, truth).points[:, body.point_index(
        ["left_heel", "left_toe", "right_heel", "right_toe"])]
    assert np.allclose(soles[..., 2].min(axis=1), true_soles[..., 2].min(axis=1), atol=0.03)


def test_angle_speed_huber_shrinks_fast_legs_less(body, camera):
    """Rempe's joint-angle velocity term pulls every joint towards standing still; on legs swinging at up to
    7.5 rad/s (noise-free observations) it shrinks the swing. With angle_speed_huber it pulls linearly above
    2 rad/s (here on every frame: these legs swing in place), and the fit comes nearer the truth
    (docs/decisions/b4-angle-velocity.md)."""
    T = 60
    phase = 2 * np.pi * 1.5 * np.arange(T) / 30.0
    step = np.zeros((T, body.nv))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        step[:, body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = 0.6 * sign * np.sin(phase)
        step[:, body.dof_address[body.joint_index[f"{side}_knee"]]] = 0.9 + 0.8 * np.sin(phase + sign)
    truth = kin.integrate(body, np.repeat(body.rest_qpos[None], T, axis=0), step)
    obs = observe(body, truth, camera)
    true = camera.to_camera(kin.forward_kinematics(body, truth).points[:, :20])
    errors = {}
    for huber in (0.0, 2.0):
        settings = Settings().replace("body", height=body.height, mass=body.mass).replace(
            "fit", weight_angle_velocity=0.1, angle_speed_huber=huber, angle_speed_huber_frames="all")
        motion = fit_motion(obs, settings)
        fitted = motion.camera.to_camera(kin.forward_kinematics(motion.body, motion.qpos).points[:, :20])
        errors[huber] = np.linalg.norm((fitted - fitted[:, :1]) - (true - true[:, :1]), axis=-1).mean()
    assert errors[2.0] < 0.8 * errors[0.0]


@pytest.mark.slow
def test_robust_weights_resist_gross_detector_errors(body, camera):
    """A detector that throws one ankle 40 cm off for a few frames should not drag the fitted leg along."""
    truth = walking_motion(body, 40)
    obs = observe(body, truth, camera)
    ankle = MARKER_LANDMARKS[[b for _, b in MARKERS].index("left_ankle")]
    wrong = slice(30, 36)
    obs.keypoints_2d[wrong, ankle, :2] += camera.focal * 0.4 / 4.0  # 40 cm at 4 m, to the side
    obs.landmarks_3d[wrong, ankle, 0] += 0.4
    up = camera.R[:, 2]
    floor = tuple(np.append(up, -up @ camera.t))
    errors = {}
    for robust in (True, False):
        fit = FitSettings() if robust else FitSettings(robust_2d=0, robust_3d=0)
        settings = Settings(fit=fit).replace("body", height=body.height).replace("camera", floor=floor)
        motion = fit_motion(obs, settings)
        ids = motion.body.point_index(["left_knee", "left_ankle"])
        fitted = motion.camera.to_camera(kin.forward_kinematics(motion.body, motion.qpos).points[wrong][:, ids])
        true = camera.to_camera(kin.forward_kinematics(body, truth).points[wrong][:, ids])
        errors[robust] = np.linalg.norm(fitted - true, axis=-1).mean()
    print(errors)
    assert errors[True] < 0.5 * errors[False]


def test_one_euro_filter_removes_jitter_and_keeps_orientations_valid(body):
    from physmocap.kinematics.filters import one_euro_qpos

    rng = np.random.default_rng(3)
    still = np.repeat(body.rest_qpos[None], 60, axis=0)
    noisy = kin.integrate(body, still, rng.normal(scale=0.02, size=(60, body.nv)))
    filtered = one_euro_qpos(body, noisy, fps=30.0)
    error_noisy = np.abs(kin.difference(body, still, noisy)).mean()
    error_filtered = np.abs(kin.difference(body, still[20:], filtered[20:])).mean()
    assert error_filtered < 0.5 * error_noisy
    quats = filtered[:, 3:7]
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0)
    # Fast motion lags less than with a fixed low-pass filter at the minimum cutoff (beta = 0): the speed term.
    moving = still.copy()
    moving[:, 0] = 3.0 * np.arange(60) / 30.0
    lag = np.abs(one_euro_qpos(body, moving, fps=30.0)[30:, 0] - moving[30:, 0]).max()
    fixed_lag = np.abs(one_euro_qpos(body, moving, fps=30.0, beta=0.0)[30:, 0] - moving[30:, 0]).max()
    assert lag < 0.6 * fixed_lag


def test_batched_frames_are_fitted_as_if_each_were_alone(body, camera):
    """fit_frames runs one Levenberg-Marquardt per frame side by side: the same poses as one at a time."""
    rng = np.random.default_rng(6)
    truth = walking_motion(body, 6)
    targets = _targets(body, truth, camera, rng)
    fitter = KinematicFitter(body, camera, FitSettings(), 30.0)
    start = kin.integrate(body, truth, rng.normal(scale=0.05, size=(6, body.nv)))
    history = [v[:, None] for v in fitter.signal_values(truth)]  # each frame's own one-frame past
    together = fitter.fit_frames(start, targets, history, 4)
    for k in range(6):
        alone = fitter.fit_frames(start[k:k + 1], targets.frames(slice(k, k + 1)), [h[k:k + 1] for h in history], 4)
        assert np.allclose(alone.qpos, together.qpos[k:k + 1], atol=1e-9)
        assert np.allclose(alone.signals[0], together.signals[0][k:k + 1], atol=1e-9)


def test_offline_fit_bridges_a_gap_without_extrapolating(body, camera):
    """Frames without a person are interpolated between their fitted neighbours, never run off."""
    truth = walking_motion(body, 40)
    obs = observe(body, truth, camera)
    obs.valid[15:22] = False
    up = camera.R[:, 2]
    settings = Settings().replace("body", height=body.height, mass=body.mass)
    motion = fit_motion(obs, settings.replace("camera", floor=tuple(np.append(up, -up @ camera.t))))
    pelvis = motion.camera.to_camera(motion.qpos[:, :3])
    true = camera.to_camera(truth[:, :3])
    assert np.linalg.norm(pelvis - true, axis=1)[15:22].max() < 0.1


def fit_noisy_walk(body, camera, fps, seconds, rng, settings=None, **walk):
    """The test walk (`walk`: walking_motion's stride_hz, turn) observed at `fps` with 2 px and 2 cm of noise,
    fitted with the floor and the body known (and `settings`, default Settings()): returns the fitted motion and the
    true poses."""
    truth = walking_motion(body, int(seconds * fps), fps, **walk)
    obs = observe(body, truth, camera, fps)
    obs.keypoints_2d[..., :2] += rng.normal(scale=2.0, size=obs.keypoints_2d[..., :2].shape)
    obs.landmarks_3d += rng.normal(scale=0.02, size=obs.landmarks_3d.shape)
    up = camera.R[:, 2]
    settings = (settings or Settings()).replace("body", height=body.height, mass=body.mass)
    return fit_motion(obs, settings.replace("camera", floor=tuple(np.append(up, -up @ camera.t)))), truth


@pytest.mark.slow
def test_offline_fit_converges_as_well_at_120_fps_as_at_30(body, camera):
    """The same walk observed with the same noise at 30 and 120 fps: the fit's pose is as good at both rates.
    Marquardt's damping scaled by the whole system's diagonal, whose temporal part grows with the frame rate
    (the acceleration's as fps^4), held the 120 fps fit back: 16.9 mm against 10.5 at 30 fps here."""
    rng = np.random.default_rng(0)
    errors = {}
    for fps in (30.0, 120.0):
        motion, truth = fit_noisy_walk(body, camera, fps, 2, rng)
        fitted = kin.forward_kinematics(motion.body, motion.qpos).points
        true = kin.forward_kinematics(body, truth).points
        errors[fps] = np.linalg.norm((fitted - fitted[:, :1]) - (true - true[:, :1]), axis=-1).mean()
    assert errors[120.0] < 1.15 * errors[30.0]


def test_steps_per_frame_are_as_many_per_second_below_30_fps():
    assert [steps_per_frame(2, fps) for fps in (10.0, 12.0, 24.0, 25.0, 29.97, 30.0, 60.0)] == [6, 5, 3, 2, 2, 2, 2]
    assert [steps_per_frame(4, fps) for fps in (8.0, 10.0, 30.0, 120.0)] == [15, 12, 4, 4]


@pytest.mark.slow
@pytest.mark.parametrize("online", [False, True])
def test_fit_follows_a_fast_turn_at_10_fps_as_at_30(body, camera, online):
    """A jog turning at 4 rad/s, observed with the same noise at 30 and 10 fps: offline and online, the pose is
    about as good at both rates. With the steps per frame of 30 fps at 10 fps, where each frame's pose lies three
    times further from its prediction, the offline start turned pelvises half round and the whole-clip fit kept
    them: 27 mm against 12 at 30 fps here (online 21 against 14)."""
    errors = {}
    for fps in (30.0, 10.0):
        motion, truth = fit_noisy_walk(body, camera, fps, 3, np.random.default_rng(0), Settings(online=online),
                                       stride_hz=2.0, turn=4.0)
        fitted = kin.forward_kinematics(motion.body, motion.qpos).points
        true = kin.forward_kinematics(body, truth).points
        errors[fps] = np.linalg.norm((fitted - fitted[:, :1]) - (true - true[:, :1]), axis=-1).mean()
    assert errors[10.0] < 1.3 * errors[30.0]


@pytest.mark.slow
def test_online_fit_follows_the_motion_at_120_fps_as_at_30(body, camera):
    """The same walk, the same noise per frame, fitted online at 30 and 120 fps: the pose is as good at both rates
    and the jitter (second differences, which grow with the rate on per-frame noise) about twice. With the
    temporal weights scaled as the whole-clip fit's (acceleration as fps^4), the causal filter's rise time grew
    with the frame rate and it rang: 17.8 mm root-relative and 79 m/s^2 at 120 fps, against 12.2 and 19 at 30."""
    rng = np.random.default_rng(0)
    errors, jitter = {}, {}
    for fps in (30.0, 120.0):
        motion, truth = fit_noisy_walk(body, camera, fps, 4, rng, Settings(online=True))
        fitted = kin.forward_kinematics(motion.body, motion.qpos).points
        true = kin.forward_kinematics(body, truth).points
        errors[fps] = np.linalg.norm((fitted - fitted[:, :1]) - (true - true[:, :1]), axis=-1).mean()
        jitter[fps] = metrics.mean_acceleration(fitted, fps)
    assert errors[120.0] < 1.15 * errors[30.0]
    assert jitter[120.0] < 2.5 * jitter[30.0]


def test_damping_scale_is_the_frames_own_terms_whatever_the_rate(body, camera):
    """The damping's scale comes from the diagonal of the frames' own terms: the same poses and targets give the
    same at 30 and 120 fps, where the whole system's diagonal grows with the temporal terms."""
    rng = np.random.default_rng(4)
    T = 6
    q = random_poses(body, T, rng, scale=0.3)
    targets = _targets(body, q, camera, rng)
    own, diagonal = {}, {}
    for fps in (30.0, 120.0):
        own[fps] = np.empty((T, body.nv))
        _, _, H = KinematicFitter(body, camera, FitSettings(), fps)._offline_system(q, targets, scale=own[fps])
        diagonal[fps] = np.einsum("tii->ti", H[0])
    assert np.allclose(own[30.0], own[120.0], rtol=1e-12, atol=0.0)
    assert (diagonal[120.0] - own[120.0]).max() > 100 * (diagonal[30.0] - own[30.0]).max()


def test_offline_fit_holds_the_pose_before_the_person_appears_and_after_they_leave(body, camera):
    truth = walking_motion(body, 40)
    obs = observe(body, truth, camera)
    obs.valid[:5] = obs.valid[35:] = False
    up = camera.R[:, 2]
    settings = Settings().replace("body", height=body.height, mass=body.mass)
    motion = fit_motion(obs, settings.replace("camera", floor=tuple(np.append(up, -up @ camera.t))))
    assert np.array_equal(motion.qpos[:5], np.repeat(motion.qpos[5:6], 5, axis=0))
    assert np.array_equal(motion.qpos[35:], np.repeat(motion.qpos[34:35], 5, axis=0))


def test_hand_markers_weigh_less_in_both_data_terms(body, camera):
    obs = observe(body, walking_motion(body, 3), camera)
    calibration = calibrate(obs, body.height)
    depth = np.full(3, 4.0)

    def targets(hand_weight):
        fit = FitSettings(hand_weight=hand_weight)
        return make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, depth, camera, calibration, fit)

    full, light = targets(1.0), targets(0.25)
    hands = np.array([a in ("left_pinky", "right_pinky", "left_index", "right_index") for a, _ in MARKERS])
    for a, b in ((full.weight_2d, light.weight_2d), (full.weight_3d, light.weight_3d)):
        assert np.allclose(b[:, hands], 0.5 * a[:, hands]) and np.array_equal(b[:, ~hands], a[:, ~hands])
        assert (a[:, hands] > 0).all()


def test_lengths_measured_again_along_the_fitted_axes_lose_the_noise_bias(camera):
    """The detector's noise across a segment lengthens the median distance between its landmarks; measured along
    the fitted axes (here the true motion's), the limbs' and feet's lengths come back, also those the template
    had wrong (heel behind the ankle, ankle height)."""
    from physmocap.body.model import build_body_model, template_lengths
    from physmocap.kinematics.calibration import Calibration
    from physmocap.kinematics.targets import REFINED_LENGTHS, refine_lengths

    template = template_lengths(1.75)
    true = dataclasses.replace(template, upper_arm=template.upper_arm + 0.02, heel_back=0.03, ankle_height=0.065)
    body = build_body_model(true, 70.0)
    motion = walking_motion(body, 120)
    rng = np.random.default_rng(3)
    obs = observe(body, motion, camera)
    obs.keypoints_2d[..., :2] += rng.normal(scale=2.0, size=obs.keypoints_2d[..., :2].shape)
    obs.landmarks_3d[:] += rng.normal(scale=0.04, size=obs.landmarks_3d.shape)
    calibrated = calibrate(obs, true.standing_height, frames=0)
    assert calibrated.lengths.upper_arm - true.upper_arm > 0.005  # the noise's bias
    depth = camera.to_camera(kin.forward_kinematics(body, motion).points[:, 0])[:, 2]
    targets = make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, depth, camera,
                           Calibration(template, 1.0, 120, ()), FitSettings())
    start = Calibration(template, 1.0, 120, ("heel_back",))  # the template's lengths, the same joint angles
    refined = refine_lengths(build_body_model(template, 70.0), camera, motion, targets, start, true.standing_height)
    for name in REFINED_LENGTHS:
        assert abs(getattr(refined.lengths, name) - getattr(true, name)) < 0.004, name
    assert refined.replaced == ()  # measured now
    assert abs(refined.lengths.standing_height - true.standing_height) < 1e-9


@pytest.mark.slow
def test_online_warmup_starts_again_after_a_gap_without_a_person(body, camera):
    """A lone small detection (a quarter of the person's size: four times as far), then frames without anyone,
    then the person: the warm-up fits the person's run from a cold start, as offline, instead of carrying the
    lone frame's distance into it (a real video's walk-in, docs/decisions/physics-online-feet.md)."""
    truth = walking_motion(body, 100)
    obs = observe(body, truth, camera)
    centre = obs.keypoints_2d[10, :, :2][obs.keypoints_2d[10, :, 2] > 0].mean(axis=0)
    obs.keypoints_2d[0, :, :2] = centre + 0.25 * (obs.keypoints_2d[10, :, :2] - centre)
    obs.landmarks_3d[0] = obs.landmarks_3d[10]
    obs.valid[1:10] = False
    up = camera.R[:, 2]
    settings = Settings(online=True).replace("body", height=body.height, mass=body.mass)
    motion = fit_motion(obs, settings.replace("camera", floor=tuple(np.append(up, -up @ camera.t))))
    error = np.linalg.norm(motion.camera.to_camera(motion.qpos[:, :3]) - camera.to_camera(truth[:, :3]), axis=1)
    assert error[10:20].max() < 0.15


def test_online_warmup_measures_the_lengths_again(body, camera):
    """The online fit's warm-up measures the lengths again as the offline fit does: with noisy 3D landmarks the
    arms and the heel come out nearer the truth than the calibration's medians make them."""
    truth = walking_motion(body, 100)
    obs = observe(body, truth, camera)
    rng = np.random.default_rng(5)
    obs.landmarks_3d[:] += rng.normal(scale=0.04, size=obs.landmarks_3d.shape)
    settings = Settings(online=True).replace("body", height=body.height, mass=body.mass)
    errors = {}
    for refine in (False, True):
        lengths = fit_motion(obs, settings.replace("fit", refine_lengths=refine)).body.lengths
        errors[refine] = sum(abs(getattr(lengths, n) - getattr(body.lengths, n))
                             for n in ("upper_arm", "forearm", "heel_back"))
    assert errors[True] < 0.5 * errors[False]


def dense_system(fitter, qpos, targets):
    """The Gauss-Newton system of the whole clip written out densely, every residual row with its full Jacobian
    row: cost, gradient (T, nv), matrix (T nv, T nv) and the diagonal of the frames' own terms (T, nv), whose mean
    over the frames is the damping's scale."""
    T, nv = len(qpos), fitter.body.nv
    points, jac = fitter.evaluate(qpos)
    r, J = fitter.frame_terms(qpos, points, jac, targets)
    own = np.stack([np.diag(J[t].T @ J[t]) for t in range(T)])
    residuals, rows = [r.ravel()], []
    for t in range(T):
        block = np.zeros((J.shape[1], T * nv))
        block[:, t * nv:(t + 1) * nv] = J[t]
        rows.append(block)
    signals = fitter.temporal_signals(points, jac, qpos, fitter.huber_frames(qpos, targets.contacts))
    for values, jacobians, coeffs, pair_weights in signals + fitter.contact_signals(points, jac, targets):
        for u in range(T - len(coeffs) + 1):
            weight = np.ones(values.shape[1]) if pair_weights is None else pair_weights[u]
            residuals.append(weight * sum(c * values[u + a] for a, c in enumerate(coeffs)))
            block = np.zeros((values.shape[1], T * nv))
            for a, c in enumerate(coeffs):
                block[:, (u + a) * nv:(u + a + 1) * nv] += c * weight[:, None] * jacobians[u + a]
            rows.append(block)
    r, J = np.concatenate(residuals), np.concatenate(rows)
    return float(r @ r), (J.T @ r).reshape(T, nv), J.T @ J, own


@pytest.mark.parametrize("chunk", [1, 4, 256])
def test_chunked_assembly_equals_the_dense_system(body, camera, monkeypatch, chunk):
    """The whole-clip system assembled a few frames at a time (the temporal terms crossing the chunks' borders)
    is the dense one's block band, with every optional term on."""
    from physmocap.kinematics import fit as fit_module

    monkeypatch.setattr(fit_module, "ASSEMBLY_FRAMES", chunk)
    rng = np.random.default_rng(8)
    T = 9
    q = random_poses(body, T, rng, scale=0.3)
    # Still, then off at 15 m/s: the whole clip runs (its stride spans all 9 frames), a chunk of the first frames
    # alone would not; the Huber weights are judged on the whole clip.
    q[:, :2] = 0.0
    q[5:, 0] = 0.5 * np.arange(1, T - 4)
    settings = FitSettings(weight_contact_velocity=10.0, weight_floor=10.0, weight_velocity=0.1,
                           weight_angle_velocity=0.1, angle_speed_huber=4.0)  # some joints above it, some under
    targets = dataclasses.replace(_targets(body, q, camera, rng), contacts=rng.uniform(0, 1, (T, 4)),
                                  floor=np.array([0.0, 0.0, 1.0, 0.1]))
    fitter = KinematicFitter(body, camera, settings, 30.0)
    assert fitter.huber_frames(q, targets.contacts).all()
    frames = []
    own = np.empty((T, body.nv))
    cost, g, H = fitter._offline_system(q, targets, progress=frames.append, scale=own)
    dense_cost, dense_g, dense_H, dense_own = dense_system(fitter, q, targets)
    assert np.abs(own - dense_own).max() < 1e-12 * np.abs(dense_own).max()
    nv = body.nv
    assert abs(cost - dense_cost) < 1e-12 * dense_cost
    assert np.abs(g - dense_g).max() < 1e-12 * np.abs(dense_g).max()
    scale = np.abs(dense_H).max()
    for d in range(3):
        for t in range(T):
            block = dense_H[t * nv:(t + 1) * nv, (t + d) * nv:(t + d + 1) * nv] if t + d < T else 0.0
            assert np.abs(H[d, t] - block).max() < 1e-12 * scale
    assert frames == list(range(chunk, T, chunk)) + [T]


def reference_offline_fit(fitter, qpos, targets):
    """Levenberg-Marquardt as fit_offline runs it, with dense systems kept whole and solved densely: the same
    steps without the band factored in place. Returns the poses and the number of rejected steps."""
    T, nv = qpos.shape[0], fitter.body.nv
    cost, g, H, own = dense_system(fitter, qpos, targets)
    damping, rejected = 3.0, 0
    for _ in range(fitter.settings.offline_iterations):
        improved = False
        while damping < 1e8:
            A = H + damping * np.diag(np.tile(own.mean(axis=0), T)) + 1e-9 * np.eye(T * nv)
            q_new = fitter.integrate(qpos, np.linalg.solve(A, -g.ravel()).reshape(T, nv))
            cost_new, g_new, H_new, own_new = dense_system(fitter, q_new, targets)
            if cost_new < cost:
                decrease = (cost - cost_new) / cost
                qpos, cost, g, H, own, improved = q_new, cost_new, g_new, H_new, own_new, True
                damping = max(damping / 3, 1e-7)
                break
            damping *= 4
            rejected += 1
        if not improved or decrease < 1e-3:
            break
    return qpos, rejected


def test_offline_fit_with_its_band_factored_in_place_takes_the_reference_steps(body, camera, monkeypatch):
    """From a poor start some steps are rejected: the system at the current poses is assembled again after each
    and the fit ends where the dense reference does; progress counts every frame pass, ending at its total."""
    from physmocap.kinematics import fit as fit_module

    monkeypatch.setattr(fit_module, "ASSEMBLY_FRAMES", 3)  # progress within each pass too
    rng = np.random.default_rng(9)
    T = 7
    truth = walking_motion(body, T)
    targets = _targets(body, truth, camera, rng)
    fitter = KinematicFitter(body, camera, FitSettings(offline_iterations=12), 30.0)
    start = kin.integrate(body, truth, rng.normal(scale=0.6, size=(T, body.nv)))
    expected, rejected = reference_offline_fit(fitter, start, targets)
    assert rejected > 0
    calls = []
    result = fitter.fit_offline(start, targets, lambda done, total: calls.append((done, total)))
    assert np.abs(kin.difference(body, expected, result.qpos)).max() < 1e-6  # rounding, through 12 steps
    done = [d for d, _ in calls]
    assert done == sorted(done) and len(set(done)) > 2 * result.iterations and calls[-1] == (done[-1], done[-1])
    assert all(d < total for d, total in calls[:-1])  # the display closes at the end only
    assert done[-1] == T * (1 + result.iterations + 2 * rejected)  # a rejected step: its pass and one again
    assert calls[0][1] == fitter.planned_passes(T)


@pytest.mark.parametrize("online", [False, True])
def test_fit_reports_progress_for_each_of_its_parts(body, camera, online, monkeypatch):
    from physmocap.kinematics import fit as fit_module

    monkeypatch.setattr(fit_module, "ASSEMBLY_FRAMES", 8)
    obs = observe(body, walking_motion(body, 30), camera)
    obs.valid[:4] = False
    bars = {}

    def factory(name, total, unit="frames"):
        bars[name] = (unit, [])
        return lambda done, total_now: bars[name][1].append((done, total_now))

    settings = Settings(online=online).replace("body", height=body.height, mass=body.mass)
    fit_motion(obs, settings.replace("fit", offline_chunk=8), factory)
    expected = {"fit": "frames"} if online else {"fit start": "frames", "fit clip": "frame passes"}
    assert {name: unit for name, (unit, _) in bars.items()} == expected
    for name, (_, calls) in bars.items():
        done = [d for d, _ in calls]
        assert done == sorted(done) and len(set(done)) > 3 and calls[-1][0] == calls[-1][1], name
    if online:
        assert bars["fit"][1][-1] == (30, 30)
    else:
        assert bars["fit start"][1][-1] == (26, 26)  # the valid frames
        assert bars["fit clip"][1][-1][0] % 30 == 0  # whole passes over the clip


def test_assembly_and_solve_hold_no_buffer_that_grows_with_the_clip(body, camera, monkeypatch):
    """Beyond the bands (given) and vectors of the clip's length, the assembly holds one chunk's Jacobians and
    the solve a pair's blocks: their peak allocation stays put from 24 to 96 frames."""
    import tracemalloc

    from physmocap.kinematics import fit as fit_module

    monkeypatch.setattr(fit_module, "ASSEMBLY_FRAMES", 8)
    fitter = KinematicFitter(body, camera, FitSettings(), 30.0)
    peaks = {}
    for T in (24, 96):
        truth = walking_motion(body, T)
        targets = _targets(body, truth, camera, np.random.default_rng(T))
        band = np.empty((3, T, body.nv, body.nv))
        tracemalloc.start()
        scale = np.empty((T, body.nv))
        _, g, _ = fitter._offline_system(truth, targets, band, scale=scale)
        fitter._solve_banded(g, band, 1.0, scale.mean(axis=0))
        peaks[T] = tracemalloc.get_traced_memory()[1] - 20 * g.nbytes  # vectors of the clip's length allowed
        tracemalloc.stop()
    assert peaks[96] < 1.2 * peaks[24]
    assert peaks[96] < 0.2 * band.nbytes  # main's solve alone copied the bands five times
