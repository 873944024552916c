"""PhysCap stage III: tests that check physics, not just that it runs."""

import mujoco
import numpy as np
import pytest

from physmocap.body import kinematics as kin
from physmocap.body.kinematics import rigid_transform_qpos
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.body.rotations import quat_exp, quat_multiply
from physmocap.config import PhysicsSettings
from physmocap.dynamics.balance import BalanceCorrector, inside_support
from physmocap.dynamics.physcap import PhysCapTracker
from physmocap.dynamics.qp import DenseQP
from physmocap.dynamics.stage import (
    PhysicsStream,
    forces_at_frames,
    kinematic_derivatives,
    run_physcap,
    zero_phase_velocities,
)

FPS = 25.0
G = 9.81


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.75), 72.0)


def track(body, qpos_kin, contacts, settings=None, stationary=None):
    """Run the tracker over a kinematic motion, keeping every integration step."""
    velocity, acceleration = kinematic_derivatives(body, qpos_kin, FPS)
    tracker = PhysCapTracker(body, settings or PhysicsSettings(), FPS, record=True)
    tracker.reset(qpos_kin[0], velocity[0])
    frames = [tracker.track(q, v, a, c) for q, v, a, c in zip(qpos_kin, velocity, acceleration, contacts, strict=True)]
    return tracker, frames, [r for f in frames for r in f.records]


def standing(body, frames):
    return np.repeat(body.rest_qpos[None], frames, axis=0)


def jump(body, frames=40, takeoff=10, flight=0.4):
    """Stand, then a ballistic flight of `flight` seconds, then stand again: the root's height follows the
    parabola, and the feet leave the floor. Returns poses and the flight frames."""
    q = standing(body, frames)
    t = (np.arange(frames) - takeoff) / FPS
    in_air = (t > 0) & (t < flight)
    v0 = G * flight / 2
    q[in_air, 2] += v0 * t[in_air] - 0.5 * G * t[in_air] ** 2
    return q, in_air


