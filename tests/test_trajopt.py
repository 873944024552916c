"""Rempe et al. trajectory optimisation (physmocap.trajopt): the pieces against independent computations, and
the solutions against physics (Newton at every frame, forces in the pyramid, still feet, ballistic flight)."""

import dataclasses
import itertools
import logging
import signal
import subprocess
import sys

import casadi as ca
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from conftest import DEMO_VIDEO
from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.body.support import STEP_HEIGHT, unexplained_frames
from physmocap.config import TrajoptSettings
from physmocap.contacts.flights import CONTACT_MAX_SPEED, flight_speeds, flight_support, support_held_flights
from physmocap.errors import InputError
from physmocap.trajopt import stage
from physmocap.trajopt.formulation import (
    Window,
    acceleration_continuity,
    angular_velocity,
    build_window_problem,
    clock_times,
    euler_torque,
    frame_sample_times,
    newton_sample_times,
    phase_layout,
    rotate,
)
from physmocap.trajopt.phases import (
    clean_flags,
    contact_phases,
    flags_from_phases,
    segment_count,
    split_drifting,
)
from physmocap.trajopt.problem import (
    STALL_ITERATIONS,
    STALLED_STATUS,
    ConstraintSet,
    CostTerm,
    IterationWatch,
    Program,
    VariableSet,
)
from physmocap.trajopt.reduced import boundary_velocity, euler_to_matrix, matrix_to_euler, reduced_motion, world_inertia
from physmocap.trajopt.splines import Node, Segment, Trajectory, hermite_weights
from physmocap.trajopt.stage import run_trajopt, window_ranges

FPS = 30.0
G = 9.81
QUICK = TrajoptSettings()  # the defaults: no duration stage


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.75), 72.0)


def standing(body, frames):
    q = np.repeat(body.rest_qpos[None], frames, axis=0)
    for side, sign in (("left", 1.0), ("right", -1.0)):  # arms down, as people stand
        a = body.qpos_address[body.joint_index[f"{side}_shoulder"]]
        q[:, a:a + 4] = [np.cos(sign * 0.7), np.sin(sign * 0.7), 0.0, 0.0]
    return q


def jump(body, frames=45, takeoff=15, flight=0.4):
    """Stand, dip 10 cm and push off, a ballistic flight of `flight` seconds from frame `takeoff` (root and feet
    on the parabola), land, dip and stand again: the root's height as a physical jump would move it."""
    from scipy.interpolate import CubicHermiteSpline

    q = standing(body, frames)
    t = np.arange(frames) / FPS
    t_off = takeoff / FPS
    t_land = t_off + flight
    v0 = G * flight / 2
    height = np.zeros(frames)
    push = CubicHermiteSpline([t_off - 0.45, t_off - 0.25, t_off], [0.0, -0.1, 0.0], [0.0, 0.0, v0])
    catch = CubicHermiteSpline([t_land, t_land + 0.2, t_land + 0.45], [0.0, -0.1, 0.0], [-v0, 0.0, 0.0])
    for lo, hi, f in ((t_off - 0.45, t_off, push), (t_land, t_land + 0.45, catch)):
        sel = (t >= lo) & (t <= hi)
        height[sel] = f(t[sel])
    in_air = (t > t_off) & (t < t_land)
    height[in_air] = v0 * (t[in_air] - t_off) - 0.5 * G * (t[in_air] - t_off) ** 2
    q[:, 2] += height
    return q, in_air


# ---- pieces -----------------------------------------------------------------------------------------------
def test_hermite_weights_are_consistent_derivatives():
    h = 0.7
    for s in np.linspace(0.05, 0.95, 7):
        eps = 1e-6
        for order in (0, 1):
            lo, hi = hermite_weights(s - eps, h, order), hermite_weights(s + eps, h, order)
            d = hermite_weights(s, h, order + 1)
            assert np.allclose((np.array(hi) - np.array(lo)) / (2 * eps * h), d, atol=1e-5)
    # Interpolation at the ends: value and velocity of each node.
    assert np.allclose(hermite_weights(0.0, h, 0), [1, 0, 0, 0])
    assert np.allclose(hermite_weights(1.0, h, 0), [0, 0, 1, 0])
    assert np.allclose(hermite_weights(0.0, h, 1), [0, 1, 0, 0])
    assert np.allclose(hermite_weights(1.0, h, 1), [0, 0, 0, 1])


def test_sampling_matrix_matches_the_expression_and_is_continuous():
    rng = np.random.default_rng(0)
    times = np.array([0.0, 0.3, 0.5, 1.1])
    x = ca.SX.sym("x", 6 * len(times))
    nodes = [Node.at(6 * k, 6 * k + 3) for k in range(len(times))]
    traj = Trajectory([Segment(float(times[k]), float(times[k + 1]), nodes[k], nodes[k + 1],
                               (times[k], times[k + 1])) for k in range(len(times) - 1)])
    values = rng.normal(size=x.shape[0])
    samples = np.linspace(0, 1.1, 23)
    for order in (0, 1, 2):
        by_matrix = traj.matrix(samples, order, x.shape[0]) @ values
        by_graph = np.asarray(ca.Function("f", [x], [traj.sample(x, samples, order)])(values)).T.ravel()
        assert np.allclose(by_matrix, by_graph)
    # Value and velocity continuous across the inner nodes; nodes reproduce their values.
    f = ca.Function("f", [x], [traj.sample(x, np.array([0.3 - 1e-9, 0.3 + 1e-9, 0.5]), 0),
                               traj.sample(x, np.array([0.3 - 1e-9, 0.3 + 1e-9]), 1)])
    value, velocity = (np.asarray(v) for v in f(values))
    assert np.allclose(value[:, 0], value[:, 1], atol=1e-6) and np.allclose(velocity[:, 0], velocity[:, 1], atol=1e-6)
    assert np.allclose(value[:, 2], values[12:15])


def test_knot_jumps_measure_the_acceleration_jump():
    times = np.array([0.0, 0.1, 0.25, 0.4])
    x = ca.SX.sym("x", 6 * len(times))
    nodes = [Node.at(6 * k, 6 * k + 3) for k in range(len(times))]
    traj = Trajectory([Segment(float(times[k]), float(times[k + 1]), nodes[k], nodes[k + 1],
                               (times[k], times[k + 1])) for k in range(len(times) - 1)])
    values = np.random.default_rng(3).normal(size=x.shape[0])
    jumps = traj.knot_jumps(2, x.shape[0]) @ values
    for j, t in enumerate(times[1:-1]):
        left = traj.matrix(np.array([t - 1e-7]), 2, x.shape[0]) @ values
        right = traj.matrix(np.array([t]), 2, x.shape[0]) @ values
        assert np.allclose(jumps[3 * j:3 * j + 3], left - right, atol=1e-4)


def test_moving_segment_ends_choose_the_right_polynomial():
    """With a boundary time as a variable, a sample on either side of it is evaluated by its own polynomial."""
    x = ca.SX.sym("x", 13)  # nodes 0..1 (6 each), boundary time x[12]
    a, b, c = Node.at(0, 3), Node.at(6, 9), Node.zero()
    traj = Trajectory([Segment(0.0, x[12], a, b, (0.0, 0.5), (0.0, 0.2)),
                       Segment(x[12], 1.0, b, c, (0.5, 1.0), (0.2, 0.0))])
    values = np.concatenate([np.arange(12.0) / 10, [0.6]])
    out = np.asarray(ca.Function("f", [x], [traj.sample(x, np.array([0.55, 0.65]), 0)])(values))
    fixed = Trajectory([Segment(0.0, 0.6, a, b, (0.0, 0.6)), Segment(0.6, 1.0, b, c, (0.6, 1.0))])
    expected = fixed.matrix(np.array([0.55, 0.65]), 0, 13) @ values
    assert np.allclose(out.T.ravel(), expected)


def test_contact_phases_from_flags():
    flags = np.array([1, 1, 1, 0, 1, 0, 0, 0, 1, 1], bool)
    cleaned = clean_flags(flags, 2)
    assert np.array_equal(cleaned, [1, 1, 1, 1, 1, 0, 0, 0, 1, 1])  # the lone frames merge
    times = np.arange(10) / FPS
    phases = contact_phases(cleaned, times)
    assert [p.contact for p in phases] == [True, False, True]
    assert phases[0].start == 0.0 and phases[-1].end == times[-1]
    assert np.isclose(phases[1].start, 4.5 / FPS) and np.isclose(phases[1].end, 7.5 / FPS)
    assert np.array_equal(flags_from_phases(phases, times), cleaned)
    assert segment_count(0.3, 6, 2.0) == 6 and segment_count(5.0, 6, 2.0) == 15
    # No polynomial shorter than a frame (nothing reads it between frames), unless the longest allowed is shorter.
    assert segment_count(0.07, 6, 2.0, shortest=1 / 30) == 2 and segment_count(0.02, 6, 2.0, shortest=1 / 30) == 1
    assert segment_count(0.3, 6, 2.0, longest=0.02, shortest=1 / 30) == 15


