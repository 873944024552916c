import mujoco
import numpy as np

from conftest import random_poses
from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, JOINT_NAMES, build_body_model, template_lengths


def test_total_mass_equals_given_mass():
    for mass in (45.0, 70.0, 112.5):
        body = build_body_model(template_lengths(1.6), mass)
        assert abs(sum(b.mass for b in body.bodies) - mass) < 1e-9
        assert abs(body.mujoco_model().body_mass.sum() - mass) < 1e-9


def test_degrees_of_freedom_and_points(body):
    assert body.nv == 40 and body.nq == 51
    assert body.point_names[:len(JOINT_NAMES)] == JOINT_NAMES
    assert all(name in body.point_names for name in CONTACT_POINTS)
    assert abs(body.height - 1.75) < 1e-9


def test_rest_pose_stands_on_the_floor_and_com_is_at_hip_height(body):
    pose = kin.forward_kinematics(body, body.rest_qpos)
    soles = pose.points[0, body.point_index(CONTACT_POINTS)]
    assert np.allclose(soles[:, 2], 0.0, atol=1e-12)
    com = kin.center_of_mass(body, pose)[0]
    # Standing adults have their centre of mass at about 55% of their height.
    assert 0.50 * body.height < com[2] < 0.60 * body.height


def test_mass_matrix_symmetric_positive_definite(body):
    m = body.mujoco_model()
    d = mujoco.MjData(m)
    for q in random_poses(body, 5, np.random.default_rng(1)):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        assert np.allclose(M, M.T, atol=1e-12)
        assert np.linalg.eigvalsh(M).min() > 0


def test_forward_kinematics_agrees_with_mujoco(body):
    m = body.mujoco_model()
    d = mujoco.MjData(m)
    q = random_poses(body, 6, np.random.default_rng(2), scale=0.8)
    pose = kin.forward_kinematics(body, q)
    for t in range(len(q)):
        d.qpos[:] = q[t]
        mujoco.mj_kinematics(m, d)
        sites = np.array([d.site(n).xpos for n in body.point_names])
        assert np.allclose(sites, pose.points[t], atol=1e-10)
        assert np.allclose(d.xmat[1:].reshape(-1, 3, 3), pose.rotations[t], atol=1e-10)


def test_point_jacobian_matches_finite_differences_on_the_manifold(body):
    rng = np.random.default_rng(3)
    q = random_poses(body, 3, rng, scale=0.6)
    ids = np.arange(len(body.points))
    J = kin.point_jacobian(body, kin.forward_kinematics(body, q), ids)
    eps = 1e-6
    for k in range(body.nv):
        step = np.zeros((3, body.nv))
        step[:, k] = eps
        plus = kin.forward_kinematics(body, kin.integrate(body, q, step)).points
        minus = kin.forward_kinematics(body, kin.integrate(body, q, -step)).points
        assert np.allclose((plus - minus) / (2 * eps), J[..., k], atol=1e-7)


def test_point_jacobian_agrees_with_mujoco(body):
    m = body.mujoco_model()
    d = mujoco.MjData(m)
    q = random_poses(body, 1, np.random.default_rng(4))
    J = kin.point_jacobian(body, kin.forward_kinematics(body, q), np.arange(len(body.points)))[0]
    d.qpos[:] = q[0]
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    for i, name in enumerate(body.point_names):
        jac = np.zeros((3, m.nv))
        mujoco.mj_jacSite(m, d, jac, None, m.site(name).id)
        assert np.allclose(jac, J[i], atol=1e-12)


def test_integrate_and_difference_agree_with_mujoco(body):
    m = body.mujoco_model()
    rng = np.random.default_rng(5)
    q = random_poses(body, 4, rng)
    dv = rng.normal(scale=0.3, size=(4, body.nv))
    ours = kin.integrate(body, q, dv)
    for t in range(4):
        theirs = q[t].copy()
        mujoco.mj_integratePos(m, theirs, dv[t], 1.0)
        assert np.allclose(ours[t], theirs, atol=1e-12)
        back = np.zeros(body.nv)
        mujoco.mj_differentiatePos(m, back, 1.0, q[t], ours[t])
        assert np.allclose(back, dv[t], atol=1e-9)
    assert np.allclose(kin.difference(body, q, ours), dv, atol=1e-9)


def test_feet_collide_with_the_floor_at_the_contact_sites(body):
    m = body.mujoco_model()
    d = mujoco.MjData(m)
    d.qpos[:] = body.rest_qpos
    d.qpos[2] -= 0.005  # sink 5 mm
    mujoco.mj_forward(m, d)
    touching = {m.geom(d.contact[i].geom[1]).name for i in range(d.ncon)}
    assert touching == {f"{p}_collision" for p in CONTACT_POINTS}
    assert np.allclose(d.contact.dist[:d.ncon], -0.005, atol=1e-9)


def test_a_body_rests_off_its_feet_when_a_knee_elbow_or_the_seat_nears_the_floor():
    from physmocap.body.support import RESTING_HEIGHT, RESTING_POINTS, resting_off_feet, resting_points

    body = build_body_model(template_lengths(1.75), 72.0)
    names = body.point_names
    chosen = [names[i] for i in resting_points(names)]
    assert set(chosen) == set(RESTING_POINTS)
    assert not {"left_heel", "left_toe", "left_index", "right_wrist"} & set(chosen)  # feet and hands are not
    heights = kin.forward_kinematics(body, body.rest_qpos[None]).points[:, resting_points(names), 2]
    assert not resting_off_feet(heights).any()  # standing: the lowest such point is a knee, ~0.5 m up
    knee = chosen.index("left_knee")
    heights = np.repeat(heights, 3, axis=0)
    heights[1, knee], heights[2, knee] = RESTING_HEIGHT - 0.01, -0.2  # on the floor; sunk through it
    assert resting_off_feet(heights).tolist() == [False, True, True]


def test_centre_of_mass_point_weights_give_the_model_centre_of_mass(body):
    """The weighted sum of the model's named points is its centre of mass within a centimetre on random poses (the
    hands' and feet's own centres lie off the lines the weights assume)."""
    rng = np.random.default_rng(2)
    q = random_poses(body, 20, rng)
    pose = kin.forward_kinematics(body, q)
    weights = kin.center_of_mass_point_weights(body)
    assert abs(sum(weights.values()) - 1.0) < 1e-12
    from_points = kin.center_of_mass_from_points(body, pose.points, body.point_names)
    assert np.linalg.norm(from_points - kin.center_of_mass(body, pose), axis=1).max() < 0.01
