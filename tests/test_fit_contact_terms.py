"""The kinematic fit's optional terms of Rempe et al. 2020 (B.3): contact velocity, contact position on the floor,
joint velocity and joint-angle velocity. Jacobians against finite differences on the manifold, the assembled
gradient against the cost, and the effect on a motion."""

import numpy as np
import pytest

from conftest import assert_frame_terms_jacobian, random_poses
from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS
from physmocap.body.support import RESTING_HEIGHT
from physmocap.camera import Camera
from physmocap.config import FitSettings
from physmocap.kinematics.fit import MARKERS, FitTargets, KinematicFitter, running_frames

# Reweighting (robust data terms, E_ang's Huber pull) off: its weights are held within a linearisation, so the
# cost's derivative would not be the assembled gradient.
ALL_TERMS = FitSettings(weight_contact_velocity=10.0, weight_floor=10.0, weight_velocity=0.1,
                        weight_angle_velocity=0.1, robust_2d=0, robust_3d=0, angle_speed_huber=0)


@pytest.fixture(scope="module")
def camera():
    cam = Camera.from_settings((1280, 720), fov=60)
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    return cam.with_extrinsics(R, -R @ np.array([0.0, -4.0, 1.0]))


def targets_for(body, qpos, camera, rng, contacts=None, floor=None):
    T, M = len(qpos), len(MARKERS)
    points = kin.forward_kinematics(body, qpos).points
    pts = points[:, body.point_index([b for _, b in MARKERS])]
    pelvis = points[:, body.point_index(["pelvis"])]  # the fit's 3D targets are relative to the pelvis point
    if contacts is None:
        contacts = rng.uniform(0, 1, (T, 4)).round()
    if floor is None:
        n = np.array([0.05, -0.03, 1.0])
        floor = np.append(n / np.linalg.norm(n), 0.02)
    return FitTargets(camera.project(pts) + rng.normal(scale=3, size=(T, M, 2)), rng.uniform(0.5, 1, (T, M)),
                      pts - pelvis + rng.normal(scale=0.02, size=(T, M, 3)), rng.uniform(0.3, 1, (T, M)),
                      np.full(T, 4.0), contacts, floor)


def test_defaults_leave_the_terms_off():
    s = FitSettings()
    assert s.weight_contact_velocity == s.weight_floor == s.weight_velocity == s.weight_angle_velocity == 0.0


def test_floor_rows_appear_only_with_weight_floor_and_contacts(body, camera):
    rng = np.random.default_rng(0)
    q = random_poses(body, 2, rng)
    targets = targets_for(body, q, camera, rng)
    base = KinematicFitter(body, camera, FitSettings(), 30.0)
    with_floor = KinematicFitter(body, camera, FitSettings(weight_floor=10.0), 30.0)
    r0, _ = base.frame_terms(q, *base.evaluate(q), targets)
    r1, _ = with_floor.frame_terms(q, *with_floor.evaluate(q), targets)
    assert r1.shape[1] == r0.shape[1] + 4
    assert np.allclose(r1[:, :r0.shape[1]], r0)
    no_floor = FitTargets(*[getattr(targets, f) for f in ("keypoints", "weight_2d", "targets_3d", "weight_3d",
                                                          "depth")], targets.contacts, None)
    assert with_floor.frame_terms(q, *with_floor.evaluate(q), no_floor)[0].shape == r0.shape
    # The residual is sqrt(w) h of the heel and toe sites labelled in contact, and of the others where they dip
    # under the floor by less than RESTING_HEIGHT; h = n . x + d their heights.
    soles = kin.forward_kinematics(body, q).points[:, body.point_index(CONTACT_POINTS)]
    height = soles @ targets.floor[:3] + targets.floor[3]
    dipping = (height < 0) & (height > -RESTING_HEIGHT)
    expected = np.sqrt(10.0) * np.where((targets.contacts > 0) | dipping, height, 0.0)
    assert np.allclose(r1[:, -4:], expected)