def test_flight_the_motion_does_not_fall_through_keeps_a_support():
    """Labels that lift every point for 7 frames while the body stands (the juggler on one foot, issue 24) keep a
    support there: of the points in contact beside the flight, the one nearest below the COM; so does such a
    flight running to the clip's end (mmhuman3d's last 5 frames). Ballistic flights stay flights."""
    fps, frames = 24.0, 48
    times = np.arange(frames) / fps
    points = np.zeros((frames, 4, 3))
    points[:, :, 0] = [-0.05, 0.1, -0.05, 0.1]  # heels behind the COM, toes farther ahead
    points[:, :, 1] = [0.3, 0.3, -0.05, -0.05]  # the right foot below the COM, the left to the side
    points[:, :2, 2] = 0.3  # the left foot raised
    flags = np.zeros((frames, 4), bool)
    flags[:, 2:] = True
    flags[:20, 3] = False  # before the flight only the right heel; after it both right points
    flags[20:27] = False
    flags[27:29, 2] = False  # the right heel resumes two frames after the flight: its contact bridges them
    com = np.zeros((frames, 3))
    com[:, 2] = 0.95 + 0.002 * np.sin(times)
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5)
    assert unsupported == [] and [(a, b, p) for a, b, p, _ in changed] == [(20, 29, 2)] and changed[0][3] > 0.9
    assert out[:, 2].all() and not out[20:27, [0, 1, 3]].any() and np.array_equal(out[:20], flags[:20])
    edge = flags.copy()
    edge[27:] = False  # a flight to the clip's end: its take-off is in the clip, its own frames do not fall
    out, changed, _ = support_held_flights(edge, com, points, times, G, 0.5)
    assert [(a, b, p) for a, b, p, _ in changed] == [(20, 48, 2)] and out[20:, 2].all()
    tau = np.clip(times - 19 / fps, 0.0, 8 / fps)  # take-off at frame 19, landing at frame 27
    com[:, 2] = 0.95 + 0.5 * G * (8 / fps) * tau - 0.5 * G * tau ** 2
    assert abs(flight_support(com[:, 2], times, 20, 27, G)) < 1e-6
    assert support_held_flights(flags, com, points, times, G, 0.5)[1] == []
    com[:, 2] = 0.95 + 0.5 * G * (8 / fps) * (times - 19 / fps) - 0.5 * G * (times - 19 / fps) ** 2
    assert support_held_flights(edge, com, points, times, G, 0.5)[1] == []  # falling to the clip's end


def test_flight_support_is_a_point_that_stays_put():
    """A point that travels along the floor through the flight, or climbs off it, is no support: the next candidate
    holds the body up, and with none left the flight is returned as unexplained, its flags unchanged."""
    fps, frames = 24.0, 48
    times = np.arange(frames) / fps
    points = np.zeros((frames, 4, 3))
    points[:, :, 0] = [-0.05, 0.1, -0.05, 0.1]
    points[:, :, 1] = [0.3, 0.3, -0.05, -0.05]
    flags = np.zeros((frames, 4), bool)
    flags[:20, 2] = flags[27:, 2:] = True
    com = np.zeros((frames, 3))
    com[:, 2] = 0.95
    points[20:27, 2, 0] += np.linspace(0.0, 0.2, 7)  # the right heel, nearest the COM, slides 20 cm
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.05)
    assert unsupported == [] and [(a, b, p) for a, b, p, _ in changed] == [(20, 27, 3)] and out[20:27, 3].all()
    points[20:27, 3, 1] += np.linspace(0.0, 0.2, 7)  # and the right toe
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.05)
    assert changed == [] and [(a, b) for a, b, _ in unsupported] == [(20, 27)] and np.array_equal(out, flags)
    # Nor is a point that climbs off the floor (a toe on a ladder's rungs) more than a step's height.
    points[20:27, 2:, :2] = points[19, 2:, :2]
    points[20:27, 2, 2] = np.linspace(0.0, STEP_HEIGHT + 0.1, 7)
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.05)
    assert unsupported == [] and [(a, b, p) for a, b, p, _ in changed] == [(20, 27, 3)]
    points[20:27, 3, 2] = points[20:27, 2, 2]
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.05)
    assert changed == [] and [(a, b) for a, b, _ in unsupported] == [(20, 27)]


def test_flight_support_is_no_faster_than_a_contact():
    """A run's short flight: the toe that pushed off swings on at 1.8 m/s, within its foot's length over four frames
    at 30 fps, so drift alone would hold the body on it. Faster than a contact may move, it holds nothing up: the
    flight is unexplained. A toe that creeps at half a metre a second still holds the same flight up."""
    fps, frames = 30.0, 40
    times = np.arange(frames) / fps
    points = np.zeros((frames, 4, 3))
    points[:, :, 0] = [-0.05, 0.15, -0.05, 0.15]
    points[:, :, 1] = [0.4, 0.4, -0.1, -0.1]
    points[:24, :2, 0] -= 0.06 * (24 - np.arange(24))[:, None]  # the left foot swings in to land on frame 24
    flags = np.zeros((frames, 4), bool)
    flags[:20, 3] = flags[24:, :2] = True  # the right toe pushes off, the left foot lands four frames later
    com = np.zeros((frames, 3))
    com[:, 2] = 0.95  # the input's centre of mass does not fall
    points[20:, 3, 0] += np.minimum(0.06 * np.arange(1, frames - 19), 0.3)  # 6 cm a frame
    assert flight_speeds(points, times, 20, 24)[3] == pytest.approx(1.8)
    assert not flight_speeds(points, times, 20, 22).any()  # two frames: one step, no speed told from noise
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.21)
    assert [(a, b, p) for a, b, p, _ in changed] == [(20, 24, 3)] and unsupported == []
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.21,
                                                     max_speed=CONTACT_MAX_SPEED)
    assert changed == [] and [(a, b) for a, b, _ in unsupported] == [(20, 24)] and np.array_equal(out, flags)
    points[20:, 3, 0] = 0.15 + np.minimum(0.5 / fps * np.arange(1, frames - 19), 0.3)
    out, changed, unsupported = support_held_flights(flags, com, points, times, G, 0.5, drift=0.21,
                                                     max_speed=CONTACT_MAX_SPEED)
    assert [(a, b, p) for a, b, p, _ in changed] == [(20, 24, 3)] and unsupported == []


@pytest.mark.slow
def test_false_flight_is_not_landed_with_a_force_peak(body, caplog):
    """Standing still, the labels say every point flies for 7 frames at 24 fps: physics must not launch and land
    the body (the flight would need about 2.5 body weights at its ends); the lowest point stays in contact."""
    fps, frames = 24.0, 48
    q = standing(body, frames)
    flags = np.ones((frames, 4), bool)
    flags[20:27] = False
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        result = run_trajopt(body, q, fps, flags, TrajoptSettings(contact_drift=0.0))
    assert result.converged.all() and "the labels give a flight" in caplog.text
    assert result.contacts[20:27].any(axis=1).all()
    vertical = result.grf[..., 2].sum(axis=1)
    assert vertical.max() < 1.2 * body.mass * G


def test_drifting_contact_split_where_the_point_moves_with_a_support_kept():
    T = 40
    flags = np.zeros((T, 4), bool)
    flags[:, 0] = True  # the heel holds still throughout
    flags[:, 1] = True  # the toe stays, shuffles 8 cm at frames 24-25, stays again
    points = np.zeros((T, 4, 2))
    points[24:, 1, 0] = np.r_[0.03, 0.06, np.full(T - 26, 0.08)]
    out = split_drifting(flags, points, 0.03, 2)
    assert np.array_equal(out[:, 0], flags[:, 0])
    assert np.array_equal(np.flatnonzero(~out[:, 1]), [24, 25])  # the gap covers the move exactly
    # Alone on the floor the toe keeps its run: a gap would leave the body without support.
    alone = flags.copy()
    alone[:, 0] = False
    assert np.array_equal(split_drifting(alone, points, 0.03, 2), alone)
    # A support whose own contact begins at the best gap carries no force there (it fades in from zero): the gap
    # goes where the heel holds from the frame before to the frame after.
    late = flags.copy()
    late[:24, 0] = False
    out = split_drifting(late, points, 0.03, 2)
    gap = np.flatnonzero(~out[:, 1])
    assert len(gap) == 2 and gap[0] >= 25 and out[gap[0] - 1:gap[-1] + 2, 0].all()
    # Within the limit, or the split off: unchanged; a steady slide is cut until every part is within the limit.
    assert np.array_equal(split_drifting(flags, points, 0.1, 2), flags)
    assert np.array_equal(split_drifting(flags, points, 0.0, 2), flags)
    points[:, 1, 0] = np.linspace(0.0, 0.3, T)
    out = split_drifting(flags, points, 0.03, 2)
    starts = np.flatnonzero(np.diff(np.r_[0, out[:, 1].astype(int)]) == 1)
    ends = np.flatnonzero(np.diff(np.r_[out[:, 1].astype(int), 0]) == -1) + 1
    assert len(starts) > 2 and all(b - a >= 2 for a, b in zip(starts, ends, strict=True))
    for a, b in zip(starts, ends, strict=True):
        part = points[a:b, 1]
        assert np.linalg.norm(part - np.median(part, axis=0), axis=1).max() <= 0.03