def squat(body, frames, fps, period, depth=0.35):
    """Knees bending and straightening with the feet flat on the floor (hips and ankles bent half as far): the
    centre of mass sinks about 20 cm and rises again every `period` seconds."""
    theta = depth * (1 - np.cos(2 * np.pi * np.arange(frames) / fps / period))
    step = np.zeros((frames, body.nv))
    for side in ("left", "right"):
        step[:, body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = -theta
        step[:, body.dof_address[body.joint_index[f"{side}_knee"]]] = 2 * theta
        step[:, body.dof_address[body.joint_index[f"{side}_ankle"]] + 1] = -theta
    q = kin.integrate(body, standing(body, frames), step)
    q[:, 2] -= kin.forward_kinematics(body, q).points[:, body.point_index(CONTACT_POINTS), 2].min(axis=1)
    return q


def test_equation_of_motion_holds_at_every_step(body):
    q, in_air = jump(body)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    tracker, _, records = track(body, q, contacts)
    m = mujoco.MjModel.from_xml_string(_xml_without_contacts(body))
    d = mujoco.MjData(m)
    jac = np.zeros((3, m.nv))
    for r in records:
        d.qpos[:], d.qvel[:], d.qacc[:] = r.qpos, r.qvel, r.qacc
        mujoco.mj_inverse(m, d)  # M qdd + c, computed independently by MuJoCo
        external = np.zeros(m.nv)
        for j, name in enumerate(CONTACT_POINTS):
            mujoco.mj_jacSite(m, d, jac, None, m.site(name).id)
            external += jac.T @ r.contact_forces[j]
        residual = d.qfrc_inverse - (r.torque + external)
        assert np.abs(residual).max() < 1e-6 * (1 + np.abs(d.qfrc_inverse).max())


def _xml_without_contacts(body):
    from physmocap.body.mujoco_model import mjcf_xml

    return mjcf_xml(body).replace('<option timestep', '<option><flag contact="disable"/></option>\n  <option timestep')


def test_forces_stay_in_the_friction_pyramid_and_never_pull(body):
    rng = np.random.default_rng(0)
    q = standing(body, 30)
    q[:, 0] += 0.3 * np.sin(np.arange(30) / 4)  # a sway the feet must resist
    q = kin.integrate(body, q, rng.normal(scale=0.05, size=(30, body.nv)) * (np.arange(body.nv) >= 6))
    _, _, records = track(body, q, np.ones((30, 4), bool))
    mu = PhysicsSettings().friction / np.sqrt(2)
    for r in records:
        f = r.contact_forces
        assert np.all(f[:, 2] >= -1e-6)
        assert np.all(np.abs(f[:, :2]) <= mu * f[:, 2:3] + 1e-6)
        assert np.all(f[~r.active] == 0)


def test_standing_still_is_carried_by_the_feet(body):
    q = standing(body, 50)
    tracker, frames, records = track(body, q, np.ones((50, 4), bool))
    weight = body.mass * G
    vertical = np.array([f.contact_forces[:, 2].sum() for f in frames[10:]])
    assert np.all(np.abs(vertical - weight) < 0.05 * weight)
    residual = np.array([np.linalg.norm(f.residual[:3]) for f in frames[10:]])
    assert residual.max() < 0.01 * weight
    soles = kin.forward_kinematics(body, np.array([r.qpos for r in records])).points[
        :, body.point_index(CONTACT_POINTS)]
    assert np.abs(soles - soles[0]).max() < 1e-3


def test_a_target_sunk_into_the_floor_is_lifted_and_carried_by_the_feet(body):
    # The kinematic fit stands 3 cm too low: its soles lie under the floor, where the character cannot follow.
    # Lifted out of the floor, the weight rests on the feet; without the lift, the floor holds up the body its root
    # PD pulls down: the character stands 3 cm above its target, its weight still on the feet (the forces are
    # those its motion needed, not those the PD asked for).
    q = standing(body, 60)
    q[:, 2] -= 0.03
    contacts, stationary = np.ones((60, 4), bool), np.zeros(60, bool)
    weight = body.mass * G
    lifted = run_physcap(body, q, FPS, contacts, stationary, PhysicsSettings())
    sunk = run_physcap(body, q, FPS, contacts, stationary, PhysicsSettings(target_lift_time=None))
    settled = slice(30, None)
    assert np.all(np.abs(lifted.grf[settled, :, 2].sum(axis=1) - weight) < 0.05 * weight)
    assert np.abs(lifted.residual[settled, 2]).max() < 0.02 * weight
    assert np.all(np.abs(sunk.grf[settled, :, 2].sum(axis=1) - weight) < 0.05 * weight)
    assert np.abs(sunk.residual[settled, 2]).max() < 0.02 * weight
    assert np.all(sunk.qpos[settled, 2] - q[settled, 2] > 0.025)
    for motion in (lifted, sunk):
        soles = kin.forward_kinematics(body, motion.qpos[settled]).points[:, body.point_index(CONTACT_POINTS)]
        assert np.abs(soles[..., 2]).max() < 2e-3


def test_a_flat_foot_fitted_tilted_is_turned_flat_before_the_lift(body):
    # The fit tilts the left foot 10 degrees toes-down while heel and toe are both predicted on the floor: the target
    # foot is turned flat about the ankle (gradually), so that the lift does not leave the heel hanging.
    q = standing(body, 40)
    ankle = body.qpos_address[body.joint_index["left_ankle"]]
    q[:, ankle:ankle + 4] = quat_multiply(quat_exp(np.radians(10.0) * np.array([0.0, 1.0, 0.0])), q[0, ankle:ankle + 4])
    contacts = np.ones((40, 4), bool)
    sole = body.point_index(CONTACT_POINTS)
    fitted = kin.forward_kinematics(body, q[:1]).points[0, sole, 2]
    assert abs(fitted[0] - fitted[1]) > 0.02  # the fitted heel and toe of the left foot differ by centimetres
    for flatten in (True, False):
        stream = PhysicsStream(body, PhysicsSettings(flatten_feet=flatten), FPS)
        targets = np.array([stream._target_on_floor(frame, c) for frame, c in zip(q, contacts, strict=True)])
        heights = kin.forward_kinematics(body, targets[-5:]).points[:, sole, 2]
        tilt = np.abs(heights[:, 0] - heights[:, 1])
        assert np.all(heights > -1e-3)  # lifted out of the floor either way
        if flatten:
            assert tilt.max() < 2e-3
        else:
            assert tilt.min() > 0.02


def test_flight_has_no_contact_force_and_a_ballistic_centre_of_mass(body):
    q, in_air = jump(body)
    contacts = np.repeat(~in_air[:, None], 4, axis=1)
    tracker, frames, records = track(body, q, contacts)
    flight = [f for f, air in zip(frames, in_air, strict=True) if air]
    assert all(np.all(f.contact_forces == 0) for f in flight[1:])
    # Newton for the whole body: m a_com = m g + root residual force, with no contact force in the air.
    air_steps = [i for i, r in enumerate(records) if not r.active.any() and 0 < i < len(records) - 1]
    com = kin.center_of_mass(body, kin.forward_kinematics(body, np.array([r.qpos for r in records])))
    dt = tracker.dt
    for i in air_steps[2:-2]:
        accel = (com[i + 1] - 2 * com[i] + com[i - 1]) / dt**2
        # semi-implicit Euler: q_{i+1} - 2 q_i + q_{i-1} = dt^2 qdd_i
        expected = np.array([0, 0, -G]) + records[i].torque[:3] / body.mass
        assert np.linalg.norm(accel - expected) < 0.5


def test_stationary_leaning_pose_is_brought_back_to_balance(body):
    q = standing(body, 80)
    # Lean forward by 25 degrees about the line through the toes: the centre of mass leaves the feet.
    toes = kin.forward_kinematics(body, body.rest_qpos).points[0, body.point_index(["left_toe", "right_toe"])]
    pivot = toes.mean(axis=0)
    angle = np.radians(25)
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    q = rigid_transform_qpos(q, R, pivot - R @ pivot)
    heels_up = kin.forward_kinematics(body, q[:1]).points[0, body.point_index(CONTACT_POINTS)]
    contacts = np.repeat((heels_up[:, 2] < 0.05)[None], 80, axis=0)
    pose = kin.forward_kinematics(body, q[:1])
    support = heels_up[contacts[0], :2]
    margin = BalanceCorrector(body).margin  # half a foot's breadth
    assert not inside_support(kin.center_of_mass(body, pose)[0, :2], support, margin)
    result = run_physcap(body, q, FPS, contacts, np.ones(80, bool), PhysicsSettings())
    final = kin.forward_kinematics(body, result.qpos[-10:])
    feet = final.points[:, body.point_index(CONTACT_POINTS)]
    com = kin.center_of_mass(body, final)
    assert result.corrected.any()
    assert all(inside_support(c[:2], f[contacts[0], :2], margin) for c, f in zip(com, feet, strict=True))


def upright_and_leaning(body) -> tuple[np.ndarray, np.ndarray]:
    """A standing pose (nq,) and the same pose tipped 25 degrees forward about the toes: out of balance."""
    upright = standing(body, 1)[0]
    toes = kin.forward_kinematics(body, body.rest_qpos).points[0, body.point_index(["left_toe", "right_toe"])]
    pivot = toes.mean(axis=0)
    angle = np.radians(25)
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    return upright, rigid_transform_qpos(upright[None], R, pivot - R @ pivot)[0]


def test_a_correction_relaxes_once_the_observed_pose_is_balanced_again(body):
    """A person leaning out of balance for a second, then standing upright and still: the accumulated tilt
    decays at the rate it grew and is dropped, so the upright frames end as observed (not moved for good)."""
    upright, leaning = upright_and_leaning(body)
    corrector = BalanceCorrector(body)
    contacts = np.ones(4, bool)
    for _ in range(int(FPS)):
        _, corrected = corrector.correct(leaning, True, contacts)
    assert corrected and corrector.tilt > 0.1
    tilts = []
    for _ in range(int(3 * FPS)):
        q, corrected = corrector.correct(upright, True, contacts)
        tilts.append(corrector.tilt)
    assert all(b <= a for a, b in zip(tilts, tilts[1:], strict=False))
    assert not corrected and corrector.tilt == 0.0 and np.array_equal(q, upright)


def test_a_correction_relaxes_when_the_person_moves_off(body):
    """A person leaning out of balance stands still for a second, then moves (and then leaves the floor): the
    accumulated tilt relaxes at the rate it grew, about the last support, and is dropped; it does not vanish in one
    frame, which stepped the target by up to 19 cm at the head on real video."""
    upright, leaning = upright_and_leaning(body)
    corrector = BalanceCorrector(body)
    for _ in range(int(FPS)):
        held, _ = corrector.correct(leaning, True, np.ones(4, bool))
    tilt = corrector.tilt
    moved, corrected = corrector.correct(leaning, False, np.ones(4, bool))
    assert corrected and corrector.tilt == pytest.approx(tilt * (1.0 - corrector.rate))

    def largest_step(a, b):
        return float(np.abs(kin.forward_kinematics(body, np.stack([a, b])).points.ptp(axis=0)).max())

    assert largest_step(moved, held) < 0.15 * largest_step(held, leaning)
    for _ in range(int(3 * FPS)):
        q, corrected = corrector.correct(leaning, False, np.zeros(4, bool))
    assert not corrected and np.array_equal(q, leaning)


def on_an_invisible_chair(body, bend: float) -> np.ndarray:
    """The standing pose (nq,) with both thighs forward and shanks down by `bend` rad, its lowest sole on the floor:
    an upright trunk on an invisible chair, its centre of mass behind the heels."""
    step = np.zeros(body.nv)
    for side in ("left", "right"):
        step[body.dof_address[body.joint_index[f"{side}_hip"]] + 1] = -bend  # thigh forward
        step[body.dof_address[body.joint_index[f"{side}_knee"]]] = bend  # shank down
    pose = kin.integrate(body, standing(body, 1), step[None])[0]
    pose[2] -= kin.forward_kinematics(body, pose[None]).points[0, body.point_index(CONTACT_POINTS), 2].min()
    return pose


def test_straightening_that_does_not_bring_balance_is_not_done(body):
    """Half sitting on an invisible chair (knees bent 40 degrees): the centre of mass lies behind the heels, and
    straightening the legs about the pelvis would only swing their mass farther back. The correction leaves the
    legs as observed instead of straightening them ever more (it had run on to straight legs)."""
    sitting = on_an_invisible_chair(body, np.radians(40.0))
    corrector = BalanceCorrector(body)
    pose = kin.forward_kinematics(body, sitting[None])
    feet = pose.points[0, body.point_index(CONTACT_POINTS), :2]
    assert not inside_support(kin.center_of_mass(body, pose)[0, :2], feet, corrector.margin)
    for _ in range(int(FPS)):
        q_out, corrected = corrector.correct(sitting, True, np.ones(4, bool))
    assert corrected and corrector.straighten == 0.0 and np.allclose(q_out, sitting)


def test_a_seated_pose_is_not_corrected(body):
    """Seated (knees bent 85 degrees), the centre of mass behind the heels, still, both feet down: a seat holds what
    the feet do not, and PhysCap's correction, made for standing poses, would stand the body up (on stools it moved
    the seated frames' joints 74 mm from the truth, against their input's 33-36)."""
    seated = on_an_invisible_chair(body, np.radians(85.0))
    corrector = BalanceCorrector(body)
    for _ in range(int(FPS)):
        q_out, corrected = corrector.correct(seated, True, np.ones(4, bool))
    assert not corrected and np.array_equal(q_out, seated)


def test_a_one_footed_stance_is_not_corrected(body):
    """Stationary on one foot is as often a slow step as a balance (on one real video the centre of mass lay a
    median 28 cm from the foot): the correction needs both feet on the floor. The base of support of the feet
    reaches half a foot's breadth beyond their heel and toe points."""
    upright, leaning = upright_and_leaning(body)
    corrector = BalanceCorrector(body)
    for _ in range(int(FPS)):
        q, corrected = corrector.correct(leaning, True, np.array([False, False, True, True]))
    assert not corrected and np.array_equal(q, leaning)
    line = np.array([[0.0, 0.0], [0.2, 0.0]])  # one foot's heel and toe
    assert inside_support(np.array([0.1, 0.04]), line, corrector.margin)
    assert not inside_support(np.array([0.1, 0.06]), line, corrector.margin)


def test_the_correction_grows_at_the_same_pace_in_seconds_at_any_frame_rate(body):
    """PhysicsStream's balance correction takes its share per frame from correction_time: after 0.2 s of the same
    leaning pose (before it is balanced) the accumulated tilt is the same at 10 and 60 fps (per frame, 60 fps grew
    it six times faster)."""
    upright, leaning = upright_and_leaning(body)
    tilts = {}
    for fps in (10.0, 60.0):
        corrector = PhysicsStream(body, PhysicsSettings(), fps).balance
        for _ in range(round(0.2 * fps)):
            corrector.correct(leaning, True, np.ones(4, bool))
        tilts[fps] = corrector.tilt
    assert tilts[10.0] > 0.05
    assert abs(tilts[10.0] - tilts[60.0]) < 0.15 * tilts[60.0]


def test_the_support_test_agrees_with_qhull_on_sole_points():
    """inside_support's own hull (monotone chain) decides as scipy's Qhull did, on random sets of 1-4 sole points
    and points around them, collinear and coincident sets included (Qhull refuses those: the segment test)."""
    from scipy.spatial import ConvexHull, QhullError

    def qhull_inside(point, support, margin=0.02):
        try:
            hull = ConvexHull(support)
        except QhullError:
            return None
        return bool(np.all(hull.equations[:, :2] @ point + hull.equations[:, 2] <= margin))

    rng = np.random.default_rng(3)
    compared = 0
    for trial in range(400):
        support = rng.uniform(-0.3, 0.3, (int(rng.integers(1, 5)), 2))
        if trial % 10 == 0 and len(support) >= 3:
            support[2] = support[0] + 0.5 * (support[1] - support[0])  # collinear with the first two
        if trial % 10 == 1 and len(support) >= 2:
            support[1] = support[0]  # coincident
        for point in rng.uniform(-0.4, 0.4, (5, 2)):
            expected = qhull_inside(point, support) if len(support) >= 3 else None
            if expected is not None:
                assert inside_support(point, support) == expected
                compared += 1
    assert compared > 500


def test_a_travelling_body_flagged_stationary_is_not_corrected(body):
    # The same forward lean, but the whole body glides sideways at 0.5 m/s: the root's speed overrules a
    # stationary flag (the correction would tilt a moving body), until the gate is switched off. What the first
    # frames accumulated, before the speed was known, relaxes and is dropped; it does not grow.
    frames = 120
    q = standing(body, frames)
    angle = np.radians(25)
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    q = rigid_transform_qpos(q, R, np.zeros(3))
    q[:, 1] += 0.5 * np.arange(frames) / FPS
    contacts = np.ones((frames, 4), bool)
    gated = run_physcap(body, q, FPS, contacts, np.ones(frames, bool), PhysicsSettings())
    ungated = run_physcap(body, q, FPS, contacts, np.ones(frames, bool),
                          PhysicsSettings(stationary_max_speed=None))
    interval = round(PhysicsSettings().stationary_speed_interval * FPS)
    relaxing = gated.corrected[interval:]
    assert not relaxing[-10:].any() and np.all(np.diff(relaxing.astype(int)) <= 0)  # once dropped, not taken up
    assert ungated.corrected[interval:].all()


def test_feet_in_contact_neither_sink_nor_slide(body):
    q = standing(body, 40)
    q[:, 2] -= 0.02  # the kinematic feet sink 2 cm into the floor
    q[:, 0] += np.linspace(0, 0.3, 40)  # and slide 30 cm forward (0.19 m/s)
    settings = PhysicsSettings(slide_speed=0.05, release_distance=None)  # hold on, whatever the target does
    tracker, _, records = track(body, q, np.ones((40, 4), bool), settings)
    soles = kin.forward_kinematics(body, np.array([r.qpos for r in records] + [tracker.qpos])).points[
        :, body.point_index(CONTACT_POINTS)]
    # Started 2 cm deep: never deeper, back on the floor after a few recovery times, and never below it again.
    assert np.all(np.diff(np.minimum(soles[:, :, 2], 0.0), axis=0) >= -1e-9)
    recovered = int(4 * settings.penetration_recovery / tracker.dt)
    assert soles[recovered:, :, 2].min() > -1e-3
    slide = np.linalg.norm(np.diff(soles[:, :, :2], axis=0), axis=-1)
    both_active = np.array([r.active for r in records])
    assert both_active.all()
    assert np.all(slide <= settings.slide_speed * tracker.dt + 1e-6)


def test_contact_released_when_the_kinematic_foot_leaves(body):
    """Contacts whose kinematic target has moved more than release_distance along the floor (a left/right swap,
    a wrong contact label) are released: they may slide faster than sigma, yet still never sink."""
    settings = PhysicsSettings()
    tracker = PhysCapTracker(body, settings, FPS)
    q = body.rest_qpos.copy()
    sliding = np.zeros(body.nv)
    sliding[0], sliding[2] = 1.0, -0.2  # the whole body moving forward at 1 m/s and down at 0.2 m/s
    tracker.reset(q, sliding)
    heights, _ = tracker._step_state()
    away = q.copy()
    away[0] += 2 * settings.release_distance
    tracker._target_kinematics(away)
    released = tracker._released_contacts(tracker.target_data.site_xpos[tracker.sites], [True] * 4)
    tracker._target_kinematics(q)
    # Back within release_distance while the target still slides (10 cm in a frame): still let go; then, the
    # target at rest, caught again.
    assert all(released) and all(tracker._released_contacts(tracker.target_data.site_xpos[tracker.sites], [True] * 4))
    assert not any(tracker._released_contacts(tracker.target_data.site_xpos[tracker.sites], [True] * 4))
    active = (True, True, True, True)
    for let_go in ([False] * 4, released):
        qdd, _, solved = tracker.pose_accelerations(np.zeros(body.nv), tracker.bias, np.zeros((4, 3)), active,
                                                    heights, let_go, heights)
        assert solved
        velocity = tracker.contact_jacobian @ (sliding + tracker.dt * qdd)  # (4, 3) after the step
        assert np.all(velocity[:, 2] >= -np.array(heights) / tracker.dt - 1e-9)  # no sinking either way
        along_floor = np.linalg.norm(velocity[:, :2], axis=1)
        if any(let_go):
            assert np.all(along_floor > 0.5)
        else:
            assert np.all(along_floor <= np.sqrt(2) * settings.slide_speed + 1e-6)


def test_the_last_support_stays_while_the_target_stands(body):
    """A standing target whose feet hover within contact_height (a fit's feet a few cm up) slides off where the
    character holds them: every contact is released. With nothing else to stand on, the points stay as supports
    that slide freely: the character neither free-falls onto the floor nor lands with a spike. A target in
    flight (needing no support) keeps none."""
    settings = PhysicsSettings()
    weight = body.mass * 9.81
    q = body.rest_qpos.copy()
    q[2] += 0.04  # the feet 4 cm up: within contact_height, not touching the floor
    tracker = PhysCapTracker(body, settings, FPS)
    tracker.reset(q, np.zeros(body.nv))
    zeros, contacts = np.zeros(body.nv), np.ones(4, bool)
    lowest, largest = q[2], 0.0
    for t in range(12):
        target = q.copy()
        target[0] += 0.02 * max(t - 2, 0)  # from the third frame on, sliding 0.5 m/s along the floor
        frame = tracker.track(target, zeros, zeros, contacts)
        lowest, largest = min(lowest, tracker.qpos[2]), max(largest, np.linalg.norm(frame.contact_forces.sum(0)))
    assert any(tracker._released) and any(tracker._supporting)
    assert q[2] - lowest < 0.01 and largest < 1.5 * weight
    tracker.needed_support = 0.0  # a target in flight
    assert not any(tracker._last_support([True] * 4, [True] * 4, [0.04] * 4))


def test_offline_label_flights_that_the_body_does_not_fall_through_are_held(body):
    """B.4's labels can leave a short whole-body flight while the motion stands (its feet hovering a few cm):
    offline, a point that stays put holds the body through it, so the character neither free-falls nor lands
    hard. A real jump keeps its flight."""
    from physmocap.dynamics.stage import offline_unexplainable

    weight = body.mass * G
    q = standing(body, 30)
    q[:, 2] += 0.03  # the feet 3 cm up: within contact_height, touching nothing
    contacts = np.ones((30, 4), bool)
    contacts[12:16] = False
    assert offline_unexplainable(body, q, FPS, contacts)[0][12:16].any(axis=1).all()
    motion = run_physcap(body, q, FPS, contacts, np.ones(30, bool), PhysicsSettings(), refined_input=True)
    assert motion.qpos[12:20, 2].min() > motion.qpos[11, 2] - 0.005  # no fall through the labels' flight
    assert np.linalg.norm(motion.grf.sum(axis=1), axis=-1).max() < 1.5 * weight
    q, in_air = jump(body)
    labels = np.repeat(~in_air[:, None], 4, axis=1)
    held, unheld = offline_unexplainable(body, q, FPS, labels)
    assert np.array_equal(held, labels) and not unheld.any()


def test_offline_label_flights_that_no_foot_can_hold_are_handed_back(body):
    """A label flight that the body does not fall through while every foot travels (here the whole body glides at
    3 m/s along the floor) has no support the contact model can give: offline, its frames are flagged and keep
    the kinematic motion with no force claimed, instead of a character free-falling through them."""
    from physmocap.dynamics.stage import offline_unexplainable

    q = standing(body, 30)
    q[:, 0] += 0.1 * np.arange(30)  # 3 m/s along the floor
    contacts = np.ones((30, 4), bool)
    contacts[12:18] = False
    held, unheld = offline_unexplainable(body, q, FPS, contacts)
    assert np.array_equal(held, contacts) and unheld[12:18].all() and unheld.sum() == 6
    motion = run_physcap(body, q, FPS, contacts, np.zeros(30, bool), PhysicsSettings(), refined_input=True)
    assert motion.unexplained[12:18].all() and not motion.grf[12:18].any() and not motion.residual[12:18].any()
    assert np.abs(motion.qpos[12:18, :3] - q[12:18, :3]).max() < 1e-9


def test_offline_frames_whose_centre_of_mass_is_below_the_floor_claim_no_force(body):
    """A person leaving the picture, fitted half a metre into the floor (intel's last frames): no contact force
    can explain that, so offline such frames keep the kinematic motion, flagged, without forces (as trajopt);
    tracked, the floor pushed the character out at the force bound."""
    from physmocap.dynamics.stage import offline_unexplainable

    q = standing(body, 40)
    q[30:35, 2] -= 0.5 + 0.2 * np.arange(5)
    contacts = np.ones((40, 4), bool)
    valid = np.ones(40, bool)
    held, sunk = offline_unexplainable(body, q, FPS, contacts, valid)
    assert np.array_equal(np.flatnonzero(sunk), np.arange(30, 35)) and not held[30:35].any()
    motion = run_physcap(body, q, FPS, contacts, np.zeros(40, bool), PhysicsSettings(), valid=valid,
                         refined_input=True)
    assert valid.all()  # the caller's frames with a person, unchanged
    assert motion.unexplained[30:35].all() and not motion.unexplained[:30].any()  # and where it jumps back up
    assert not motion.grf[30:35].any() and not motion.residual[30:35].any()
    np.testing.assert_allclose(motion.qpos[30:35], q[30:35], atol=1e-9)
    weight = body.mass * G
    assert np.linalg.norm(motion.grf.sum(axis=1), axis=-1).max() < 2 * weight


def test_a_causal_run_does_not_track_a_centre_of_mass_below_the_floor(body):
    """Online and live, the same frames are found as they arrive: each keeps its target, flagged, with no force,
    and the character starts afresh at the next frame instead of being pushed out of the floor."""
    q = standing(body, 40)
    q[30:35, 2] -= 1.0 + 0.2 * np.arange(5)  # the whole body under the floor
    motion = run_physcap(body, q, FPS, np.ones((40, 4), bool), np.zeros(40, bool), PhysicsSettings())
    assert motion.unexplained[30:35].all()
    assert not motion.grf[30:35].any() and not motion.residual[30:35].any()
    np.testing.assert_allclose(motion.qpos[30:35], q[30:35], atol=1e-9)
    assert np.linalg.norm(motion.grf.sum(axis=1), axis=-1).max() < 2 * body.mass * G


def test_a_held_contact_above_its_target_comes_down_to_it(body):
    """The floor only stops a contact point from sinking; a point in use that hovers above its kinematic target
    must also come down to it (within contact_settle_time), or a foot held in the air takes the contact forces
    and the body rides up on it. A point below its target is left free."""
    settings = PhysicsSettings()
    tracker = PhysCapTracker(body, settings, FPS)
    q = body.rest_qpos.copy()
    q[2] += 0.02  # the character 2 cm above its target, which stands on the floor
    tracker.reset(q, np.zeros(body.nv))
    heights, _ = tracker._step_state()
    targets = [height - 0.02 for height in heights]
    active, held = (True, True, True, True), [False] * 4
    qdd, _, solved = tracker.pose_accelerations(np.zeros(body.nv), tracker.bias, np.zeros((4, 3)), active, heights,
                                                held, targets)
    assert solved
    normal_velocity = (tracker.contact_jacobian @ (tracker.dt * qdd))[:, 2]
    goal = np.maximum(targets, settings.floor_clearance)
    assert np.all(normal_velocity <= (goal - np.array(heights)) / settings.contact_settle_time + 1e-9)
    free = [tracker.pose_accelerations(np.zeros(body.nv), tracker.bias, np.zeros((4, 3)), active, heights, held,
                                       [height + above for height in heights])[0] for above in (0.01, 10.0)]
    assert np.allclose(free[0], free[1])


def _on_tilted_floor(body, frames, degrees):
    """Standing poses sliding along a winding path on a floor tilted by `degrees` about the world x axis (the
    whole body moved rigidly, so the soles trace the tilted floor). Returns poses and the floor's normal."""
    from physmocap.body.rotations import axis_angle_matrix

    tilt = axis_angle_matrix(np.array([1.0, 0.0, 0.0]), np.radians(degrees))
    q = standing(body, frames)
    q[:, 0] += np.sin(np.linspace(0.0, 2 * np.pi, frames))  # a winding walk: the feet cover 2 x 2 m of floor
    q[:, 1] += np.linspace(0.0, 2.0, frames)
    return rigid_transform_qpos(q, tilt, np.zeros(3)), tilt @ np.array([0.0, 0.0, 1.0])


def test_floor_refiner_finds_a_tilted_floor_and_turns_gently(body):
    from physmocap.dynamics.floor import FloorRefiner

    q, normal = _on_tilted_floor(body, 200, 3.0)
    refiner = FloorRefiner(body, FPS, refit_interval=0.5, tilt_rate=np.radians(1.0), lift_rate=0.05,
                           first_refit=1.0)
    turns = []
    for pose in q:
        before = refiner.normal.copy()
        refiner.push(pose, np.ones(4, bool))
        turns.append(np.arccos(np.clip(before @ refiner.normal, -1, 1)))
    assert np.degrees(np.arccos(refiner.normal @ normal)) < 0.3  # of 3: the prior towards the warm-up floor
    assert max(turns) <= np.radians(1.0) / FPS + 1e-9
    # The maps: the floor goes to z = 0 in the physics frame, and back.
    soles = kin.forward_kinematics(body, refiner.to_physics(q[-1])[None]).points[0, body.point_index(CONTACT_POINTS)]
    assert np.abs(soles[:, 2]).max() < 0.01
    assert np.allclose(refiner.to_kinematic(refiner.to_physics(q[-1])), q[-1])
    assert np.allclose(refiner.vector_to_kinematic(np.array([0.0, 0.0, 1.0])), refiner.normal)


def test_floor_refiner_puts_the_floor_under_the_feet_not_through_them(body):
    """A fit whose feet rest on the floor in two frames of three and 1.5 cm above it in the third (within the
    robust fit's quadratic zone, as a fit's noise is): the refit lays the floor under each frame's lowest point
    (their median), not through the middle of all points, 5 mm up, where the character, whose feet cannot sink,
    would stand above its input."""
    from physmocap.dynamics.floor import FloorRefiner

    q, _ = _on_tilted_floor(body, 90, 0.0)  # a level floor, the feet winding over 2 x 2 m
    q[1::3, 2] += 0.015
    q[:, 2] += np.random.default_rng(0).normal(0.0, 0.001, len(q))  # a fit's millimetre of noise
    refiner = FloorRefiner(body, FPS, refit_interval=1.0, tilt_rate=1.0, lift_rate=1.0, first_refit=1.0)
    for pose in q:
        refiner.push(pose, np.ones(4, bool))
    points = kin.forward_kinematics(body, q[::3]).points[:, body.point_index(CONTACT_POINTS)]  # on the floor
    assert abs(np.median(points @ refiner.fitted_normal + refiner.fitted_offset)) < 0.002  # through them: 5 mm


def test_online_physics_keeps_the_feet_on_a_refined_tilted_floor(body):
    """The floor refined as frames arrive finds the tilted floor, and the character's soles stand on it. (On a
    floor held at z = 0 the soles would either leave the tilted floor or hover over their own.)"""
    q, normal = _on_tilted_floor(body, 250, 2.0)  # 10 s: refits at 3, 6 and 9 s
    contacts = np.ones((250, 4), bool)
    refined = run_physcap(body, q, FPS, contacts, np.ones(250, bool), PhysicsSettings(), refine_floor=True)
    soles = kin.forward_kinematics(body, refined.qpos[-25:]).points[:, body.point_index(CONTACT_POINTS)]
    assert refined.floor_plane is not None
    assert np.degrees(np.arccos(refined.floor_plane[:3] @ normal)) < 0.5
    assert np.abs(soles @ normal).max() < 0.005  # over the last second


def test_an_untrusted_warm_up_floor_keeps_its_tilt_and_has_its_height_refined(body):
    """A warm-up floor that was not trusted (the feet's plane leant from the posture, and the floor was levelled
    with the posture instead) is not leant towards the same feet by the online refits; its height still follows
    them. Without keep_tilt the refined floor turns the 6 degrees of the feet's plane."""
    q, normal = _on_tilted_floor(body, 250, 6.0)
    q[:, 2] += 0.03  # the feet 3 cm above the warm-up's floor
    contacts = np.ones((250, 4), bool)
    refined = run_physcap(body, q, FPS, contacts, np.ones(250, bool), PhysicsSettings(), refine_floor=True,
                          floor_trusted=False)
    leaning = run_physcap(body, q, FPS, contacts, np.ones(250, bool), PhysicsSettings(), refine_floor=True)
    assert refined.floor_plane is not None and leaning.floor_plane is not None
    assert np.allclose(refined.floor_plane[:3], [0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(leaning.floor_plane[:3] @ normal)) < 1.0
    # the last refit (at 9 s) lays the floor at the median of each frame's lowest point, frames 1-224 (a point is
    # evidence from the second frame of its contact on)
    soles = kin.forward_kinematics(body, q[1:225]).points[:, body.point_index(CONTACT_POINTS)]
    lowest = np.median(soles[..., 2].min(axis=1))
    assert abs(refined.floor_plane[3] + lowest) < 0.002  # the plane z = lowest: n . x + d = 0 with d = -lowest


def test_resting_contacts_do_not_dip_under_the_floor_while_the_feet_roll(body):
    """Feet pitching and rolling while all four points are in contact never take a point under the floor."""
    names = [b.joint for b in body.bodies]
    roll = np.zeros((60, body.nv))
    for ankle in ("left_ankle", "right_ankle"):  # both feet pitch and roll slowly back and forth
        dof = body.dof_address[names.index(ankle)]
        roll[:, dof:dof + 2] = 0.25 * np.sin(np.arange(60) / 5.0)[:, None]
    q = kin.integrate(body, standing(body, 60), roll)
    _, _, records = track(body, q, np.ones((60, 4), bool))
    soles = kin.forward_kinematics(body, np.array([r.qpos for r in records])).points[
        :, body.point_index(CONTACT_POINTS)]
    assert soles[:, :, 2].min() >= 0.0


def test_a_joint_flipping_between_frames_is_followed_gently_without_fallbacks(body):
    """A fit that flips a wrist back and forth each frame (seen on real video) asks the PD for accelerations far
    beyond any human motion; the tracker bounds them instead of diverging and restarting."""
    names = [b.joint for b in body.bodies]
    flip = np.zeros((50, body.nv))
    dof = body.dof_address[names.index("left_wrist")]
    flip[:, dof] = 1.2 * (-1.0) ** np.arange(50)  # +-1.2 rad about one axis, alternating every frame
    q = kin.integrate(body, standing(body, 50), flip)
    _, frames, records = track(body, q, np.ones((50, 4), bool))
    assert sum(f.qp_failures for f in frames) == 0
    from physmocap.dynamics.physcap import MAX_DESIRED_ACCELERATION

    assert max(np.abs(r.qacc[dof]).max() for r in records) <= 1.01 * MAX_DESIRED_ACCELERATION


def test_the_result_world_moves_onto_the_refined_floor_and_the_camera_follows(body):
    from physmocap.camera import Camera, Floor, floor_in_camera, world_from_floor
    from physmocap.dynamics.stage import onto_refined_floor
    from physmocap.kinematics.stage import KinematicMotion

    q, normal = _on_tilted_floor(body, 150, 2.0)
    contacts = np.ones((150, 4), bool)
    physics = run_physcap(body, q, FPS, contacts, np.ones(150, bool), PhysicsSettings(), refine_floor=True)
    camera = Camera.from_settings((1280, 720), fov=60.0)
    camera = camera.with_extrinsics(*world_from_floor(Floor(np.array([0.0, -1.0, 0.0]), 1.2), np.array([0, 0, 4.0])))
    floor = Floor.from_plane(floor_in_camera(camera.R, camera.t))  # the kinematic world's z = 0
    motion = KinematicMotion(body, None, camera, floor, q, np.zeros(150), np.ones(150, bool), 0.0, True)
    moved, moved_physics = onto_refined_floor(motion, physics)

    def points(m, qpos):
        return m.camera.to_camera(kin.forward_kinematics(body, qpos).points)

    # The same motion seen by the camera; the soles now rest on z = 0, and the floor in the camera frame with them.
    assert np.allclose(points(moved, moved.qpos), points(motion, q), atol=1e-9)
    assert np.allclose(points(moved, moved_physics.qpos), points(motion, physics.qpos), atol=1e-9)
    soles = kin.forward_kinematics(body, moved_physics.qpos[-25:]).points[:, body.point_index(CONTACT_POINTS)]
    assert np.abs(soles[..., 2]).max() < 0.01
    camera_soles = moved.camera.to_camera(soles)
    assert np.allclose(moved.floor.height(camera_soles), soles[..., 2], atol=1e-9)
    assert moved_physics.floor_plane is None
    assert np.allclose(moved_physics.grf.sum(1)[-1] @ np.array([0, 0, 1.0]),
                       physics.grf.sum(1)[-1] @ physics.floor_plane[:3], atol=1e-6)


def test_the_character_starts_at_the_first_frame_with_a_person(body):
    # A whole-clip fit extrapolates the frames before the person appears, here half a metre under the floor;
    # started there, the character would be launched out of the floor.
    q = standing(body, 40)
    q[:5, 2] -= np.linspace(0.5, 0.1, 5)
    valid = np.arange(40) >= 5
    result = run_physcap(body, q, FPS, np.ones((40, 4), bool), np.ones(40, bool), PhysicsSettings(), valid=valid)
    np.testing.assert_array_equal(result.qpos[:5], q[:5])  # kept, without forces
    assert not result.unexplained.any()  # nobody to explain before the person appears
    assert not result.grf[:5].any() and not result.residual[:5].any()
    weight = body.mass * G
    assert np.all(np.abs(result.grf[10:, :, 2].sum(axis=1) - weight) < 0.05 * weight)
    assert np.abs(result.qpos[5:, 2] - q[5:, 2]).max() < 0.01  # no launch
    launched = run_physcap(body, q, FPS, np.ones((40, 4), bool), np.ones(40, bool), PhysicsSettings())
    assert np.abs(launched.qpos[5:, 2] - q[5:, 2]).max() > 0.05  # what starting on the extrapolated frames does


def test_a_lone_valid_frame_does_not_start_the_character(body):
    """A person glimpsed for one frame before entering: the step from that frame to the next, extrapolated by the
    fit, is no observed velocity. Knowing the whole clip, the character starts at the first two valid frames in a
    row, as intel's walk into the picture (10 fps) needs: started on the lone frame, it took 3 m/s it never had.
    A causal run cannot know that the next frame will be missing, and starts on the lone frame."""
    q = standing(body, 40)
    q[:5, 0] -= 0.1 * np.arange(5, 0, -1)  # the extrapolated approach, 3 m/s
    valid = np.arange(40) >= 5
    valid[3] = True
    args = (body, q, FPS, np.ones((40, 4), bool), np.ones(40, bool), PhysicsSettings())
    result = run_physcap(*args, valid=valid, whole_clip=True)
    np.testing.assert_allclose(result.qpos[:5], q[:5], atol=1e-5)  # kept (the held feet's planting blends in)
    # the glimpsed person is flagged, as physics does not explain it; the frames without one are not
    np.testing.assert_array_equal(np.flatnonzero(result.unexplained), [3])
    assert np.abs(result.qpos[5:, :3] - q[5:, :3]).max() < 0.01
    glimpsed = valid.copy()
    glimpsed[4] = True  # the lone frame's step observed: the character does start there, moving
    assert np.abs(run_physcap(*args, valid=glimpsed, whole_clip=True).qpos[5:, 0] - q[5:, 0]).max() > 0.02
    assert np.abs(run_physcap(*args, valid=valid).qpos[5:, 0] - q[5:, 0]).max() > 0.02  # causal


def test_a_causal_run_starts_afresh_where_the_person_is_seen_again_far_away(body):
    """Causally, the frames without a person hold the fit's extrapolation, and the person seen again can be a metre
    away (intel online: 1 m between frames 15 and 17). Tracked through, the character was pulled after the jump with
    the force bound's 10 body weights; started afresh there (PhysicsStream.resume: farther than stray_distance), as
    at the clip's start, it stands on its feet. Seen again where the character is, it is tracked on."""
    q = standing(body, 40)
    q[20:, 0] += 1.0  # the person seen again a metre from the fit's extrapolation
    valid = np.ones(40, bool)
    valid[17:20] = False
    args = (body, q, FPS, np.ones((40, 4), bool), np.ones(40, bool), PhysicsSettings())
    result = run_physcap(*args, valid=valid)
    weight = body.mass * G
    assert np.linalg.norm(result.grf.sum(axis=1), axis=-1).max() < 1.5 * weight
    assert np.abs(result.qpos[20:, :3] - q[20:, :3]).max() < 0.01
    assert not result.unexplained[20:].any()
    near = q.copy()
    near[20:, 0] -= 0.9  # 10 cm from the extrapolation: tracked on, as without the gap
    args = (body, near, FPS, np.ones((40, 4), bool), np.ones(40, bool), PhysicsSettings())
    np.testing.assert_array_equal(run_physcap(*args, valid=valid).qpos, run_physcap(*args).qpos)


@pytest.mark.parametrize("fps", [10.0, 30.0, 120.0])
def test_offline_forces_are_the_forces_at_the_frames_instant(body, fps):
    """Offline, a frame's net vertical force (contacts and residual) is m (z'' + g) of the character's own centre
    of mass at that frame by central differences two frames apart, at any frame rate. Before, the interval ending
    at the frame lagged by half a frame, and the mean of the intervals on either side still by a third of one
    (0.117 / 0.036 / 0.015 body weights RMS from the same figure on this squat at 10 / 30 / 120 fps): the
    character takes up each change of the target's chord just after the frame."""
    frames = int(4 * fps)
    physics = run_physcap(body, squat(body, frames, fps, period=1.0), fps, np.ones((frames, 4), bool),
                          np.zeros(frames, bool), PhysicsSettings(), refined_input=True)
    assert not physics.unexplained.any()
    height = kin.center_of_mass(body, kin.forward_kinematics(body, physics.qpos))[:, 2]
    implied = (height[4:] - 2 * height[2:-2] + height[:-4]) * (fps / 2) ** 2 / G + 1.0  # frames 2 .. T - 3
    vertical = (physics.grf[..., 2].sum(axis=1) + physics.residual[:, 2])[2:-2] / (body.mass * G)
    error = (vertical - implied)[2:-2]
    assert np.sqrt(np.mean(error**2)) < 0.005


def test_forces_at_frames_read_the_bend_at_each_frame_and_its_neighbours():
    """A frame bends the path by its share of the interval ending at it plus its share of the next one (the
    tracker's shares where it split the interval, else the interval's force by the steps' weights: (n + 1) / 2n to
    the interval's start frame); its force is 1/4, 1/2, 1/4 of the bends at the frame before, itself and the frame
    after, a missing neighbour's counted as its own, and so is one supported where the frame is not, or the other way
    round. A frame whose next interval claims nothing (the clip's end, a frame without a person) keeps its own
    interval's."""
    n = 4
    intervals = np.arange(7.0)  # the force over each interval ending at frames 0-6
    grf = np.zeros((7, 4, 3))
    grf[:, 1, 2] = intervals
    residual = np.repeat(intervals[:, None], 6, axis=1)
    claimed = np.array([True, True, True, True, False, True, True])
    shares = [None] * 7
    split = np.zeros((4, 3))
    split[0, 2] = 8.0
    shares[2] = ((split, np.zeros(6)), (2 * split, np.ones(6)))  # the interval ending at frame 2
    supported = np.ones(7, bool)
    at_frames, residual_at_frames = forces_at_frames(grf, residual, claimed, supported, shares, n)
    start, end = 5 / 8, 3 / 8
    bend = {0: end * 0 + start * 1, 1: end * 1, 2: start * 3}  # on point 1; point 0 takes 8 at 1 and 16 at 2
    assert np.allclose(at_frames[[0, 1, 2], 1, 2], [0.75 * bend[0] + 0.25 * bend[1],
                                                    0.25 * bend[0] + 0.5 * bend[1] + 0.25 * bend[2],
                                                    0.25 * bend[1] + 0.75 * bend[2]])
    assert np.allclose(at_frames[[0, 1, 2], 0, 2], [0.25 * 8, 0.5 * 8 + 0.25 * 16, 0.25 * 8 + 0.75 * 16])
    assert np.allclose(at_frames[5, 1, 2], end * 5 + start * 6)  # its only neighbour with a bend: none
    assert np.allclose(at_frames[[3, 4, 6], 1, 2], intervals[[3, 4, 6]])
    assert np.allclose(residual_at_frames[2], 0.25 * (end * 1 + 0.0) + 0.75 * (1.0 + start * 3))
    assert np.array_equal(grf[:, 1, 2], intervals)  # the inputs are left as they were
    supported[2] = False  # frame 2 in the air: its bend and frame 1's stay apart
    at_frames, _ = forces_at_frames(grf, residual, claimed, supported, shares, n)
    assert np.allclose(at_frames[[1, 2], 1, 2], [0.25 * bend[0] + 0.75 * bend[1], bend[2]])


def test_frames_without_a_person_carry_no_contacts_or_forces(body):
    """A person lost for a few frames mid-clip (the fit extrapolates them, the labels still say planted): the
    character is tracked through as before, but those frames claim no contact and no force; the flags stay."""
    q = standing(body, 40)
    valid = np.ones(40, bool)
    valid[15:22] = False
    args = (body, q, FPS, np.ones((40, 4), bool), np.ones(40, bool), PhysicsSettings())
    result, everywhere = run_physcap(*args, valid=valid), run_physcap(*args)
    assert everywhere.grf[~valid].any() and everywhere.contacts[~valid].any()  # what was written before
    assert not result.grf[~valid].any() and not result.residual[~valid].any() and not result.contacts[~valid].any()
    np.testing.assert_array_equal(result.qpos, everywhere.qpos)
    # the forces at a frame's instant read the intervals either side of it: the gap's neighbours read no bend there
    far = valid & ~np.convolve(~valid, np.ones(5), mode="same").astype(bool)
    np.testing.assert_array_equal(result.grf[far], everywhere.grf[far])
    np.testing.assert_array_equal(result.unexplained, everywhere.unexplained)


def test_physics_smooths_a_jittery_target_instead_of_passing_the_jitter_on(body):
    """Standing still with pose noise of a few centimetres: the character's joints shake less than the target's
    (the smoothed kinematic velocity keeps the derivative term from feeding frame-to-frame noise through)."""
    rng = np.random.default_rng(3)
    q = standing(body, 80)
    model = body.mujoco_model()
    for pose in q:  # rad on every joint, about 3 cm at the end of a limb; 1 cm on the root
        mujoco.mj_integratePos(model, pose, np.r_[rng.normal(0.0, 0.01, 3), np.zeros(3),
                                                 rng.normal(0.0, 0.03, body.nv - 6)], 1.0)
    contacts = np.ones((len(q), 4), bool)

    def shake(qpos):  # mean joint acceleration, m/s^2
        points = kin.forward_kinematics(body, qpos).points
        return np.linalg.norm(np.diff(points, 2, axis=0), axis=-1).mean() * FPS ** 2

    smoothed = run_physcap(body, q, FPS, contacts, np.zeros(len(q), bool), PhysicsSettings())
    plain = run_physcap(body, q, FPS, contacts, np.zeros(len(q), bool), PhysicsSettings(velocity_smoothing=0.0))
    assert shake(smoothed.qpos[10:]) < 0.8 * shake(q[10:])
    assert shake(smoothed.qpos[10:]) < shake(plain.qpos[10:])
    full_velocity = run_physcap(body, q, FPS, contacts, np.zeros(len(q), bool),
                                PhysicsSettings(rotation_velocity_share=1.0))
    assert shake(smoothed.qpos[10:]) < shake(full_velocity.qpos[10:])


def test_the_whole_clips_velocity_is_smoothed_without_lag_and_not_across_a_restart(body):
    """B.4 input (whole clip): the kinematic velocity is smoothed forward and backward, so a sway's velocity peaks
    where its backward differences peak (the causal filter's peak comes later), a steady velocity is kept as it
    is, and a jump in an untracked frame does not leak into the runs either side of it."""
    fps, T = 30.0, 90
    times = np.arange(T) / fps
    q = standing(body, T)
    q[:, 0] = 0.1 * np.sin(2 * np.pi * 1.5 * times)  # m: a 1.5 Hz sideways sway of the root
    tracked = np.ones(T, bool)
    backward, _ = kinematic_derivatives(body, q, fps)
    smoothed = zero_phase_velocities(body, q, fps, 0.03, tracked)
    share = 1.0 - np.exp(-1.0 / (fps * 0.03))
    causal = backward.copy()
    for t in range(2, T):
        causal[t] = share * backward[t] + (1.0 - share) * causal[t - 1]
    middle = slice(20, 80)  # three whole periods

    def delay(velocity):  # s: the phase of the sway's velocity, as a delay
        wave = 2 * np.pi * 1.5 * times[middle]
        return -np.arctan2(velocity[middle, 0] @ -np.sin(wave), velocity[middle, 0] @ np.cos(wave)) / (2 * np.pi * 1.5)

    assert abs(delay(smoothed) - delay(backward)) < 1e-3
    assert delay(causal) - delay(backward) > 0.01  # about (1 - share) / share frames
    assert np.abs(smoothed[middle, 0]).max() > 0.9 * np.abs(backward[middle, 0]).max()
    steady = standing(body, 30)
    steady[:, 1] = np.arange(30) * 0.04  # 1.2 m/s forwards
    np.testing.assert_allclose(zero_phase_velocities(body, steady, fps, 0.03, np.ones(30, bool))[1:, 1], 1.2,
                               atol=1e-9)
    jumped = q.copy()
    jumped[45, 0] += 0.5  # m: one untracked frame far off
    tracked[45] = False
    split = zero_phase_velocities(body, jumped, fps, 0.03, tracked)
    alone = [zero_phase_velocities(body, part, fps, 0.03, np.ones(len(part), bool))
             for part in (jumped[:45], jumped[46:])]
    np.testing.assert_allclose(split[1:45], alone[0][1:], atol=1e-12)
    np.testing.assert_allclose(split[47:], alone[1][1:], atol=1e-12)


def test_the_fed_forward_acceleration_brings_the_damped_velocity_onto_the_chord_by_the_frames_end(body):
    """Eq. (4)'s feed-forward share per DOF, x / (e^x - 1) with x = kd / fps: the damped velocity
    v' = f a + kd (v_chord - v), starting a frame interval T behind the new chord's velocity (v_chord - a T),
    reaches it at the interval's end; the paper's full share as frames get dense, almost none for the stiff joints at
    10 fps, whose damping alone gets there."""
    settings = PhysicsSettings()
    assert np.allclose(PhysCapTracker(body, settings, 1e5).feedforward, settings.acceleration_feedforward, rtol=1e-3)
    for fps in (10.0, 30.0, 60.0):
        tracker = PhysCapTracker(body, settings, fps)
        share, kd, interval, acceleration = tracker.feedforward, tracker.kd, 1.0 / fps, 3.0
        velocity = np.full(body.nv, -acceleration * interval)  # the chord's velocity is 0
        steps = 20000
        for _ in range(steps):
            velocity += interval / steps * (share * acceleration - kd * velocity)
        assert np.abs(velocity).max() < 1e-3 * acceleration * interval, fps
    assert PhysCapTracker(body, settings, 10.0).feedforward[6:].max() < 0.01


def test_the_derivative_term_tracks_a_share_of_the_rotational_velocity_and_all_of_the_translation(body):
    """Eq. (4) with rotation_velocity_share s: kd (s qd_kin - qd) on the root's orientation and the joints,
    kd (qd_kin - qd) on the root's translation (its own kd horizontally)."""
    share = 0.25
    settings = PhysicsSettings(rotation_velocity_share=share, acceleration_feedforward=0.0)
    tracker = PhysCapTracker(body, settings, FPS)
    rng = np.random.default_rng(5)
    qvel, qd_kin = rng.normal(0.0, 0.2, body.nv), rng.normal(0.0, 0.2, body.nv)
    tracker.reset(body.rest_qpos, qvel)
    desired = tracker.desired_acceleration(body.rest_qpos, qd_kin, np.zeros(body.nv))
    np.testing.assert_allclose(desired[:2], settings.kd_root_horizontal * (qd_kin[:2] - qvel[:2]), atol=1e-9)
    np.testing.assert_allclose(desired[2], settings.kd_root_translation * (qd_kin[2] - qvel[2]), atol=1e-9)
    np.testing.assert_allclose(desired[3:6], settings.kd_root_rotation * (share * qd_kin[3:6] - qvel[3:6]), atol=1e-9)
    np.testing.assert_allclose(desired[6:], settings.kd_joint * (share * qd_kin[6:] - qvel[6:]), atol=1e-9)


def test_offline_on_b4_input_the_joints_track_with_their_own_stiffer_gains(body):
    settings = PhysicsSettings()
    assert PhysicsStream(body, settings, FPS).tracker.kp[6] == settings.kp_joint  # online: a noisy fit's gains
    offline = PhysicsStream(body, settings, FPS, refined_input=True).tracker
    assert (offline.kp[6], offline.kd[6]) == (settings.kp_joint_refined, settings.kd_joint_refined)
    frames = 60
    q = squat(body, frames, FPS, period=0.8)
    errors = []
    for gains in (settings, PhysicsSettings(kp_joint_refined=None, kd_joint_refined=None)):
        motion = run_physcap(body, q, FPS, np.ones((frames, 4), bool), np.zeros(frames, bool), gains,
                             refined_input=True)
        knee = body.qpos_address[body.joint_index["left_knee"]]  # a hinge: one coordinate, radians
        errors.append(np.abs(motion.qpos[10:, knee] - q[10:, knee]).mean())
    assert errors[0] < 0.9 * errors[1]  # lag of the velocity share, (1 - share) kd / kp: 3/4 of the online gains'


def test_a_root_shaken_sideways_by_fit_noise_gets_smaller_horizontal_forces_than_the_stiff_root_gave(body):
    """kp_root_horizontal: a target whose root jumps 1 cm sideways from frame to frame (a fit's noise) is followed
    less, so the horizontal contact forces that would carry the shake are smaller than with the stiff root's gains
    (kp_root_translation), and the character shakes less."""
    frames = 60
    q = standing(body, frames)
    q[:, 0] += 0.01 * (-1.0) ** np.arange(frames)
    contacts = np.ones((frames, 4), bool)
    force, sway = {}, {}
    for stiff in (False, True):
        settings = PhysicsSettings(kp_root_horizontal=None, kd_root_horizontal=None) if stiff else PhysicsSettings()
        tracker, outputs, records = track(body, q, contacts, settings)
        force[stiff] = np.abs(np.array([f.contact_forces.sum(axis=0)[0] for f in outputs[10:]])).mean()
        sway[stiff] = np.ptp([r.qpos[0] for r in records[len(records) // 2:]])
    assert force[False] < 0.75 * force[True] and sway[False] < sway[True]


def test_the_qp_workspace_returns_what_daqp_solve_returns_bit_for_bit():
    """DenseQP calls daqp's C solver on its own buffers with daqp.solve's defaults: the same solutions and exit
    flags on the tracker's problem sizes, feasible and infeasible, with and without rows, and its buffers unchanged
    (a daqp whose structures or defaults differ from those DenseQP declares fails here)."""
    import daqp

    rng = np.random.default_rng(3)
    flags = set()
    for trial in range(400):
        n = int(rng.choice([3, 6, 9, 12, 40]))
        rows = int(rng.integers(0, 13))
        B = rng.normal(size=(n, n))
        H = B @ B.T + (1e-4 if trial % 2 else 1.0) * np.eye(n)
        f, A = 10 * rng.normal(size=n), rng.normal(size=(rows, n))
        lower = rng.normal(size=rows) - 1.0
        upper = lower + rng.uniform(-1.0 if trial % 4 == 0 else 0.0, 2.0, size=rows)  # some rows infeasible
        qp = DenseQP(n, 12)
        qp.H[:], qp.f[:], qp.A[:rows], qp.upper[:rows], qp.lower[:rows] = H, f, A, upper, lower
        buffers = [b.copy() for b in (qp.H, qp.f, qp.A, qp.upper, qp.lower)]
        x, exitflag = qp.solve(rows)
        expected, _, expected_flag, _ = daqp.solve(H, f, A, upper, lower)
        flags.add(exitflag)
        assert exitflag == expected_flag
        if exitflag == 1:
            assert np.array_equal(x, expected)
        assert all(np.array_equal(a, b) for a, b in zip(buffers, (qp.H, qp.f, qp.A, qp.upper, qp.lower), strict=True))
    assert 1 in flags and len(flags) > 1  # solved and infeasible problems both seen


def test_a_non_finite_target_restarts_the_character_instead_of_integrating_it(body):
    """Accelerations that are not finite (here from a target with a NaN joint) are never integrated: the step
    counts as a fallback and the character restarts from the target (the stage then flags the frame)."""
    tracker = PhysCapTracker(body, PhysicsSettings(), FPS)
    tracker.reset(body.rest_qpos, np.zeros(body.nv))
    target = body.rest_qpos.copy()
    target[7] = np.nan
    frame = tracker.track(target, np.zeros(body.nv), np.zeros(body.nv), np.ones(4, bool))
    assert frame.diverged and frame.qp_failures >= tracker.substeps
    assert np.isfinite(frame.contact_forces).all() and np.isfinite(frame.residual).all()


def test_an_online_foot_stays_planted_while_its_fitted_foot_wanders(body):
    """Online (a fit not refined by B.4), the fitted left foot wanders about 2 cm from frame to frame while it
    is predicted in contact: the character's held points stay planted (the target's foot is moved onto them)
    instead of being dragged after the fitted foot at slide_speed."""
    rng = np.random.default_rng(0)
    frames = 75
    names = [b.joint for b in body.bodies]
    hip = body.dof_address[names.index("left_hip")]
    wander = np.zeros((frames, body.nv))
    wander[:, hip:hip + 2] = rng.uniform(-0.02, 0.02, (frames, 2))  # rad: about 2 cm at the sole, each frame
    q = kin.integrate(body, standing(body, frames), wander)
    contacts = np.ones((frames, 4), bool)

    def left_sole_slides(qpos):  # m per frame along the floor, after the first 5 frames
        soles = kin.forward_kinematics(body, qpos[5:]).points[:, body.point_index(CONTACT_POINTS[:2])]
        return np.linalg.norm(np.diff(soles[:, :, :2], axis=0), axis=-1)

    motion = run_physcap(body, q, FPS, contacts, np.zeros(frames, bool), PhysicsSettings())
    assert motion.contacts[5:, :2].all()
    assert np.median(left_sole_slides(motion.qpos)) < 0.25 * np.median(left_sole_slides(q))
    assert left_sole_slides(motion.qpos).max() < 0.01  # below slide_speed's 1.2 cm per frame
    # Without planting, as offline on B.4's feet, the held points follow the fitted foot.
    unplanted = run_physcap(body, q, FPS, contacts, np.zeros(frames, bool),
                            PhysicsSettings(plant_time=None, plant_reach=None))
    assert np.median(left_sole_slides(unplanted.qpos)) > 0.4 * np.median(left_sole_slides(q))
    zero = run_physcap(body, q, FPS, contacts, np.zeros(frames, bool),
                       PhysicsSettings(plant_time=None, plant_reach=0.0))
    assert np.array_equal(zero.qpos, unplanted.qpos)  # a reach of 0 (what a TOML file can say) is off too
    # The output's own planting (plant_reach, causal online) alone holds the output's feet still.
    output_only = run_physcap(body, q, FPS, contacts, np.zeros(frames, bool), PhysicsSettings(plant_time=None))
    assert np.median(left_sole_slides(output_only.qpos)) < 0.1 * np.median(left_sole_slides(unplanted.qpos))


def test_the_base_of_support_is_the_soles_of_the_feet_that_touch(body):
    """A person standing upright and still whose labels name only the two heels (a line behind the centre of
    mass) is balanced on both soles and is not corrected; the soles of a foot count whichever of its points
    touches."""
    from physmocap.dynamics.balance import sole_support

    assert sole_support(np.array([True, False, False, True])).all()
    assert sole_support(np.array([False, False, True, False])).tolist() == [False, False, True, True]
    upright, _ = upright_and_leaning(body)
    corrector = BalanceCorrector(body)
    for _ in range(int(FPS)):
        q, corrected = corrector.correct(upright, True, np.array([True, False, True, False]))
    assert not corrected and np.array_equal(q, upright)


def test_online_feet_resting_on_the_floor_count_though_no_contact_was_predicted(body):
    """A person leaning still on the toes of both feet whose network saw only the right toe: online (a fit not
    refined by B.4) the sole points resting on the floor count as contacts, the person stands on both feet and the
    balance correction (which needs both feet down) brings the lean back; with rest_height None, after B.4 (which
    adds resting points itself) or with contacts that hold them already (resting_labelled: a retargeted
    capture's), the right toe alone is the support and nothing is corrected. Points gliding over the floor faster
    than slide_speed do not rest."""
    q = standing(body, 50)
    leaning = np.repeat(upright_and_leaning(body)[1][None], 50, axis=0)
    right_toe = np.repeat(np.array([[False, False, False, True]]), 50, axis=0)
    stationary = np.ones(50, bool)
    assert run_physcap(body, leaning, FPS, right_toe, stationary, PhysicsSettings()).corrected[-10:].all()
    assert not run_physcap(body, leaning, FPS, right_toe, stationary,
                           PhysicsSettings(rest_height=None)).corrected.any()
    for given in ({"refined_input": True}, {"resting_labelled": True}):  # B.4's labels; a retargeted capture's
        assert not run_physcap(body, leaning, FPS, right_toe, stationary, PhysicsSettings(), **given).corrected.any()
    for speed, resting in ((0.0, True), (1.0, False)):  # m/s along the floor
        stream = PhysicsStream(body, PhysicsSettings(), FPS)
        moved = q[:5].copy()
        moved[:, 0] += speed * np.arange(5) / FPS
        assert [stream._resting(pose).all() for pose in moved][1:] == [resting] * 4


def test_a_lone_frames_contacts_are_no_evidence_of_the_floor(body):
    """FloorRefiner takes a contact point as floor evidence from the second frame of its contact on: frames in
    contact one at a time, 0.5 m above the floor (a lone detection between frames without a person), never
    move the floor; the same frames held in contact do."""
    from physmocap.dynamics.floor import FloorRefiner

    raised = standing(body, 1)[0].copy()
    raised[2] += 0.5
    offsets = []
    for alternating in (True, False):
        refiner = FloorRefiner(body, FPS, refit_interval=0.5, tilt_rate=np.radians(1.0), lift_rate=1.0,
                               first_refit=1.0)
        for t in range(100):
            refiner.push(raised, np.full(4, t % 2 == 0 or not alternating))
        offsets.append(refiner.offset)
    assert offsets[0] == 0.0 and abs(offsets[1] + 0.5) < 0.05


def test_a_causal_run_writes_each_frames_force_at_its_instant(body):
    """Online the character moves causally, but its written forces are read once every frame is tracked, from the
    intervals either side of each frame (forces_at_frames): a whole body bobbing 4 cm at 1.5 Hz gets the vertical
    force its own path reads by central differences. The interval before each frame alone, as handed out live,
    followed that path no better than a constant body weight does (0.28 against 0.27 body weights, RMS)."""
    frames = 75
    q = standing(body, frames)
    q[:, 2] += 0.04 * np.sin(2 * np.pi * 1.5 * np.arange(frames) / FPS)
    motion = run_physcap(body, q, FPS, np.ones((frames, 4), bool), np.zeros(frames, bool), PhysicsSettings())
    assert not motion.unexplained.any()
    com = kin.center_of_mass(body, kin.forward_kinematics(body, motion.qpos))[:, 2]
    weight = body.mass * G
    path = body.mass * ((com[2:] - 2 * com[1:-1] + com[:-2]) * FPS**2 + G) / weight  # frames 1 .. T-2
    written = (motion.grf[1:-1, :, 2].sum(axis=1) + motion.residual[1:-1, 2]) / weight
    inner = slice(4, -4)
    error = np.sqrt(np.mean((written - path)[inner] ** 2))
    assert error < 0.6 * np.sqrt(np.mean((1.0 - path[inner]) ** 2)), error