def test_floor_term_pushes_unlabelled_sites_up_only_from_a_dip(body, camera):
    """A site not labelled in contact costs nothing above the floor, is pushed back up from a dip under it, and is
    left alone deeper than RESTING_HEIGHT, where it stands on lower ground."""
    rng = np.random.default_rng(4)
    q = np.repeat(body.rest_qpos[None], 3, axis=0)
    heights = kin.forward_kinematics(body, q).points[0, body.point_index(CONTACT_POINTS), 2]
    q[:, 2] -= heights.mean()
    assert np.ptp(heights) < 0.01  # the rest pose's soles are level
    q[:, 2] += [-0.03, 0.10, -0.20]  # frame 0 dips 3 cm, frame 1 floats 10 cm, frame 2 stands 20 cm lower
    targets = targets_for(body, q, camera, rng, contacts=np.zeros((3, 4)), floor=np.array([0, 0, 1.0, 0]))
    fitter = KinematicFitter(body, camera, FitSettings(weight_floor=10.0), 30.0)
    r, J = fitter.frame_terms(q, *fitter.evaluate(q), targets)
    assert np.allclose(r[0, -4:], -np.sqrt(10.0) * 0.03, atol=np.sqrt(10.0) * 0.005)
    # raising the root raises every site: the rows' Jacobian along the root's height is sqrt(w)
    assert np.allclose(J[0, -4:, 2], np.sqrt(10.0))
    assert np.all(r[1:, -4:] == 0.0) and np.all(J[1:, -4:] == 0.0)


@pytest.mark.parametrize("labelled", [True, False])
def test_frame_terms_with_floor_jacobian_matches_finite_differences(body, camera, labelled):
    rng = np.random.default_rng(1)
    q = random_poses(body, 3, rng, scale=0.5)
    q[:, 2] -= 0.05  # some sites under the floor, where the one-sided rows of unlabelled sites act
    fitter = KinematicFitter(body, camera, ALL_TERMS, 30.0)
    targets = targets_for(body, q, camera, rng, contacts=np.full((3, 4), float(labelled)))
    assert_frame_terms_jacobian(fitter, q, targets)


def test_velocity_and_angle_signal_jacobians_match_finite_differences(body, camera):
    rng = np.random.default_rng(2)
    q = random_poses(body, 3, rng, scale=0.6)
    fitter = KinematicFitter(body, camera, ALL_TERMS, 25.0)
    signals = fitter.temporal_signals(*fitter.evaluate(q), q)
    assert len(signals) == 4  # acceleration, depth, joint velocity, angle velocity
    eps = 1e-6
    for k in range(body.nv):
        step = np.zeros((3, body.nv))
        step[:, k] = eps
        qp, qm = fitter.integrate(q, step), fitter.integrate(q, -step)
        plus = fitter.temporal_signals(*fitter.evaluate(qp), qp)
        minus = fitter.temporal_signals(*fitter.evaluate(qm), qm)
        for (_, J, _, _), (vp, _, _, _), (vm, _, _, _) in zip(signals, plus, minus, strict=True):
            assert np.allclose((vp - vm) / (2 * eps), J[..., k], atol=1e-6), k


def test_angle_speed_huber_weighs_only_the_fast_joints(body, camera):
    """Above angle_speed_huber a joint's angle-velocity residual is scaled by sqrt(huber / speed) (Huber's linear
    pull), below it by 1; by default only where the body runs (its stances labelled), on every frame with
    angle_speed_huber_frames "all"; an online fitter keeps the plain quadratic term."""
    q = np.repeat(body.rest_qpos[None], 3, axis=0)
    tab = kin.tables(body)
    hinge = tab.qadr[tab.hinge_bodies][0]
    q[1, hinge], q[2, hinge] = 0.05, 0.45  # 1.5 then 12 rad/s at 30 fps
    column = 3 * len(tab.ball_bodies)

    def angle_weights(q, contacts=None, **fields):
        fitter = KinematicFitter(body, camera, FitSettings(weight_angle_velocity=0.1, angle_speed_huber=3.0, **fields),
                                 30.0)
        return fitter.temporal_signals(*fitter.evaluate(q), q, fitter.huber_frames(q, contacts))[-1][3]

    on_feet = np.ones((len(q), 4))
    for weights in (angle_weights(q, angle_speed_huber_frames="all"), angle_weights(running_root(q, 4.0), on_feet)):
        assert weights[0, column] == 1.0 and np.isclose(weights[1, column], np.sqrt(3.0 / 12.0))
        assert np.all(np.delete(weights, column, axis=1) == 1.0)  # the other joints stand still
    assert angle_weights(q, on_feet) is None  # standing: the quadratic pull
    assert angle_weights(running_root(q, 1.4), on_feet) is None  # walking pace
    assert angle_weights(running_root(q, 4.0)) is None  # no stance labelled: not known to run
    causal = KinematicFitter(body, camera, FitSettings(weight_angle_velocity=0.1, angle_speed_huber_frames="all"),
                             30.0, causal=True)
    assert causal.temporal_signals(*causal.evaluate(q), q)[-1][3] is None