def test_phase_layout_keeps_nodes_clear_of_moving_boundaries():
    nodes = phase_layout(1.0, 1.6, 6, 0.1, 0.05)
    assert np.isclose(nodes[0], 1.0) and np.isclose(nodes[-1], 1.6) and np.all(np.diff(nodes) > 0)
    assert nodes[1] - nodes[0] >= 0.15 - 1e-12 and nodes[-1] - nodes[-2] >= 0.1 - 1e-12
    assert np.allclose(phase_layout(0.0, 0.6, 6, 0.0, 0.0), np.linspace(0, 0.6, 7))


def test_euler_angles_round_trip_and_unwrap():
    yaw = np.linspace(0, 4 * np.pi, 50)  # two full turns
    euler = np.stack([yaw, 0.2 * np.sin(yaw), 0.1 * np.cos(yaw)], axis=1)
    back = matrix_to_euler(euler_to_matrix(euler))
    assert np.allclose(back - back[0] + euler[0], euler, atol=1e-9)
    R = Rotation.from_euler("ZYX", euler[7]).as_matrix()
    v = np.array([0.3, -0.2, 0.9])
    assert np.allclose(np.asarray(rotate(ca.DM(euler[7]), ca.DM(v))).ravel(), R @ v)
    assert np.allclose(np.asarray(rotate(ca.DM(euler[7]), ca.DM(v), inverse=True)).ravel(), R.T @ v)


def test_angular_velocity_and_euler_torque_against_finite_differences():
    def theta(t):
        return np.array([0.3 + 1.1 * t + 0.4 * np.sin(2 * t), 0.2 * np.cos(3 * t), -0.5 + 0.7 * np.sin(1.3 * t)])

    def rates(t, h=1e-5):
        return (theta(t + h) - theta(t - h)) / (2 * h), (theta(t + h) - 2 * theta(t) + theta(t - h)) / h**2

    def R(t):
        return euler_to_matrix(theta(t)[None])[0]

    t, h = 0.37, 1e-5
    de, dde = rates(t)
    W = (R(t + h) - R(t - h)) / (2 * h) @ R(t).T
    w, _ = angular_velocity(ca.DM(theta(t)), ca.DM(de), ca.DM(dde))
    assert np.allclose(np.asarray(w).ravel(), [W[2, 1], W[0, 2], W[1, 0]], atol=1e-6)
    inertia = np.array([[2.0, 0.1, 0.2], [0.1, 3.0, -0.3], [0.2, -0.3, 1.5]])

    def momentum(t):
        d, _ = rates(t)
        omega = np.asarray(angular_velocity(ca.DM(theta(t)), ca.DM(d), ca.DM(d))[0]).ravel()
        return R(t) @ inertia @ R(t).T @ omega

    dL = (momentum(t + 1e-4) - momentum(t - 1e-4)) / 2e-4
    torque = np.asarray(euler_torque(ca.DM(theta(t)), ca.DM(de), ca.DM(dde), inertia[None])).ravel()
    assert np.allclose(torque, dL, atol=1e-4)


def test_reduced_model_com_and_inertia_match_mujoco(body):
    rng = np.random.default_rng(1)
    q = kin.integrate(body, np.repeat(body.rest_qpos[None], 3, axis=0), rng.normal(scale=0.4, size=(3, body.nv)))
    red = reduced_motion(body, q, FPS)
    m = body.mujoco_model()
    d = mujoco.MjData(m)
    for t in range(3):
        d.qpos[:] = q[t]
        mujoco.mj_forward(m, d)
        assert np.allclose(red.com[t], d.subtree_com[1], atol=1e-9)
        inertia = np.zeros((3, 3))
        for b in range(1, m.nbody):
            Rb = d.ximat[b].reshape(3, 3)
            r = d.xipos[b] - d.subtree_com[1]
            inertia += Rb @ np.diag(m.body_inertia[b]) @ Rb.T + m.body_mass[b] * (r @ r * np.eye(3) - np.outer(r, r))
        root = d.xmat[1].reshape(3, 3)
        assert np.allclose(red.inertia[t], root.T @ inertia @ root, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(red.inertia) > 0)
    # Hips relative to the COM in the root frame, feet at the contact sites.
    pts = kin.forward_kinematics(body, q).points
    hip = pts[:, body.point_index(["left_hip"])[0]]
    assert np.allclose(red.rotation[0] @ red.hips[0, 0] + red.com[0], hip[0])
    assert np.allclose(red.feet, pts[:, body.point_index(CONTACT_POINTS)])
    assert np.allclose(world_inertia(body, kin.forward_kinematics(body, q), red.com)[0],
                       red.rotation[0] @ red.inertia[0] @ red.rotation[0].T)


def swinging(body, frames=40, rigid=False):
    """A motion whose root turns and moves; its arm and leg swing too unless `rigid`."""
    t = np.arange(frames) / FPS
    rates = np.zeros((frames, body.nv))
    rates[:, 0:3] = [0.4, 0.1, 0.2]
    rates[:, 3:6] = np.stack([0.3 * np.cos(2 * t), 0.5 * np.sin(3 * t), 0.8 + 0 * t], axis=1)
    if not rigid:
        for joint in ("left_shoulder", "right_hip"):
            a = body.dof_address[body.joint_index[joint]]
            rates[:, a + 1] = 4.0 * np.cos(5 * t)
    q = [body.rest_qpos]
    for k in range(frames - 1):
        q.append(kin.integrate(body, q[-1][None], rates[k][None] / FPS)[0])
    return np.array(q)


def test_internal_torque_is_the_limbs_share_of_the_angular_momentum_rate(body):
    """dL/dt of the whole body about its COM (MuJoCo's subtree angular momentum) = the reduced model's rigid
    torque (from its inertia and root rotation) + internal_torque; zero for a body that turns rigidly."""
    rigid = reduced_motion(body, swinging(body, rigid=True), FPS)
    assert np.abs(rigid.internal_torque[2:-2]).max() < 1e-3 * body.mass
    q = swinging(body)
    red = reduced_motion(body, q, FPS)
    m = body.mujoco_model()
    d = mujoco.MjData(m)
    momentum = []
    for k in range(len(q)):
        lo, hi = max(k - 1, 0), min(k + 1, len(q) - 1)
        d.qpos[:] = q[k]
        d.qvel[:] = kin.difference(body, q[lo][None], q[hi][None])[0] * FPS / (hi - lo)
        mujoco.mj_forward(m, d)
        mujoco.mj_subtreeVel(m, d)
        momentum.append(d.subtree_angmom[1].copy())
    total = np.gradient(np.array(momentum), axis=0) * FPS
    R = red.rotation
    w = 0.5 * np.stack([(dR @ r.T)[[2, 0, 1], [1, 2, 0]] - (dR @ r.T)[[1, 2, 0], [2, 0, 1]]
                        for dR, r in zip(np.gradient(R, axis=0) * FPS, R, strict=True)])
    inertia = R @ red.inertia @ R.transpose(0, 2, 1)
    rigid_part = np.einsum("tij,tj->ti", inertia, np.gradient(w, axis=0) * FPS) + np.cross(
        w, np.einsum("tij,tj->ti", inertia, w))
    inner = slice(3, -3)
    expected = (total - rigid_part)[inner]
    assert np.abs(expected).max() > 5.0  # N m: the swinging limbs matter
    assert np.allclose(red.internal_torque[inner], expected, atol=0.05 * np.abs(expected).max())


def test_center_of_mass_from_points_matches_the_models_own(body):
    rng = np.random.default_rng(3)
    q = kin.integrate(body, np.repeat(body.rest_qpos[None], 5, axis=0), rng.normal(scale=0.4, size=(5, body.nv)))
    pose = kin.forward_kinematics(body, q)
    com = kin.center_of_mass_from_points(body, pose.points, body.point_names)
    assert np.abs(com - kin.center_of_mass(body, pose)).max() < 0.003
    shuffled = list(reversed(body.point_names))
    assert np.allclose(kin.center_of_mass_from_points(body, pose.points[:, ::-1], shuffled), com)


