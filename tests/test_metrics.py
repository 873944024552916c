"""Every metric on a tiny case whose answer is worked out by hand, plus properties and shape checks."""

import numpy as np
import pytest

from physmocap import metrics


def rotation_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


# Two joints (root, foot) over three frames, walking along x.
TWO_JOINTS = np.array([
    [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]],
    [[0.1, 0.0, 1.0], [0.1, 0.0, 0.0]],
    [[0.2, 0.0, 1.0], [0.2, 0.0, 0.0]],
])

TETRAHEDRON = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


# ----- MPJPE and alignments -------------------------------------------------------------------------------


def test_mpjpe_constant_offset_of_10_mm():
    pred = TWO_JOINTS + np.array([0.010, 0.0, 0.0])
    assert metrics.mpjpe(pred, TWO_JOINTS, align="none") == pytest.approx(0.010)
    assert metrics.mpjpe(pred, TWO_JOINTS, align="root") == pytest.approx(0.0)


def test_mpjpe_offset_of_one_joint():
    pred = TWO_JOINTS.copy()
    pred[:, 1] += [0.006, 0.008, 0.0]  # a 3-4-5 offset of 10 mm on the foot only
    # Root-relative: the root's error is 0 and the foot's 10 mm -> mean 5 mm; the same without alignment.
    assert metrics.mpjpe(pred, TWO_JOINTS, align="root") == pytest.approx(0.005)
    assert metrics.mpjpe(pred, TWO_JOINTS, align="none") == pytest.approx(0.005)
    # Only the foot, as for Rempe's "Feet" column.
    assert metrics.mpjpe(pred, TWO_JOINTS, align="none", joints=[1]) == pytest.approx(0.010)
    # root_index picks the joint subtracted: relative to the foot, the root is 10 mm off.
    assert metrics.mpjpe(pred, TWO_JOINTS, align="root", root_index=1) == pytest.approx(0.005)


def test_procrustes_removes_rotation_translation_and_scale():
    truth = np.stack([TETRAHEDRON, TETRAHEDRON * 2.0 + 1.0])
    rotation = rotation_z(0.7) @ rotation_x(-1.2)
    pred = 1.7 * truth @ rotation.T + np.array([3.0, -2.0, 0.5])
    assert metrics.mpjpe(pred, truth, align="procrustes") == pytest.approx(0.0, abs=1e-12)
    assert metrics.mpjpe(pred, truth, align="root") > 0.1


def test_procrustes_does_not_reflect():
    truth = TETRAHEDRON[None]
    mirrored = truth * np.array([-1.0, 1.0, 1.0])
    # A mirror image of a non-planar shape is no rotation of it: some error must remain.
    assert metrics.mpjpe(mirrored, truth, align="procrustes") > 0.05