def running_root(q: np.ndarray, speed: float, fps: float = 30.0) -> np.ndarray:
    """q (T, nq) with its root carried along x at `speed` m/s."""
    moved = q.copy()
    moved[:, 0] += speed * np.arange(len(q)) / fps
    return moved


def test_running_frames_are_those_faster_than_the_walk_run_transition():
    """A leg of 0.9 m changes gait at sqrt(0.5 g 0.9) = 2.1 m/s: a run at 3 m/s (a stance every 0.35 s) that slows
    to a walk is running on its first part only, at any frame rate; a detector's drift in place is not running, nor
    is a fast path without a stance in each step (a body carried, or extrapolated where it is not seen)."""
    for fps in (10.0, 30.0, 60.0):
        t = np.arange(int(4 * fps)) / fps
        speed = np.where(t < 2.0, 3.0, 1.4)
        root = np.stack([np.concatenate([[0.0], np.cumsum(speed[1:]) / fps]), np.zeros_like(t)], axis=1)
        stances = (t % 0.35) < 0.1
        running = running_frames(root, stances, fps, 0.9)
        assert running[t < 1.6].all() and not running[t > 2.4].any(), fps
        unsupported = stances & ((t < 0.8) | (t > 1.6))  # 0.8 s in the air
        assert not running_frames(root, unsupported, fps, 0.9)[(t > 1.15) & (t < 1.25)].any(), fps
        cut = t < 1.0 + 0.3  # the clip ends in a flight: the next stance is not seen
        assert running_frames(root[cut], stances[cut], fps, 0.9).all(), fps
    rng = np.random.default_rng(0)
    drift = np.cumsum(rng.normal(0.0, 0.02, (120, 2)), axis=0)  # 2 cm a frame at random
    assert not running_frames(drift, np.ones(120, bool), 30.0, 0.9).any()


def test_angle_signal_is_the_joint_angles(body, camera):
    rng = np.random.default_rng(3)
    q = random_poses(body, 2, rng)
    fitter = KinematicFitter(body, camera, FitSettings(weight_angle_velocity=1.0), 30.0)
    values = fitter.temporal_signals(*fitter.evaluate(q), q)[-1][0]
    tab = kin.tables(body)
    expected = np.concatenate([kin.ball_rotation_vectors(body, q).reshape(2, -1), q[:, tab.qadr[tab.hinge_bodies]]],
                              axis=1)
    assert np.allclose(values, expected)


def test_contact_velocity_jacobian_and_pair_weights(body, camera):
    rng = np.random.default_rng(4)
    q = random_poses(body, 4, rng)
    contacts = np.array([[1, 1, 0, 0], [1, 0, 0, 1], [1, 1, 0, 1], [0, 1, 1, 1]], float)
    targets = targets_for(body, q, camera, rng, contacts=contacts)
    fitter = KinematicFitter(body, camera, ALL_TERMS, 30.0)
    ((values, J, coeffs, pair),) = fitter.contact_signals(*fitter.evaluate(q), targets)
    assert np.array_equal(coeffs, [-1.0, 1.0])
    # A pair counts when the site is in contact in both frames.
    assert np.array_equal(pair[:, ::3], [[1, 0, 0, 0], [1, 0, 0, 1], [0, 1, 0, 1]])
    eps = 1e-6
    for k in range(body.nv):
        step = np.zeros((4, body.nv))
        step[:, k] = eps
        qp, qm = fitter.integrate(q, step), fitter.integrate(q, -step)
        ((vp, _, _, _),) = fitter.contact_signals(*fitter.evaluate(qp), targets)
        ((vm, _, _, _),) = fitter.contact_signals(*fitter.evaluate(qm), targets)
        assert np.allclose((vp - vm) / (2 * eps), J[..., k], atol=1e-6), k
    unlabelled = FitTargets(targets.keypoints, targets.weight_2d, targets.targets_3d, targets.weight_3d,
                            targets.depth)
    assert fitter.contact_signals(*fitter.evaluate(q), unlabelled) == []
    off = KinematicFitter(body, camera, FitSettings(), 30.0)
    assert off.contact_signals(*off.evaluate(q), targets) == []