def test_boundary_velocity_is_the_mean_over_the_first_sixth_of_a_second_at_any_frame_rate():
    com = np.stack([np.arange(20) * 0.04, np.zeros(20), np.ones(20)], axis=1)
    com[0, 0] += 0.01  # a noisy first frame
    assert np.allclose(boundary_velocity(com, FPS, 5 / FPS, end=True), [1.2, 0, 0])
    assert np.allclose(boundary_velocity(com, FPS, 5 / FPS, end=False), [(0.2 - 0.01) * FPS / 5, 0, 0])
    seconds = TrajoptSettings().boundary_seconds
    for fps in (10.0, 12.0, 24.0, 30.0, 60.0):
        frames = round(seconds * fps)  # 2, 2, 4, 5, 10
        mean = (0.04 * frames - 0.01) * fps / frames
        assert np.allclose(boundary_velocity(com, fps, seconds, end=False), [mean, 0, 0])
    assert np.allclose(boundary_velocity(com, 2.0, seconds, end=False), [(0.04 - 0.01) * 2.0, 0, 0])  # a frame at least


def test_settings_name_the_pieces():
    with pytest.raises(InputError):
        TrajoptSettings(constraints=("dynamics", "levitation")).check()
    with pytest.raises(InputError):
        TrajoptSettings(costs=("data", "beauty")).check()
    TrajoptSettings().check()


def whole_program(program: Program):
    """The program's rows and objective as one SX expression of its x each: what CasADi differentiates whole."""
    g = ca.densify(ca.vertcat(*[c.expression_in(program.x) for c in program.constraints]))
    return g, sum((c.expression(program.x) for c in program.costs), ca.SX(0))


def test_program_derivatives_equal_casadis_whole_program_ones():
    """The per-piece Jacobian and Hessian handed to IPOPT equal CasADi's of the whole program."""
    x = ca.SX.sym("x", 3)
    v = VariableSet("v", 3, -np.inf * np.ones(3), np.inf * np.ones(3), np.zeros(3), x)
    nonlinear, linear = ConstraintSet("round"), ConstraintSet("flat", linear=True)
    nonlinear.add(ca.vertcat(x[0] * x[1] - 1, ca.sin(x[2]) * x[0]), [0, -1], [0, 1])
    linear.add(x[0] + 2 * x[2], -np.inf, 3)
    cost = CostTerm("c", (x[0] - 2) ** 2 + x[1] ** 4 + x[0] * x[2])
    program = Program(x, [v], [nonlinear, linear], [cost], {})
    opts = program._derivatives()
    g, f = whole_program(program)
    lam_f, lam_g = ca.SX.sym("lf"), ca.SX.sym("lg", g.shape[0])
    expected_h = ca.Function("h", [x, lam_f, lam_g], [ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), x)[0])])
    expected_j = ca.Function("j", [x], [ca.jacobian(g, x)])
    rng = np.random.default_rng(2)
    for _ in range(3):
        xv, lf, lg = rng.normal(size=3), rng.normal(), rng.normal(size=g.shape[0])
        assert np.allclose(np.asarray(opts["hess_lag"](xv, [], lf, lg)), np.asarray(expected_h(xv, lf, lg)))
        assert np.allclose(np.asarray(opts["jac_g"](xv, [])[1]), np.asarray(expected_j(xv)))
    sol = program.solve(np.array([1.0, 1.0, 0.1]))
    assert sol.converged and abs(sol.x[0] * sol.x[1] - 1) < 1e-6



def test_an_infeasible_program_stops_once_its_violation_stalls():
    """Two equalities that contradict each other: the violation cannot fall below 1, and a watched run stops
    STALL_ITERATIONS after its last halving instead of spending its whole budget; an unwatched one goes on."""
    x = ca.SX.sym("x", 3)
    v = VariableSet("v", 3, -np.inf * np.ones(3), np.inf * np.ones(3), np.zeros(3), x)
    contradicting = ConstraintSet("contradicting")
    contradicting.add(ca.vertcat(x[0] * x[1] - 1, x[0] * x[1] + 1 + x[2] ** 2), [0, 0], [0, 0])
    program = Program(x, [v], [contradicting], [CostTerm("c", (x[0] - 2) ** 2 + x[1] ** 4)], {"max_iter": 1000})
    sol = program.solve(np.array([1.0, 1.0, 1.0]), stop_stalled=True)
    assert sol.status == STALLED_STATUS and not sol.converged
    assert STALL_ITERATIONS <= sol.iterations < 2 * STALL_ITERATIONS and sol.max_violation > 1
    unwatched = program.solve(np.array([1.0, 1.0, 1.0]), max_iterations=2 * STALL_ITERATIONS)
    assert unwatched.status != STALLED_STATUS and unwatched.iterations > sol.iterations



def test_a_first_try_whose_fit_stalls_skips_its_dynamics_and_gives_way_to_the_retry(body, monkeypatch):
    """The fit's constraints are the dynamics stage's: a window whose fit stalls goes straight to its retry."""
    q, in_air = jump(body, frames=40, takeoff=12)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    solve, runs = Program.solve, []

    def first_stalls(self, *args, **kwargs):
        sol = solve(self, *args, **kwargs)
        runs.append(kwargs.get("stop_stalled", False))
        return dataclasses.replace(sol, status=STALLED_STATUS, converged=False) if len(runs) == 1 else sol

    monkeypatch.setattr(Program, "solve", first_stalls)
    result = run_trajopt(body, q, FPS, contacts, TrajoptSettings(optimize_durations=False))
    names = [st.name for st in result.windows[0].stages]
    assert names == ["fit", "restart fit", "restart dynamics"] and runs == [True, False, False]
    assert result.converged.all() and result.windows[0].restarted

def test_the_watch_stops_only_a_violation_that_is_not_feasible_and_not_halving():
    watch = IterationWatch(1, 1, feasible=1e-4)

    def run(violations, limit=None, stop_stalled=True) -> int:
        """Iterations until the watch stops a run with these violations (of g <= 0), or 0 if it never does."""
        watch.start(limit, np.array([-np.inf]), np.array([0.0]), stop_stalled)
        for k, violation in enumerate(violations, 1):
            if watch.eval([np.zeros(1), 0.0, np.array([violation]), np.zeros(1), np.zeros(1), np.zeros(0)])[0]:
                return k
        return 0

    assert run([1e-2] * 500) == STALL_ITERATIONS + 2 and watch.stalled  # counted from the first iterate
    assert run([1e-2 * 0.4 ** (k // STALL_ITERATIONS) for k in range(1000)]) == 0  # slow, but halving
    assert run([1e-5] * 500) == 0  # feasible: improving the objective however long it takes
    assert run([1e-2] * 50, limit=20) == 21 and not watch.stalled  # the iteration limit, not a stall
    assert run([1e-2] * 500, stop_stalled=False) == 0  # a run not watched for stalls

def test_window_derivatives_from_matrices_equal_casadis_whole_program_ones(body):
    """A window's least-squares costs (from their matrices) and constraint rows written on read symbols (chain
    rule through the sampling matrices) give the gradient, Jacobian and Hessian of CasADi's differentiation of the
    whole program, the Jacobian with no extra structural entries (a force in flight reads nothing)."""
    q = sway(body, 30)
    red = reduced_motion(body, q, FPS)
    flags = np.ones(30, bool)
    flags[12:18] = False
    phases = [contact_phases(flags, red.times)] + [contact_phases(np.ones(30, bool), red.times)] * 3
    problem = build_window_problem(Window(red, phases), TrajoptSettings())
    program = Program(problem.x, problem.variable_sets, list(problem.constraints.values()),
                      list(problem.costs.values()), {})
    read = {c.name for c in program.constraints if c.inputs}
    assert read == {"dynamics", "foot_length", "leg_length"}
    assert all(c.squares is not None for c in program.costs)
    derivatives = program._derivatives()
    x, (g, f) = program.x, whole_program(program)
    lam_f, lam_g = ca.SX.sym("lf"), ca.SX.sym("lg", g.shape[0])
    jacobian = ca.jacobian(g, x)
    expected = ca.Function("e", [x, lam_f, lam_g], [ca.gradient(f, x), jacobian,
                                                     ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), x)[0])])
    assert derivatives["jac_g"].sparsity_out(1).nnz() == jacobian.nnz()
    rng = np.random.default_rng(3)
    xv, lf, lg = rng.normal(size=int(x.shape[0])), rng.normal(), rng.normal(size=int(g.shape[0]))
    grad, jac, hess = (np.asarray(ca.densify(v)) for v in expected(xv, lf, lg))
    assert np.allclose(np.asarray(derivatives["grad_f"](xv, [])[1]).ravel(), grad.ravel(), rtol=1e-9, atol=1e-9)
    assert np.allclose(np.asarray(ca.densify(derivatives["jac_g"](xv, [])[1])), jac, rtol=1e-9, atol=1e-9)
    assert np.allclose(np.asarray(ca.densify(derivatives["hess_lag"](xv, [], lf, lg))), hess, rtol=1e-9, atol=1e-9)