def test_procrustes_hand_computed_scale_and_residual():
    # Truth: three joints on the x axis. Pred: the middle joint lifted by 3 along y.
    truth = np.array([[[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    pred = np.array([[[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 3.0, 0.0]]])
    # Centred pred: (-1, -1, 0), (1, -1, 0), (0, 2, 0), variance sum 8. Cross-covariance sum g p^T = diag(2, 0, 0)
    # -> rotation leaves x alone, scale = 2 / 8 = 1/4. Aligned: (-1/4, .) and (1/4, .) with an off-axis part of
    # length 1/4, and the middle joint at distance 2/4 from the origin.
    outer = np.sqrt(0.75**2 + 0.25**2)
    expected = (2 * outer + 0.5) / 3
    assert metrics.mpjpe(pred, truth, align="procrustes") == pytest.approx(expected)


def test_procrustes_never_worse_than_root_relative_on_random_data():
    rng = np.random.default_rng(0)
    for _ in range(20):
        truth = rng.normal(scale=0.3, size=(5, 17, 3))
        pred = truth @ rotation_z(rng.uniform(-0.5, 0.5)).T + rng.normal(scale=0.05, size=truth.shape)
        # Procrustes minimises the summed squared error, which root alignment (a translation) cannot beat.
        squared_procrustes = np.sum(metrics.joint_errors(pred, truth, "procrustes") ** 2, axis=1)
        squared_root = np.sum(metrics.joint_errors(pred, truth, "root") ** 2, axis=1)
        assert np.all(squared_procrustes <= squared_root + 1e-12)
        assert metrics.mpjpe(pred, truth, "procrustes") <= metrics.mpjpe(pred, truth, "root")


def test_first_frame_alignment_removes_one_heading_and_offset():
    # Root above the origin in frame 0 and two feet spread out, so the heading is defined; walking along x.
    frame = np.array([[0.0, 0.0, 1.0], [0.1, 0.1, 0.0], [-0.1, -0.1, 0.0]])
    truth = np.stack([frame + [0.1 * t, 0.0, 0.0] for t in range(3)])
    pred = truth @ rotation_z(np.pi / 2).T + np.array([5.0, -3.0, 0.2])
    assert metrics.mpjpe(pred, truth, align="first_frame") == pytest.approx(0.0, abs=1e-12)
    assert metrics.mpjpe(pred, truth, align="none") > 1.0
    # Translation only keeps the quarter turn about the root (which sits on the z axis in frame 0):
    # a point with horizontal part h ends at R h, |R h - h| = sqrt(2) |h| for a quarter turn.
    expected = np.mean(np.sqrt(2) * np.linalg.norm(truth[..., :2], axis=-1))
    assert metrics.mpjpe(pred, truth, align="first_frame_root") == pytest.approx(expected)


def test_first_frame_alignment_keeps_later_drift():
    pred = TWO_JOINTS + np.array([1.0, 2.0, 0.0])
    pred[1:] += [0.03, 0.0, 0.0]  # drift after frame 0: 30 mm in frames 1 and 2 -> mean over 3 frames 20 mm
    assert metrics.mpjpe(pred, TWO_JOINTS, align="first_frame") == pytest.approx(0.02)
    assert metrics.mpjpe(pred, TWO_JOINTS, align="first_frame_root") == pytest.approx(0.02)


def test_first_frame_alignment_does_not_remove_tilt():
    pred = TETRAHEDRON[None] @ rotation_x(0.5).T
    assert metrics.mpjpe(pred, TETRAHEDRON[None], align="first_frame") > 0.05


# ----- PCK and AUC -----------------------------------------------------------------------------------------


def four_joints_with_errors(errors):
    truth = np.zeros((1, len(errors), 3))
    pred = truth.copy()
    pred[0, :, 0] = errors
    return pred, truth


def test_pck_one_of_four_joints_beyond_150_mm():
    pred, truth = four_joints_with_errors([0.0, 0.05, 0.1, 0.2])
    assert metrics.pck(pred, truth, align="none") == pytest.approx(75.0)
    assert metrics.pck(pred, truth, threshold=0.075, align="none") == pytest.approx(50.0)


def test_auc_hand_computed():
    pred, truth = four_joints_with_errors([0.0, 0.05, 0.1, 0.2])
    # Thresholds 0, 0.1, 0.2: PCK 25%, 75%, 100% -> mean 66.67%.
    assert metrics.auc(pred, truth, thresholds=np.array([0.0, 0.1, 0.2]), align="none") == pytest.approx(200 / 3)
    # Default thresholds 0, 5, ..., 150 mm (31). Errors 0, 52.5, 102.5, 200 mm pass 31, 20, 10 and 0 of them.
    pred, truth = four_joints_with_errors([0.0, 0.0525, 0.1025, 0.2])
    assert metrics.auc(pred, truth, align="none") == pytest.approx(100 * 61 / 124)


def test_auc_of_perfect_prediction_is_100():
    assert metrics.auc(TWO_JOINTS, TWO_JOINTS, align="none") == pytest.approx(100.0)


# ----- Reprojection ----------------------------------------------------------------------------------------

K_SIMPLE = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])


def test_reprojection_error_mean_and_std_over_frames():
    points = np.array([[[0.0, 0.0, 2.0], [0.2, 0.0, 2.0]]] * 2)  # project to (50, 50) and (60, 50)
    keypoints = np.array([
        [[53.0, 50.0], [60.0, 55.0]],  # errors 3 and 5 -> frame mean 4
        [[50.0, 50.0], [60.0, 46.0]],  # errors 0 and 4 -> frame mean 2
    ])
    mean, std = metrics.reprojection_error(points, K_SIMPLE, np.eye(3), np.zeros(3), keypoints)
    assert mean == pytest.approx(3.0)
    assert std == pytest.approx(1.0)


def test_reprojection_error_skips_low_confidence_joints():
    points = np.array([[[0.0, 0.0, 2.0], [0.2, 0.0, 2.0]]])
    keypoints = np.array([[[53.0, 50.0, 0.9], [500.0, 500.0, 0.0]]])  # the second joint was not detected
    mean, std = metrics.reprojection_error(points, K_SIMPLE, np.eye(3), np.zeros(3), keypoints)
    assert (mean, std) == pytest.approx((3.0, 0.0))
    mean, _ = metrics.reprojection_error(points, K_SIMPLE, np.eye(3), np.zeros(3), keypoints, min_confidence=0.95)
    assert np.isnan(mean)


def test_reprojection_error_with_extrinsics_of_another_view():
    # A level camera at the world origin looking along +y (Z up world): x_cam = x, y_cam = -z, z_cam = y.
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    translation = np.array([0.0, 0.0, 0.0])
    points = np.array([[[0.0, 2.0, 0.2]]])  # camera (0, -0.2, 2) -> pixel (50, 40)
    mean, _ = metrics.reprojection_error(points, K_SIMPLE, rotation, translation, np.array([[[50.0, 46.0]]]))
    assert mean == pytest.approx(6.0)
    # Moving the camera 1 m back along the view axis (t = -R c with c = (0, -1, 0)): depth 3 -> pixel (50, 43.33).
    mean, _ = metrics.reprojection_error(points, K_SIMPLE, rotation, np.array([0.0, 0.0, 1.0]),
                                         np.array([[[50.0, 50.0]]]))
    assert mean == pytest.approx(20 / 3)


# ----- Smoothness and acceleration -------------------------------------------------------------------------


def test_e_smooth_constant_shift_is_zero():
    assert metrics.e_smooth(TWO_JOINTS + 0.3, TWO_JOINTS) == pytest.approx((0.0, 0.0))


def test_e_smooth_alternating_jitter():
    truth = np.zeros((4, 2, 3))
    pred = truth.copy()
    pred[:, 0, 0] = [0.0, 0.01, 0.0, 0.01]  # joint 0 jitters by 10 mm every frame, joint 1 is exact
    # |Jit_GT - Jit_X| = 0.01 for joint 0 in all 3 steps and 0 for joint 1: mean 0.005, std 0.005.
    assert metrics.e_smooth(pred, truth) == pytest.approx((0.005, 0.005))


def test_e_smooth_jitter_on_a_moving_joint():
    steps = np.arange(4)
    truth = np.zeros((4, 1, 3))
    truth[:, 0, 0] = 0.02 * steps  # 20 mm per frame
    pred = truth.copy()
    pred[:, 0, 0] += 0.005 * (-1.0) ** steps  # steps of 10, 30, 10 mm instead of 20
    assert metrics.e_smooth(pred, truth) == pytest.approx((0.01, 0.0))


def test_acceleration_error_of_alternating_jitter():
    truth = np.zeros((5, 1, 3))
    pred = truth.copy()
    pred[:, 0, 0] = 0.005 * (-1.0) ** np.arange(5)
    # Second difference of +-5 mm alternation: 5 mm * (1 + 2 + 1) = 20 mm per frame^2; at 10 fps -> 2 m/s^2.
    assert metrics.acceleration_error(pred, truth, fps=10.0) == pytest.approx(2.0)
    assert metrics.acceleration_error(truth + 1.0, truth, fps=10.0) == pytest.approx(0.0)


def test_mean_acceleration_of_free_fall():
    times = np.arange(6) / 10.0
    points = np.zeros((6, 2, 3))
    points[:, :, 0] = 0.3 * times[:, None]  # constant horizontal velocity adds nothing
    points[:, :, 2] = -0.5 * 9.81 * times[:, None] ** 2
    assert metrics.mean_acceleration(points, fps=10.0) == pytest.approx(9.81)


def test_explained_acceleration_counts_only_frames_explained_with_both_neighbours():
    times = np.arange(8) / 10.0
    points = np.zeros((8, 1, 3))
    points[:, 0, 2] = -0.5 * 9.81 * times**2
    points[5, 0, 2] += 1.0  # a jump on a flagged frame
    explained = np.ones(8, bool)
    explained[5] = False
    # frames 4, 5 and 6 each have frame 5 beside or on them; the others see the free fall alone
    assert metrics.explained_acceleration(points, 10.0, explained) == pytest.approx(9.81)
    assert metrics.explained_acceleration(points, 10.0, np.ones(8, bool)) > 9.81 + 50.0
    assert np.isnan(metrics.explained_acceleration(points, 10.0, np.arange(8) % 2 == 0))


# ----- Feet and floor --------------------------------------------------------------------------------------


def feet_at_heights(heights):
    """(T, F) heights -> (T, F, 3) points at x = foot index, y = 0."""
    heights = np.asarray(heights, float)
    points = np.zeros(heights.shape + (3,))
    points[..., 0] = np.arange(heights.shape[1])
    points[..., 2] = heights
    return points


def test_height_above_floor_with_plane():
    point = np.array([1.0, 0.0, 1.0])
    assert metrics.height_above_floor(point) == pytest.approx(1.0)
    assert metrics.height_above_floor(point, floor_height=0.25) == pytest.approx(0.75)
    # Plane x + z = 0, normal (1, 0, 1)/sqrt(2): the point is 2/sqrt(2) above it.
    assert metrics.height_above_floor(point, floor_plane=np.array([1.0, 0.0, 1.0, 0.0])) == pytest.approx(np.sqrt(2))
    with pytest.raises(ValueError):
        metrics.height_above_floor(point, floor_height=0.1, floor_plane=np.array([0.0, 0.0, 1.0, 0.0]))


def test_mpe_pnp_hand_computed():
    heights = np.array([[0.0, 0.03], [0.01, 0.0], [-0.02, 0.0], [0.05, 0.0]])
    contacts = np.array([[True, False], [True, True], [True, True], [False, True]])
    mpe, mpe_std, pnp = metrics.mpe_pnp(feet_at_heights(heights), contacts)
    # In-contact |heights|: 0, 0.01, 0.02 (foot 0) and 0, 0, 0 (foot 1): mean 0.005.
    assert mpe == pytest.approx(0.005)
    assert mpe_std == pytest.approx(np.sqrt((4 * 0.005**2 + 0.005**2 + 0.015**2) / 6))
    assert pnp == pytest.approx(75.0)  # frame 2 has a foot 2 cm below the floor
    assert metrics.mpe_pnp(feet_at_heights(heights), contacts, penetration_tolerance=0.03)[2] == pytest.approx(100.0)


def test_mpe_pnp_floor_height_and_plane_agree():
    heights = np.array([[0.1, 0.12], [0.08, 0.1]])
    contacts = np.ones((2, 2), bool)
    by_height = metrics.mpe_pnp(feet_at_heights(heights), contacts, floor_height=0.1)
    by_plane = metrics.mpe_pnp(feet_at_heights(heights), contacts, floor_plane=np.array([0.0, 0.0, 2.0, -0.2]))
    assert by_height == pytest.approx(by_plane)
    assert by_height == pytest.approx((0.01, 0.01, 50.0))


def test_mpe_without_contacts_is_nan():
    mpe, mpe_std, pnp = metrics.mpe_pnp(feet_at_heights(np.zeros((3, 2))), np.zeros((3, 2), bool))
    assert np.isnan(mpe) and np.isnan(mpe_std) and pnp == 100.0


def test_penetration_one_frame_in_ten():
    heights = np.zeros((10, 1))
    heights[4, 0] = -0.04  # 4 cm below the floor: beyond 3 cm
    heights[7, 0] = -0.02  # 2 cm: within tolerance
    errors = metrics.foot_contact_errors(feet_at_heights(heights), np.ones((10, 1), bool))
    assert errors["penetration_percent"] == pytest.approx(10.0)
    assert errors["floating_percent"] == 0.0
    assert errors["skate_percent"] == 0.0


def test_foot_contact_errors_hand_computed():
    heights = np.zeros((10, 4))
    contacts = np.ones((10, 4), bool)
    heights[3, 0] = -0.04  # penetration (and a vertical move, which is no skate)
    heights[5, 1] = 0.05  # floating: 5 cm up while in contact
    heights[6, 2] = 0.05  # 5 cm up, but not in contact: no floating
    contacts[6, 2] = False
    points = feet_at_heights(heights)
    points[8:, 3, 1] += 0.03  # toe slides 3 cm between frames 7 and 8, both in contact: one skate frame
    errors = metrics.foot_contact_errors(points, contacts)
    assert errors["floating_percent"] == pytest.approx(100 / 40)
    assert errors["penetration_percent"] == pytest.approx(100 / 40)
    assert errors["skate_percent"] == pytest.approx(100 / 40)
    assert errors["floating_percent_of_contact"] == pytest.approx(100 / 39)
    assert errors["skate_percent_of_contact"] == pytest.approx(100 / 39)


def test_no_skate_into_a_row_that_follows_a_gap():
    """Rows of the frames with a person: a foot in contact on both sides of a gap has not slid between them."""
    points = feet_at_heights(np.zeros((3, 1)))
    points[1:, 0, 0] += 1.0  # the source walked a metre while nobody was seen
    contacts = np.ones((3, 1), bool)
    assert metrics.foot_contact_errors(points, contacts)["skate_percent"] == pytest.approx(100 / 3)
    assert metrics.foot_contact_errors(points, contacts, breaks=np.array([False, True, False]))["skate_percent"] == 0


def test_skate_needs_contact_in_both_frames_and_rescales_with_fps():
    points = feet_at_heights(np.zeros((4, 1)))
    points[2:, 0, 0] += 0.05  # 5 cm jump between frames 1 and 2
    contacts = np.array([[True], [False], [True], [True]])
    assert metrics.foot_contact_errors(points, contacts)["skate_percent"] == 0.0

    points = feet_at_heights(np.zeros((4, 1)))
    points[:, 0, 0] = 0.015 * np.arange(4)  # 15 mm per frame
    contacts = np.ones((4, 1), bool)
    assert metrics.foot_contact_errors(points, contacts)["skate_percent"] == 0.0
    # At 60 fps the 2 cm per 1/30 s threshold becomes 1 cm per frame: frames 1, 2, 3 skate.
    assert metrics.foot_contact_errors(points, contacts, fps=60.0)["skate_percent"] == pytest.approx(75.0)


# ----- Ground reaction forces ------------------------------------------------------------------------------


def test_grf_statistics_hand_computed():
    grf = np.zeros((4, 2, 3))
    grf[0] = [[0, 0, 50], [0, 0, 50]]  # 100 N = 100 % of 10 kg x 10 m/s^2
    grf[1] = [[0, 0, 150], [0, 0, 50]]  # 200 %
    grf[3] = [[30, 0, 40], [0, 0, 0]]  # magnitude 50 N = 50 %, vertical 40 %
    contacts = np.array([[1, 1], [1, 1], [0, 0], [0, 0]], bool)
    stats = metrics.grf_statistics(grf, body_mass=10.0, contacts_truth=contacts, gravity=10.0)
    assert stats["mean_percent_bw"] == pytest.approx(87.5)
    assert stats["max_percent_bw"] == pytest.approx(200.0)
    assert stats["ballistic_percent_bw"] == pytest.approx(25.0)  # median of 0 % and 50 %
    np.testing.assert_allclose(stats["flight_percent_bw"], [0.0, 50.0])
    vertical = metrics.grf_statistics(grf, 10.0, contacts, gravity=10.0, measure="vertical")
    vertical.pop("flight_percent_bw")
    assert vertical == pytest.approx({"mean_percent_bw": 85.0, "max_percent_bw": 200.0, "ballistic_percent_bw": 20.0})
    without_truth = metrics.grf_statistics(grf, 10.0, gravity=10.0)
    assert np.isnan(without_truth["ballistic_percent_bw"]) and without_truth["flight_percent_bw"].size == 0


def test_implied_grf_of_standing_and_free_fall():
    standing = np.tile([0.0, 0.0, 1.0], (5, 1))
    np.testing.assert_allclose(metrics.implied_grf(standing, 70.0, fps=30.0), np.tile([0, 0, 70 * 9.81], (5, 1)))
    times = np.arange(5) / 30.0
    flying = np.stack([0.5 * times, 0.0 * times, 1.0 + 2.0 * times - 0.5 * 9.81 * times**2], axis=1)
    np.testing.assert_allclose(metrics.implied_grf(flying, 70.0, fps=30.0), 0.0, atol=1e-9)


def test_implied_grf_hand_computed_and_its_statistics():
    com = np.zeros((4, 3))
    com[:, 2] = [0.0, 0.0, 0.01, 0.0]
    # Second differences 0.01 and -0.02 m per frame^2 at 10 fps: 1 and -2 m/s^2; the ends copy their neighbour.
    forces = metrics.implied_grf(com, body_mass=10.0, fps=10.0, gravity=10.0)
    np.testing.assert_allclose(forces[:, 2], 10.0 * (np.array([1.0, 1.0, -2.0, -2.0]) + 10.0))
    stats = metrics.grf_statistics(forces, body_mass=10.0, gravity=10.0)
    assert stats["mean_percent_bw"] == pytest.approx(95.0)  # (110 + 110 + 80 + 80) / 4
    assert stats["max_percent_bw"] == pytest.approx(110.0)


# ----- Contact classification ------------------------------------------------------------------------------


def test_contact_scores_hand_computed():
    truth = np.array([[1, 1], [1, 1], [0, 1], [0, 0]], bool)
    pred = np.array([[1, 1], [0, 1], [1, 1], [0, 1]], bool)
    scores = metrics.contact_scores(pred, truth)
    # Column 0: TP 1, FP 1, FN 1, TN 1. Column 1: TP 3, FP 1, FN 0, TN 0. Pooled: TP 4, FP 2, FN 1, TN 1.
    assert scores["accuracy"] == pytest.approx(5 / 8)
    assert scores["precision"] == pytest.approx(4 / 6)
    assert scores["recall"] == pytest.approx(4 / 5)
    assert scores["f1"] == pytest.approx(8 / 11)
    per_column = scores["per_column"]
    np.testing.assert_allclose(per_column["accuracy"], [0.5, 0.75])
    np.testing.assert_allclose(per_column["precision"], [0.5, 0.75])
    np.testing.assert_allclose(per_column["recall"], [0.5, 1.0])
    np.testing.assert_allclose(per_column["f1"], [0.5, 6 / 7])


def test_contact_scores_undefined_precision_is_nan():
    scores = metrics.contact_scores(np.zeros(4, bool), np.array([1, 0, 1, 0], bool))
    assert scores["accuracy"] == pytest.approx(0.5)
    assert np.isnan(scores["precision"])
    assert scores["recall"] == 0.0
    assert scores["f1"] == 0.0


# ----- Bone lengths ----------------------------------------------------------------------------------------


def test_bone_length_std_hand_computed():
    points = np.zeros((3, 3, 3))
    points[:, 1, 2] = [1.0, 1.1, 0.9]  # bone 0-1: lengths 1.0, 1.1, 0.9
    points[:, 2] = points[:, 1] + [0.3, 0.0, 0.0]  # bone 1-2: always 0.3
    edges = np.array([[0, 1], [1, 2]])
    np.testing.assert_allclose(metrics.bone_lengths(points, edges)[:, 1], 0.3)
    np.testing.assert_allclose(metrics.bone_length_std(points, edges), [np.sqrt(0.02 / 3), 0.0], atol=1e-12)


def test_bone_length_std_of_a_rotating_rigid_body_is_zero():
    frames = np.stack([TETRAHEDRON @ rotation_z(a).T @ rotation_x(2 * a).T for a in np.linspace(0, 1, 7)])
    edges = np.array([[0, 1], [0, 2], [0, 3], [1, 2]])
    np.testing.assert_allclose(metrics.bone_length_std(frames, edges), 0.0, atol=1e-12)


# ----- Shape checks ----------------------------------------------------------------------------------------

A = np.zeros((4, 3, 3))
B = np.zeros((4, 2, 3))


@pytest.mark.parametrize("call", [
    lambda: metrics.mpjpe(A, B),
    lambda: metrics.mpjpe(A[..., :2], A[..., :2]),
    lambda: metrics.mpjpe(A, A, align="bogus"),
    lambda: metrics.mpjpe(A, A, root_index=3),
    lambda: metrics.pck(A, B),
    lambda: metrics.auc(A, B),
    lambda: metrics.auc(A, A, thresholds=np.zeros((2, 2))),
    lambda: metrics.e_smooth(A, B),
    lambda: metrics.e_smooth(A[:1], A[:1]),
    lambda: metrics.acceleration_error(A, B, fps=30.0),
    lambda: metrics.mean_acceleration(A[:2], fps=30.0),
    lambda: metrics.reprojection_error(A, K_SIMPLE, np.eye(3), np.zeros(3), np.zeros((4, 2, 2))),
    lambda: metrics.reprojection_error(A, K_SIMPLE, np.eye(3), np.zeros(2), np.zeros((4, 3, 2))),
    lambda: metrics.mpe_pnp(B, np.ones((4, 3), bool)),
    lambda: metrics.mpe_pnp(B, np.ones((4, 2), bool), floor_plane=np.zeros(4)),
    lambda: metrics.foot_contact_errors(B, np.ones((3, 2), bool)),
    lambda: metrics.grf_statistics(np.zeros((4, 2, 2)), 70.0),
    lambda: metrics.grf_statistics(np.zeros((4, 3)), 70.0, contacts_truth=np.ones((5, 4), bool)),
    lambda: metrics.grf_statistics(np.zeros((4, 3)), 70.0, measure="bogus"),
    lambda: metrics.implied_grf(np.zeros((4, 2)), 70.0, fps=30.0),
    lambda: metrics.implied_grf(np.zeros((2, 3)), 70.0, fps=30.0),
    lambda: metrics.contact_scores(np.ones((4, 2), bool), np.ones((4, 3), bool)),
    lambda: metrics.bone_lengths(A, np.array([0, 1])),
])
def test_mismatched_or_bad_shapes_raise_value_error(call):
    with pytest.raises(ValueError):
        call()