def test_offline_gradient_matches_the_cost_with_all_terms(body, camera):
    """The assembled gradient (with the per-pair contact weights) is half the cost's derivative."""
    rng = np.random.default_rng(5)
    T = 5
    q = random_poses(body, T, rng, scale=0.3)
    targets = targets_for(body, q, camera, rng)
    fitter = KinematicFitter(body, camera, ALL_TERMS, 30.0)
    cost, g, H = fitter._offline_system(q, targets)
    eps = 1e-6
    for _ in range(6):
        direction = rng.normal(size=(T, body.nv))
        cp = fitter._offline_system(fitter.integrate(q, eps * direction), targets)[0]
        cm = fitter._offline_system(fitter.integrate(q, -eps * direction), targets)[0]
        assert np.isclose((cp - cm) / (2 * eps), 2 * np.sum(g * direction), rtol=1e-5, atol=1e-7)
    # The Gauss-Newton matrix is positive semi-definite in every diagonal block.
    assert np.all(np.linalg.eigvalsh(H[0]) > -1e-9)


def test_contact_terms_plant_the_feet_on_the_floor(body, camera):
    """Feet labelled in contact that jitter and hover in the data end up still and on the given floor."""
    rng = np.random.default_rng(6)
    T = 20
    truth = np.repeat(body.rest_qpos[None], T, axis=0)
    noisy = kin.integrate(body, truth, rng.normal(scale=0.02, size=(T, body.nv)))
    noisy[:, 2] += 0.04  # hovering 4 cm
    targets = targets_for(body, noisy, camera, rng, contacts=np.ones((T, 4)), floor=np.array([0, 0, 1.0, 0]))
    soles = body.point_index(CONTACT_POINTS)
    results = {}
    for name, settings in (("plain", FitSettings(robust_2d=0, robust_3d=0)), ("contact", ALL_TERMS)):
        fitted = KinematicFitter(body, camera, settings, 30.0).fit_offline(noisy, targets).qpos
        feet = kin.forward_kinematics(body, fitted).points[:, soles]
        results[name] = (np.abs(feet[..., 2]).mean(), np.linalg.norm(np.diff(feet, axis=0), axis=-1).mean())
    assert results["contact"][0] < 0.3 * results["plain"][0]
    assert results["contact"][1] < 0.5 * results["plain"][1]


def test_floor_term_lifts_a_swinging_foot_out_of_the_floor(body, camera):
    """Data that put a foot not labelled in contact 4 cm under the floor: the fit with the floor term brings it up
    to the floor, as the physics that tracks this motion must; without the term it stays under."""
    rng = np.random.default_rng(7)
    T = 12
    pose = body.rest_qpos.copy()
    soles = body.point_index(CONTACT_POINTS)
    pose[2] -= kin.forward_kinematics(body, pose).points[0, soles, 2].max() + 0.04  # every sole 4 cm or more under
    truth = np.repeat(pose[None], T, axis=0)
    contacts = np.zeros((T, 4))
    targets = targets_for(body, truth, camera, rng, contacts=contacts, floor=np.array([0, 0, 1.0, 0]))
    lowest = {}
    for name, weight in (("without", 0.0), ("with", 10.0)):
        settings = FitSettings(robust_2d=0, robust_3d=0, weight_floor=weight)
        fitted = KinematicFitter(body, camera, settings, 30.0).fit_offline(truth, targets).qpos
        lowest[name] = kin.forward_kinematics(body, fitted).points[:, soles, 2].min()
    assert lowest["without"] < -0.03
    assert lowest["with"] > -0.01