def test_foot_length_rows_are_independent(body):
    """Every foot-length row says something no other row says: a stance of both points is one row on their two
    places, however long, and a flight is held at its own nodes. Sampled every kinematic_interval, a stance repeated
    one equation and IPOPT's multipliers of the copies grew and cancelled (docs/decisions/trajopt-turn-window.md)."""
    q = sway(body, 45)
    red = reduced_motion(body, q, FPS)
    heel, toe, planted = np.ones(45, bool), np.ones(45, bool), np.ones(45, bool)
    heel[20:30] = False  # heel-off, then heel strike
    toe[24:28] = False
    phases = [contact_phases(f, red.times) for f in (heel, toe, planted, planted)]
    problem = build_window_problem(Window(red, phases), QUICK)
    rows = problem.constraints["foot_length"].expression_in(problem.x)
    x0 = np.concatenate([v.initial for v in problem.variable_sets])
    jacobian = np.asarray(ca.Function("J", [problem.x], [ca.jacobian(rows, problem.x)])(x0))
    # Left: two stances of both points and the flights' own nodes; right: one stance, one row.
    assert jacobian.shape[0] > 4 and np.linalg.matrix_rank(jacobian) == jacobian.shape[0]


def test_turning_and_leaning_on_planted_feet_converges_well_within_budget(body):
    """Turning 120 degrees in 1.5 s while leaning 30 degrees, labelled in contact throughout, so that the drifting
    contacts are re-placed (pivots): each stage converges (with foot-length rows that repeated each other the fit
    ran its half of the budget) and a foot planted at both points keeps its length."""
    frames = 45
    q = standing(body, frames)
    s = np.clip((np.arange(frames) / FPS - 0.2) / (frames / FPS - 0.4), 0.0, 1.0)
    turn = Rotation.from_euler("ZYX", np.stack([np.radians(120) * (3 * s**2 - 2 * s**3),
                                                np.radians(30) * np.sin(np.pi * s), np.zeros(frames)], axis=1))
    q[:, 3:7] = np.roll(turn.as_quat(), 1, axis=1)  # scalar first
    result = run_trajopt(body, q, FPS, np.ones((frames, 4), bool), QUICK)
    assert result.converged.all()
    assert all(stage.converged for w in result.windows for stage in w.stages)
    assert sum(stage.iterations for w in result.windows for stage in w.stages) < QUICK.max_iterations / 4
    lengths = reduced_motion(body, q, FPS).foot_length
    for side, (h, t) in enumerate(((0, 1), (2, 3))):
        both = result.contacts[:, h] & result.contacts[:, t]
        assert both.any()
        span = np.linalg.norm(result.feet[both, h] - result.feet[both, t], axis=-1)
        assert np.allclose(span, lengths[side], rtol=1e-3)


def test_window_ranges_cover_the_clip_with_overlap():
    s = TrajoptSettings(window_seconds=2.0, window_overlap=0.5)
    ranges = window_ranges(301, FPS, s)
    assert ranges[0][0] == 0 and ranges[-1][1] == 300 and ranges[-1][2] == 301
    for (a, b, keep), (a2, _, _) in itertools.pairwise(ranges):
        assert keep == a2 and b - keep >= 14 and b - a <= 60
    assert window_ranges(50, FPS, s) == [(0, 49, 50)]


# ---- solutions ------------------------------------------------------------------------------------------------
def check_physics(body, result, settings):
    """Newton at every frame with the COM spline's acceleration; forces in the pyramid; contact points
    still and on the floor while in contact; zero force in flight."""
    weight = body.mass * G
    f = result.grf
    assert np.all(f[..., 2] >= -1e-3 * weight)
    assert np.all(f[..., 2] <= settings.max_force + 1e-3 * weight)
    assert np.all(np.abs(f[..., :2]) <= settings.friction * f[..., 2:3] + 1e-3 * weight)
    assert np.all(f[~result.contacts] == 0)
    newton = body.mass * result.com_acceleration - (f.sum(axis=1) + np.array([0, 0, -body.mass * G]))
    assert np.abs(newton).max() < 1e-3 * weight
    # The acceleration is the COM trajectory's: C2, so its second differences agree, and no acceleration hides
    # between the frames (their means agree too).
    acc = (result.com[2:] - 2 * result.com[1:-1] + result.com[:-2]) * FPS**2
    assert np.median(np.abs(acc - result.com_acceleration[1:-1])) < 0.5
    assert np.abs(acc.mean(axis=0) - result.com_acceleration[1:-1].mean(axis=0)).max() < 0.3
    for i in range(4):
        c = result.contacts[:, i]
        assert np.all(np.abs(result.feet[c, i, 2]) < 1e-6)
        still = c[1:] & c[:-1]
        assert np.all(np.linalg.norm(np.diff(result.feet[:, i], axis=0)[still], axis=-1) < 1e-6)
        assert np.all(result.feet[~c, i, 2] > -1e-4)


def test_frame_samples_hold_every_frame_whatever_the_rate():
    for fps in (10.0, 23.976, 24.0, 30.0, 60.0):
        frames = np.arange(37) / fps
        times = frame_sample_times(frames, 1.0 / 60.0)
        assert np.isin(frames, times).all()
        assert np.diff(times).max() <= 1.0 / 60.0 + 1e-9 and np.diff(times).min() > 0
    assert np.array_equal(frame_sample_times(frames, 0.0), frames)


def test_newton_samples_are_the_frames_up_to_60_fps_then_the_clock():
    """Newton's equation is held at every frame (and between) up to 60 fps; above, every 1/60 s of the clock, so
    that a 0.05 s COM piece never gets more samples than at 60 fps (six at 120 fps: IPOPT failed on half of the
    clips)."""
    interval = 1.0 / 60.0
    for fps in (10.0, 23.976, 30.0, 60.0):
        frames = np.arange(1, 73) / fps
        assert np.array_equal(newton_sample_times(frames, interval), frame_sample_times(frames, interval))
    for fps in (90.0, 100.0, 120.0, 240.0):
        frames = np.arange(3, 300) / fps
        times = newton_sample_times(frames, interval)
        assert times[0] == frames[0] and times[-1] == frames[-1]
        assert np.diff(times).max() <= 1.5 * interval + 1e-9 and np.diff(times[1:-1]).min() > interval * (1 - 1e-9)
    frames = np.arange(3, 300) / 120.0
    assert np.isin(np.round(newton_sample_times(frames, interval), 12), np.round(frames, 12)).all()


@pytest.mark.slow
def test_the_same_motion_at_60_and_120_fps_gives_the_same_physics(body):
    """Swaying with the left toe stepping every 0.2 s, at 60 and 120 fps: the same Newton rows in seconds, the
    same COM and net force at common frames (held at every 120 fps frame, the net force was tied to the COM's
    piecewise-linear acceleration: 1.0 mm and 0.034 body weights apart here, and on half of the real clips IPOPT
    did not converge), and Newton's equation exact at its samples."""
    runs, rows = {}, {}
    for fps in (60.0, 120.0):
        frames = int(2 * fps)
        q = standing(body, frames)
        t = np.arange(frames) / fps
        q[:, 1] += 0.04 * np.sin(2 * np.pi * 0.6 * t)
        q[:, 0] += 0.03 * np.sin(2 * np.pi * 0.4 * t)
        contacts = np.ones((frames, 4), bool)
        contacts[:, 1] = (t * 5).astype(int) % 2 == 0
        red = reduced_motion(body, q, fps)
        problem = build_window_problem(Window(red, [contact_phases(contacts[:, i], red.times) for i in range(4)]),
                                       QUICK)
        rows[fps] = problem.constraints["dynamics"].size
        runs[fps] = run_trajopt(body, q, fps, contacts, TrajoptSettings(contact_drift=0.0))
        assert runs[fps].converged.all()
    assert rows[120.0] == rows[60.0]
    weight = body.mass * G
    slow, fast = runs[60.0], runs[120.0]
    assert np.abs(slow.com - fast.com[::2]).max() < 5e-4
    assert np.abs(slow.grf.sum(axis=1) - fast.grf[::2].sum(axis=1)).max() < 0.02 * weight
    newton = body.mass * fast.com_acceleration - (fast.grf.sum(axis=1) + np.array([0, 0, -weight]))
    times = np.arange(len(newton)) / 120.0
    held = np.isin(np.round(times, 9), np.round(newton_sample_times(times, QUICK.linear_dynamics_interval), 9))
    assert held.sum() > len(newton) / 2 - 2 and np.abs(newton[held]).max() < 1e-3 * weight


