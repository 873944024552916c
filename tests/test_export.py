"""`physmocap export` (export_result) on a synthetic result.npz, presets, smoothing strength and foot-lock.

`synthetic_result` here is the walking clip the other export, viewer, plot and report tests share.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from bvh import Bvh

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, build_body_model, template_lengths
from physmocap.config import Settings
from physmocap.contacts.footlock import FOOT_LOCK_MODES, foot_lock
from physmocap.errors import InputError
from physmocap.export import EXPORT_FORMATS, body_from_result, export_result
from physmocap.landmarks import LANDMARK_NAMES
from physmocap.presets import PRESETS, apply_preset, apply_smoothing
from physmocap.result import RESULT_POINTS, save_result

GRAVITY = 9.81


def walking_qpos(body, frames: int, fps: float) -> np.ndarray:
    """(frames, nq) a stylised walk along +x at 1.2 m/s: legs and arms swing at 1 Hz, knees bend, the
    pelvis bobs, and the body turns slowly about the vertical."""
    time = np.arange(frames) / fps
    phase = 2 * np.pi * 1.0 * time
    qpos = np.tile(body.rest_qpos, (frames, 1))
    qpos[:, 0] = 1.2 * time + 0.5
    qpos[:, 1] = -0.3
    qpos[:, 2] += -0.02 + 0.015 * np.cos(2 * phase)
    yaw = 0.2 * np.sin(0.3 * phase)
    qpos[:, 3:7] = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)

    def about_y(angle: np.ndarray) -> np.ndarray:
        return np.stack([np.cos(angle / 2), 0 * angle, np.sin(angle / 2), 0 * angle], axis=1)

    for side, sign in (("left", 1.0), ("right", -1.0)):
        hip = body.qpos_address[body.joint_index[f"{side}_hip"]]
        knee = body.qpos_address[body.joint_index[f"{side}_knee"]]
        shoulder = body.qpos_address[body.joint_index[f"{side}_shoulder"]]
        qpos[:, hip:hip + 4] = about_y(-0.35 * sign * np.sin(phase))
        qpos[:, knee] = 0.35 + 0.35 * np.sin(phase + sign * np.pi / 2)
        qpos[:, shoulder:shoulder + 4] = [np.cos(0.6), -sign * np.sin(0.6), 0.0, 0.0]  # arms 70 degrees down
    return qpos


def synthetic_result(frames: int = 60, fps: float = 30.0, with_physics: bool = True) -> dict[str, np.ndarray]:
    """Every key of result.npz for a synthetic walk seen by a camera 4 m to the side, with contacts from the foot
    heights and GRFs that carry the body weight over the contact points (plus a small forward push)."""
    body = build_body_model(template_lengths(1.72), 68.0)
    qpos = walking_qpos(body, frames, fps)
    points = kin.forward_kinematics(body, qpos).points[:, body.point_index(RESULT_POINTS)]
    kinematic_qpos = qpos.copy()
    kinematic_qpos[:, 2] += 0.01 * np.sin(np.arange(frames) * 1.7)  # a jittery kinematic motion
    kinematic = kin.forward_kinematics(body, kinematic_qpos).points[:, body.point_index(RESULT_POINTS)]

    contact_ids = [RESULT_POINTS.index(name) for name in CONTACT_POINTS]
    heights = points[:, contact_ids, 2]
    contacts = heights < heights.min() + 0.03
    grf = np.zeros((frames, 4, 3))
    if with_physics:
        share = contacts / np.maximum(contacts.sum(axis=1, keepdims=True), 1)
        grf[..., 2] = share * body.mass * GRAVITY
        grf[..., 0] = share * 40.0
        grf[..., 1] = share * np.array([10.0, 5.0, -10.0, -5.0])

    # Camera 4 m to the right of the walkway, looking along +y (world y -> camera z, world z -> camera -y).
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    t = -R @ np.array([1.5, -4.3, 1.0])
    K = np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]])
    camera_points = points @ R.T + t
    pixels = camera_points[..., :2] / camera_points[..., 2:3] @ K[:2, :2].T + K[:2, 2]
    keypoints = np.zeros((frames, len(LANDMARK_NAMES), 3))
    for index, name in enumerate(LANDMARK_NAMES):
        point = name.replace("foot_index", "toe")
        if point in RESULT_POINTS:
            keypoints[:, index, :2] = pixels[:, RESULT_POINTS.index(point)] + 1.5
            keypoints[:, index, 2] = 0.9
    floor_normal_camera = R @ np.array([0.0, 0.0, 1.0])
    floor = np.append(floor_normal_camera, -floor_normal_camera @ t)
    return dict(
        fps=np.float64(fps), joint_names=np.array(RESULT_POINTS), joints_world=points,
        joints_world_kinematic=kinematic, qpos=qpos, qpos_kinematic=kinematic_qpos,
        contact_names=np.array(CONTACT_POINTS), contacts=contacts, contacts_predicted=contacts,
        stationary=np.zeros(frames, bool), grf=grf, residual_root_force=np.zeros((frames, 6)),
        physics=np.str_("physcap" if with_physics else "none"), physics_fallback=np.zeros(frames, bool),
        balance_corrected=np.zeros(frames, bool), camera_K=K, camera_R=R, camera_t=t,
        image_size=np.array([1280, 720]), floor=floor, keypoints_2d=keypoints, valid=np.ones(frames, bool),
        invalid_reason=np.full(frames, "", dtype=str), reprojection_error=np.full(frames, 2.1),
        person_height_px=np.full(frames, 350.0), body_mass=np.float64(body.mass),
        body_height=np.float64(body.height), body_lengths=np.str_(json.dumps(body.lengths.__dict__)),
        stage_seconds=np.str_(json.dumps({"kinematics": 1.0})), settings=np.str_(json.dumps({})),
    )


@pytest.fixture(scope="module")
def result_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("run") / "result.npz"
    save_result(path, synthetic_result())
    return path


def test_body_from_result_rebuilds_the_skeleton(result_path):
    result = dict(np.load(result_path))
    body = body_from_result(result)
    points = kin.forward_kinematics(body, result["qpos"]).points[:, body.point_index(RESULT_POINTS)]
    np.testing.assert_allclose(points, result["joints_world"], atol=1e-9)
    assert body.mass == pytest.approx(float(result["body_mass"]))


@pytest.mark.parametrize("to", EXPORT_FORMATS)
def test_export_writes_each_format(result_path, tmp_path, to):
    files = export_result(result_path, to, tmp_path / to)
    assert files and all(Path(f).is_file() and Path(f).stat().st_size > 0 for f in files.values())


def test_export_bvh_passes_options(result_path, tmp_path):
    files = export_result(result_path, "bvh", tmp_path, units="cm", root_at_origin=True)
    mocap = Bvh(Path(files["bvh"]).read_text())
    root = np.array(mocap.frames_joint_channels("Hips", ["Xposition", "Yposition", "Zposition"]))
    assert root[0, 0] == pytest.approx(0.0, abs=1e-6) and root[0, 2] == pytest.approx(0.0, abs=1e-6)
    result = np.load(result_path)
    assert root[0, 1] == pytest.approx(100 * result["qpos"][0, 2], abs=1e-3)


def test_export_rejects_unknown_format_and_options(result_path, tmp_path):
    with pytest.raises(InputError, match="fbx"):
        export_result(result_path, "fbx", tmp_path)
    with pytest.raises(InputError, match="units"):
        export_result(result_path, "glb", tmp_path, units="cm")
    with pytest.raises(InputError, match="no such result file"):
        export_result(tmp_path / "missing.npz", "bvh", tmp_path)


# ---- presets, smoothing strength, foot-lock -----------------------------------------------------------


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_presets_are_valid_settings(name):
    settings = apply_preset(Settings(), name)
    settings.check()
    preset = PRESETS[name]
    assert preset.rationale
    for section, fields in preset.overrides.items():
        for field, value in fields.items():
            assert getattr(getattr(settings, section), field) == value


def test_presets_cover_the_named_activities():
    assert set(PRESETS) == {"walking", "running", "jumping", "dancing", "standing"}
    with pytest.raises(InputError, match="swimming"):
        apply_preset(Settings(), "swimming")


def test_smoothing_strength_scales_the_temporal_weights():
    base = Settings()
    stronger = apply_smoothing(base, 3.0)
    assert stronger.fit.weight_smooth == pytest.approx(3 * base.fit.weight_smooth)
    assert stronger.fit.weight_depth == pytest.approx(3 * base.fit.weight_depth)
    assert apply_smoothing(base, 0.0).fit.weight_smooth == 0.0
    assert apply_smoothing(base, 1.0) == base
    with pytest.raises(InputError, match="smoothing"):
        apply_smoothing(base, -1.0)


def test_foot_lock_modes():
    predicted = np.array([[True, False, False, False], [False, False, True, True], [False] * 4])
    heights = np.array([[0.01, 0.02, 0.30, 0.00], [0.20, 0.05, 0.01, 0.09], [0.5, 0.5, -0.01, 0.5]])
    assert FOOT_LOCK_MODES == ("auto", "always", "never")
    np.testing.assert_array_equal(foot_lock(predicted, heights, "auto", 0.08), predicted)
    np.testing.assert_array_equal(foot_lock(predicted, heights, "always", 0.08),
                                  [[True, True, False, True], [False, True, True, False],
                                   [False, False, True, False]])
    assert not foot_lock(predicted, heights, "never", 0.08).any()
    with pytest.raises(InputError, match="foot-lock"):
        foot_lock(predicted, heights, "sometimes", 0.08)
    with pytest.raises(ValueError, match="shape"):
        foot_lock(predicted, heights[:, :2], "auto", 0.08)