def test_com_knots_stay_on_the_clock_whatever_the_rate_or_length(body):
    """The COM's knots (and the constraint grids) sit on multiples of their interval in seconds: the same motion at
    another frame rate, or a clip a frame shorter, keeps every knot away from its end (an even spread over the
    window moved them all, and the joints by 4-7 mm)."""
    knots = {}
    for fps, T in ((10.0, 29), (24.0, 69), (30.0, 86), (60.0, 172), (60.0, 171)):
        red = reduced_motion(body, sway(body, T), fps)
        phases = [contact_phases(np.ones(T, bool), red.times)] * 4
        t = build_window_problem(Window(red, phases), QUICK).com.node_times
        assert t[0] == red.times[0] and t[-1] == red.times[-1]
        assert QUICK.com_interval / 2 < np.diff(t).min() and np.diff(t).max() < 1.5 * QUICK.com_interval
        knots[(fps, T)] = t[1:-1]
    inner = knots[(10.0, 29)]  # 0.05 .. 2.75 s
    for t in knots.values():
        assert np.allclose(t[:len(inner)], inner)
    assert np.allclose(clock_times(0.31, 0.72, 0.1), [0.31, 0.4, 0.5, 0.6, 0.72])


def test_force_limits_hold_wherever_newton_is_held(body):
    """At 12 fps Newton's equation is held 4 times between frames; limits held at the frames only let the cubics
    there pull on the floor and push tens of body weights (mmhuman3d_single_person_demo, issue 24)."""
    fps = 12.0
    q = sway(body, 24)
    red = reduced_motion(body, q, fps)
    flags = np.ones(24, bool)
    flags[10:14] = False
    phases = [contact_phases(flags, red.times)] + [contact_phases(np.ones(24, bool), red.times)] * 3
    settings = TrajoptSettings()
    problem = build_window_problem(Window(red, phases), settings)
    limits = problem.constraints["force_limits"]
    lower, upper = limits.bounds()
    rows = ca.Function("g", [problem.x], [limits.expression()])
    x = np.random.default_rng(0).normal(size=int(problem.x.shape[0]))
    values = np.asarray(rows(x)).ravel()
    normal = values[(lower == 0.0) & (upper > 0.0)]  # the normal force rows, 0 <= f_z <= f_max
    samples = frame_sample_times(red.times, settings.linear_dynamics_interval)
    assert len(samples) == 5 * 23 + 1  # 4 samples between frames
    for i, force in enumerate(problem.forces):
        inside = np.logical_or.reduce([(samples >= p.start - 1e-9) & (samples <= p.end + 1e-9)
                                       for p in phases[i] if p.contact])
        fz = np.asarray(ca.Function("f", [problem.x], [problem.sample(force.trajectory, samples[inside])])(x))[2]
        assert np.isin(np.round(fz, 12), np.round(normal, 12)).all()


def test_force_rate_cost_is_the_frames_force_differences(body):
    q = sway(body, 30)
    red = reduced_motion(body, q, FPS)
    flags = np.ones(30, bool)
    flags[12:18] = False
    phases = [contact_phases(flags, red.times)] + [contact_phases(np.ones(30, bool), red.times)] * 3
    settings = TrajoptSettings(force_rate=0.3)
    problem = build_window_problem(Window(red, phases), settings)
    x = np.random.default_rng(0).normal(size=int(problem.x.shape[0]))
    cost = float(ca.Function("c", [problem.x], [problem.costs["force_rate"].expression(problem.x)])(x))
    expected = 0.0
    for force in problem.forces:
        f = np.asarray(ca.Function("f", [problem.x], [problem.sample(force.trajectory, red.times)])(x))
        expected += settings.force_rate * np.sum((np.diff(f, axis=1) * FPS) ** 2)
    assert np.isclose(cost, expected, rtol=1e-9)


def test_smoothing_is_read_between_frames_below_30_fps(body):
    """At 10 fps the velocity and force_rate terms read at the frames only let the polynomials swing between
    frames without cost; they are read every 1/30 s, each sample weighing a third of a frame interval."""
    fps, n = 10.0, 12
    q = sway(body, n)
    red = reduced_motion(body, q, fps)
    flags = np.ones(n, bool)
    flags[5:7] = False
    phases = [contact_phases(flags, red.times)] + [contact_phases(np.ones(n, bool), red.times)] * 3
    settings = TrajoptSettings(force_rate=0.3, velocity_com=0.7, velocity_orientation=0.0, velocity_feet=0.0)
    problem = build_window_problem(Window(red, phases), settings)
    x = np.random.default_rng(1).normal(size=int(problem.x.shape[0]))
    samples = np.arange(3 * (n - 1) + 1) / 30.0

    def term(name):
        return float(ca.Function("c", [problem.x], [problem.costs[name].expression(problem.x)])(x))

    def read(trajectory, order=0):
        return np.asarray(ca.Function("f", [problem.x], [problem.sample(trajectory, samples, order)])(x))

    expected = sum(settings.force_rate / 3 * np.sum((np.diff(read(f.trajectory), axis=1) * 30.0) ** 2)
                   for f in problem.forces)
    assert np.isclose(term("force_rate"), expected, rtol=1e-9)
    velocity = settings.velocity_com / 3 * np.sum(read(problem.com.position, 1) ** 2)
    assert np.isclose(term("velocity"), velocity, rtol=1e-9)


@pytest.mark.slow
def test_forces_at_24_fps_obey_newton_at_every_frame_without_chatter(body):
    """At 24 fps a grid of 1/60 s from the first frame missed every other frame, and there the forces, free,
    chattered up to 5-6 times body weight on slow tai-chi with flickering contact labels (issue 24)."""
    fps, frames = 24.0, 72
    q = sway(body, frames)
    contacts = np.ones((frames, 4), bool)
    contacts[:, 1] = (np.arange(frames) // 3) % 2 == 0  # the left toe flickers every 3 frames
    s = TrajoptSettings(contact_drift=0.0)
    result = run_trajopt(body, q, fps, contacts, s)
    assert result.converged.all()
    weight = body.mass * G
    net = result.grf.sum(axis=1)
    newton = body.mass * result.com_acceleration - (net + np.array([0, 0, -weight]))
    assert np.abs(newton).max() < 1e-3 * weight  # at every frame
    assert net[:, 2].max() < 1.3 * weight and net[:, 2].min() > 0.7 * weight
    assert np.abs(np.diff(net[:, 2], 2)).max() < 0.2 * weight


@pytest.mark.slow
def test_standing_is_carried_by_the_feet(body):
    q = standing(body, 40)
    result = run_trajopt(body, q, FPS, np.ones((40, 4), bool), QUICK)
    assert result.converged.all() and len(result.windows) == 1
    check_physics(body, result, QUICK)
    vertical = result.grf[..., 2].sum(axis=1)
    assert np.allclose(vertical, body.mass * G, rtol=0.02)
    # The output barely moves from a motion that is already physical.
    pts_in = kin.forward_kinematics(body, q).points
    pts_out = kin.forward_kinematics(body, result.qpos).points
    assert np.abs(pts_out - pts_in).max() < 0.02
    assert np.all(result.residual == 0) and np.all(result.qp_failures == 0)


@pytest.mark.slow
def test_jump_has_no_force_in_flight_and_a_ballistic_com(body):
    q, in_air = jump(body, frames=50, takeoff=18)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    result = run_trajopt(body, q, FPS, contacts, QUICK)
    assert result.converged.all()
    check_physics(body, result, QUICK)
    flight = np.flatnonzero(in_air)[1:-1]
    assert np.all(result.grf[flight] == 0)
    acc = (result.com[flight + 1] - 2 * result.com[flight] + result.com[flight - 1]) * FPS**2
    assert np.allclose(acc, [0, 0, -G], atol=0.3)
    # The take-off pushes harder than the weight.
    assert result.grf[..., 2].sum(axis=1).max() > 1.2 * body.mass * G


@pytest.mark.slow
def test_sliding_sinking_input_is_planted(body):
    """A kinematic motion whose feet slide 20 cm and sink 2 cm while labelled in contact comes out still and
    on the floor, the upper body near the input (the drifting contacts kept whole: contact_drift off)."""
    q = standing(body, 36)
    q[:, 0] += np.linspace(0, 0.2, 36)
    q[:, 2] -= 0.02
    result = run_trajopt(body, q, FPS, np.ones((36, 4), bool), TrajoptSettings(contact_drift=0.0))
    assert result.converged.all()
    soles = kin.forward_kinematics(body, result.qpos).points[:, body.point_index(CONTACT_POINTS)]
    assert np.abs(soles[..., 2]).max() < 0.01
    assert np.linalg.norm(np.diff(soles, axis=0), axis=-1).max() < 0.005
    head = body.point_index(["head"])[0]
    assert np.abs(kin.forward_kinematics(body, result.qpos).points[:, head]
                  - kin.forward_kinematics(body, q).points[:, head]).max() < 0.15


def sway(body, frames):
    """Standing, the body swaying sideways and forwards (COM +-4 cm at 0.6 and 0.4 Hz) over planted feet (the
    input's feet sway along: run with contact_drift off, or they would be re-placed)."""
    q = standing(body, frames)
    t = np.arange(frames) / FPS
    q[:, 1] += 0.04 * np.sin(2 * np.pi * 0.6 * t)
    q[:, 0] += 0.03 * np.sin(2 * np.pi * 0.4 * t)
    return q


@pytest.mark.slow
def test_long_clips_are_windowed_and_stitched_continuously(body):
    q = sway(body, 100)
    s = TrajoptSettings(window_seconds=1.5, window_overlap=0.5, contact_drift=0.0, parallel_windows=False)
    result = run_trajopt(body, q, FPS, np.ones((100, 4), bool), s)
    assert len(result.windows) >= 3 and result.converged.all()
    assert all(w.com_departure < 0.02 for w in result.windows)
    check_physics(body, result, s)
    # Position and velocity continue across the junctions (the acceleration may change there, as the forces
    # may): the first differences' steps there are no larger than elsewhere.
    step = np.linalg.norm(np.diff(result.com, 2, axis=0), axis=1)
    junctions = [w.start - 1 for w in result.windows[1:]]
    assert step[junctions].max() <= 2 * np.delete(step, junctions).max() + 1e-4
    # The sway's sideways force: m a of the input's sine, carried by the feet.
    expected = body.mass * 0.04 * (2 * np.pi * 0.6) ** 2
    assert abs(np.abs(result.grf[..., 1].sum(axis=1)).max() - expected) < 0.3 * expected


@pytest.mark.slow
def test_windows_two_at_a_time_meet_each_other_whoever_solves_them(body, monkeypatch):
    """parallel_windows: the even windows from free starts, then each odd one from its predecessor's state to its
    successor's start; the same numbers whether worker processes or this one solve them (issue 23)."""
    q = sway(body, 100)
    s = TrajoptSettings(window_seconds=1.5, window_overlap=0.5, contact_drift=0.0, parallel_windows=True)
    result = run_trajopt(body, q, FPS, np.ones((100, 4), bool), s)
    assert len(result.windows) == 3 and result.converged.all() and not any(w.restarted for w in result.windows)
    assert result.windows[1].stop == result.windows[2].start  # the odd window ends where the next one starts
    step = np.linalg.norm(np.diff(result.com, 2, axis=0), axis=1)
    junctions = [w.start - 1 for w in result.windows[1:]]
    assert step[junctions].max() <= 2 * np.delete(step, junctions).max() + 1e-4
    # A contact held through the whole odd window keeps its predecessor's place, while the successor fitted the
    # same planted point on its own: at that junction the point steps, within how far the input's point strays
    # (the sway's feet sway along; docs/decisions/trajopt-long-clips.md).
    feet_step = np.linalg.norm(np.diff(result.feet, axis=0), axis=-1).max(axis=1)
    odd = result.windows[1]
    stray = np.linalg.norm(np.ptp(reduced_motion(body, q, FPS).feet[odd.start:odd.stop + 1], axis=0), axis=-1)
    assert feet_step[junctions[0]] < 1e-6 and feet_step[junctions[1]] <= stray.max()
    monkeypatch.setattr(stage, "PARALLEL_WORKERS", 10 ** 6)  # more than any machine's cores: all in this process
    alone = run_trajopt(body, q, FPS, np.ones((100, 4), bool), s)
    for name in ("qpos", "grf", "com", "feet", "contacts", "converged"):
        assert np.array_equal(getattr(alone, name), getattr(result, name)), name


def test_failure_is_loud_and_keeps_the_kinematic_motion(body, caplog):
    q, in_air = jump(body, frames=40)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    s = TrajoptSettings(optimize_durations=False, max_iterations=2)
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        result = run_trajopt(body, q, FPS, contacts, s)
    assert not result.converged.any()
    assert np.array_equal(result.qpos, q) and np.all(result.grf == 0) and np.all(result.qp_failures == 1)
    assert "did not converge" in caplog.text and "NOT converged" in result.summary()
    assert result.failed_frames == ["0-39"]


@pytest.mark.slow
def test_every_window_keeps_within_its_iteration_budget(body):
    """All IPOPT runs of a window (fit, dynamics, a restart) share settings.max_iterations: on long clips a window
    that wandered to each stage's limit and then restarted cost 20-70 times a converged one (issue 23)."""
    q, in_air = jump(body, frames=60, takeoff=25)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    s = TrajoptSettings(window_seconds=1.0, window_overlap=0.3, max_iterations=12)
    result = run_trajopt(body, q, FPS, contacts, s)
    assert len(result.windows) >= 2
    for window in result.windows:
        runs = [st.iterations for st in window.stages]
        assert sum(runs) <= s.max_iterations and runs[0] <= s.max_iterations // 2
    assert not result.converged.all()


@pytest.mark.slow
def test_duration_stage_keeps_the_better_solution(body):
    q, in_air = jump(body, frames=40, takeoff=12)
    # The fixture dips the whole standing pose, feet and all: held within 4.5 cm, so that the frames whose labels
    # lift off early do not read as feet deep under the floor, another level (support.under_the_floor).
    q[:, 2] = np.maximum(q[:, 2], standing(body, 1)[0, 2] - 0.045)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    contacts[11:13] = False  # the labels lift off two frames early
    s = TrajoptSettings(optimize_durations=True, max_iterations=250)  # the durations stage gets what is left
    result = run_trajopt(body, q, FPS, contacts, s)
    assert result.converged.all()
    report = result.windows[0]
    names = [st.name for st in report.stages]
    assert names[:2] == ["fit", "dynamics"]
    if report.chosen == "durations":
        assert report.stages[2].converged and report.stages[2].objective < report.stages[1].objective
    check_physics(body, result, s)


@pytest.mark.slow
def test_durations_program_shares_the_layout(body):
    q, in_air = jump(body, frames=30, takeoff=8, flight=0.3)
    red = reduced_motion(body, q, FPS)
    phases = [contact_phases(~in_air, red.times) for _ in range(4)]
    window = Window(red, phases)
    s = TrajoptSettings(optimize_durations=True)
    fixed, moving = build_window_problem(window, s), build_window_problem(window, s, durations=True)
    assert [v.size for v in fixed.variable_sets] == [v.size for v in moving.variable_sets[:-1]]
    assert moving.durations.set.size == 4 * 2  # lift-off and touch-down of each point
    assert np.all(moving.durations.set.upper - moving.durations.set.lower <= 2 * s.max_duration_change + 1e-12)


def test_com_acceleration_may_jump_only_where_a_contact_begins_or_ends(body):
    q, in_air = jump(body, frames=30, takeoff=8, flight=0.3)
    red = reduced_motion(body, q, FPS)
    phases = [contact_phases(~in_air, red.times) for _ in range(4)]
    window = Window(red, phases)
    s = TrajoptSettings()
    problem = build_window_problem(window, s)
    knots = np.array([seg.nominal[0] for seg in problem.com.position.segments[1:]])
    changes = np.array([p.start for p in phases[0][1:]])  # lift-off and touch-down
    near = (np.abs(knots[:, None] - changes[None]) <= s.contact_change_reach * s.com_interval + 1e-9).any(axis=1)
    assert len(changes) == 2 and 2 <= near.sum() <= len(knots) // 2
    rows = lambda settings: acceleration_continuity(build_window_problem(window, settings)).size  # noqa: E731
    everywhere = rows(dataclasses.replace(s, contact_change_reach=0.0))
    on_change = (np.abs(knots[:, None] - changes[None]) <= 1e-9).any(axis=1)  # the touch-down, 0.55 s
    assert on_change.sum() == 1
    assert everywhere == 2 * 3 * (len(knots) - 1)  # position and orientation, 3 each, at every other inner knot
    assert everywhere - rows(s) == 2 * 3 * (near.sum() - 1)


@pytest.mark.slow
def test_frames_without_observations_split_the_clip(body):
    q = sway(body, 70)
    valid = np.ones(70, bool)
    valid[30:36] = False
    result = run_trajopt(body, q, FPS, np.ones((70, 4), bool), QUICK, valid=valid)
    assert len(result.windows) == 2
    assert result.converged[:30].all() and result.converged[36:].all() and not result.converged[30:36].any()
    assert np.array_equal(result.qpos[30:36], q[30:36]) and not result.contacts[30:36].any()
    assert result.failed_frames == ["30-35"]
    tiny = run_trajopt(body, q[:2], FPS, np.ones((2, 4), bool), QUICK)
    assert not tiny.converged.any() and np.array_equal(tiny.qpos, q[:2])


def test_the_motion_passes_to_frames_kept_kinematic_without_a_jump(body):
    """Next to frames handed back to the kinematic motion (here a COM below the floor), the output is blended
    into it over stage.BLEND_SECONDS instead of jumping there."""
    q = sway(body, 50)
    q[40:, 2] -= 1.5
    result = run_trajopt(body, q, FPS, np.ones((50, 4), bool), TrajoptSettings(contact_drift=0.0))
    gap = np.linalg.norm(kin.forward_kinematics(body, result.qpos).points - kin.forward_kinematics(body, q).points,
                         axis=-1).mean(axis=1)
    blend = int(stage.BLEND_SECONDS * FPS)
    assert result.converged[:40].all() and np.all(gap[40:] == 0)
    assert gap[39] < 0.5 * gap[10:40 - blend].mean()
    assert np.all(np.diff(gap[40 - blend:40]) < 1e-3)  # handed over gradually
    share = stage._kinematic_share(result.converged, FPS)
    assert np.all(share[:40 - blend - 1] == 0) and np.all(share[40:] == 1) and 0.8 < share[39] < 1


def test_frames_whose_com_is_below_the_floor_are_kept_kinematic_and_flagged(body, caplog):
    """A COM below the floor (a person leaving the view, a floor at another height) is not a motion the feet on
    the floor explain: optimised, such an island at the clip's end asked for several body weights."""
    q = sway(body, 50)
    q[40:, 2] -= 1.5  # the last 10 frames sink below the floor
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        result = run_trajopt(body, q, FPS, np.ones((50, 4), bool), TrajoptSettings(contact_drift=0.0))
    assert np.array_equal(result.unexplained, np.arange(50) >= 40)
    assert result.converged[:40].all() and not result.converged[40:].any()
    assert np.array_equal(result.qpos[40:], q[40:]) and np.all(result.grf[40:] == 0)
    assert "40-49" in caplog.text and "below the floor" in caplog.text
    assert "cannot explain frames 40-49" in result.summary()
    again = stage.TrajoptMotion.from_arrays(result.to_arrays())
    assert np.array_equal(again.unexplained, result.unexplained)


def test_frames_resting_on_a_knee_are_kept_kinematic_and_flagged(body):
    """Down on the left knee (test_physics_limits.kneeling) for frames 20-29: the knee carries weight that no sole
    point can; those frames are left kinematic and flagged, the standing ones around them are optimised."""
    from test_physics_limits import kneeling

    q = sway(body, 50)
    q[20:30] = kneeling(body, 0.02)
    q[20:30, :2] = q[19, :2]
    pose = kin.forward_kinematics(body, q)
    assert np.array_equal(unexplained_frames(body.point_names, pose.points, kin.center_of_mass(body, pose)),
                          (np.arange(50) >= 20) & (np.arange(50) < 30))


@pytest.mark.slow
def test_a_solution_far_from_the_input_is_not_used(body, caplog):
    """Feet labelled in contact while they slide 60 cm: the converged motion keeps them still, so its centre of
    mass ends far from the input's; beyond reject_departure the window is flagged and the input kept."""
    q = standing(body, 36)
    q[:, 0] += np.linspace(0, 0.6, 36)
    contacts = np.ones((36, 4), bool)
    kept = run_trajopt(body, q, FPS, contacts, TrajoptSettings(contact_drift=0.0))
    departure = kept.windows[0].com_departure
    assert kept.converged.all() and departure > 0.02
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        result = run_trajopt(body, q, FPS, contacts,
                             TrajoptSettings(contact_drift=0.0, reject_departure=0.5 * departure))
    assert not result.converged.any() and result.windows[0].departed
    assert np.array_equal(result.qpos, q) and np.all(result.grf == 0) and np.all(result.qp_failures == 1)
    assert "reject_departure" in caplog.text and "departed" in result.summary()
    assert "NOT used" in result.windows[0].describe()


@pytest.mark.slow
def test_a_solution_far_from_the_input_on_some_frames_is_not_used(body):
    """The same sliding feet: the optimised COM leaves the input gradually, so its largest departure is well over
    its mean. A limit between the two rejects the window: a solution that holds its input on average can still
    drop the body far for a few frames (measured: 50 cm on a taiji video, 11 cm on average)."""
    q = standing(body, 36)
    q[:, 0] += np.linspace(0, 0.6, 36)
    contacts = np.ones((36, 4), bool)
    window = run_trajopt(body, q, FPS, contacts, TrajoptSettings(contact_drift=0.0)).windows[0]
    assert window.com_departure_max > 1.5 * window.com_departure
    limit = 0.5 * (window.com_departure + window.com_departure_max)
    result = run_trajopt(body, q, FPS, contacts, TrajoptSettings(contact_drift=0.0, reject_departure=limit))
    assert result.windows[0].departed and not result.converged.any()


# The CLI, with each IPOPT run announced on stdout so that the test can interrupt one while it runs. Ctrl-C
# handled as on a terminal: a test run in the background (a shell's `&`) inherits SIGINT ignored.
ANNOUNCING_CLI = """
import signal
import sys
signal.signal(signal.SIGINT, signal.default_int_handler)
from physmocap.cli import main
import time
from physmocap.trajopt.problem import IterationWatch, Program
solve = Program.solve
runs = 0
def announced(self, *args, **kwargs):
    global runs
    runs += 1
    print("IPOPT starts", flush=True)
    return solve(self, *args, **kwargs)
Program.solve = announced
def iterating(self, arg):  # the second run's Ctrl-C lands while IPOPT iterates: inside this callback
    if runs == 2 and self.count == 2:
        print("IPOPT iterates", flush=True)
        time.sleep(2.0)
    return stop(self, arg)
stop = IterationWatch.eval
IterationWatch.eval = iterating
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.slow
def test_ctrl_c_inside_the_solver_stops_the_run_and_caches_nothing(tmp_path):
    out = tmp_path / "run"
    capture = ["capture", str(DEMO_VIDEO), "-o", str(out), "--no-overlay"]
    first = subprocess.run([sys.executable, "-m", "physmocap.cli", *capture, "--physics", "none"],
                           capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    child = subprocess.Popen([sys.executable, "-c", ANNOUNCING_CLI, *capture, "--physics", "trajopt"],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines, runs = [], 0
    for line in child.stdout:
        lines.append(line)
        runs += line.startswith("IPOPT starts")
        if runs == 2 and line.startswith("IPOPT iterates"):  # the first window's dynamics stage
            child.send_signal(signal.SIGINT)
            break
    text = "".join(lines) + child.communicate(timeout=600)[0]
    assert text.count("IPOPT starts") == 2, text  # the interrupted solve was the last: no stage went on
    assert child.returncode == 130, text
    assert "interrupted" in text and "Traceback" not in text
    assert not (out / "cache" / "trajopt.npz").exists()  # nothing from the interrupted stage
    assert (out / "cache" / "observations.npz").exists()  # the finished stages stay cached


def test_a_window_that_fails_is_solved_again_with_its_start_velocity_free(body, monkeypatch):
    """A window without a neighbour's state to drop (the clip's first) used to keep the kinematic motion when the
    input's start velocity could not be met; its first solve now gets half the budget and the retry the rest."""
    q, in_air = jump(body, frames=40, takeoff=12)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    s = TrajoptSettings(max_iterations=400)
    calls = []
    solve = stage.solve_window

    def first_fails(window, settings, budget=None, stop_stalled=False):
        calls.append((window.start_velocity, budget, stop_stalled))
        result = solve(window, settings, budget, stop_stalled)
        if len(calls) == 1:
            result.converged = False
        return result

    monkeypatch.setattr(stage, "solve_window", first_fails)
    result = run_trajopt(body, q, FPS, contacts, s)
    assert len(calls) == 2 and calls[0][1] == s.max_iterations // 2
    assert calls[0][0] is not None and calls[1][0] is None
    assert calls[0][2] and not calls[1][2]  # a stall stops the first try, never the retry
    assert result.converged.all() and result.windows[0].restarted
    assert sum(st.iterations for st in result.windows[0].stages) <= s.max_iterations
