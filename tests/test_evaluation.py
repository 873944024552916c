import json

import numpy as np
import pytest

from physmocap.body import kinematics as kin
from physmocap.body.model import JOINT_NAMES
from physmocap.camera import Camera, Floor
from physmocap.cli import main
from physmocap.errors import InputError
from physmocap.evaluation import evaluate
from physmocap.io.atomic import save_npz
from physmocap.kinematics.calibration import Calibration
from physmocap.kinematics.stage import KinematicMotion
from physmocap.result import build_result, save_result
from test_fit import observe, walking_motion


@pytest.fixture(scope="module")
def case(body, tmp_path_factory):
    """A run whose motion is exactly the truth, and the truth file."""
    folder = tmp_path_factory.mktemp("evaluation")
    cam = Camera.from_settings((1280, 720), fov=60)
    R = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])
    cam = cam.with_extrinsics(R, -R @ np.array([0.5, -4.0, 1.0]))
    qpos = walking_motion(body, 40)
    obs = observe(body, qpos, cam)
    up = R[:, 2]
    motion = KinematicMotion(body, Calibration(body.lengths, 1.0, 30, ()), cam, Floor(up, float(-up @ cam.t)),
                             qpos, np.zeros(40), np.ones(40, bool), 0.0, False)
    result = build_result(obs, motion, {}, {}, np.zeros((40, 4), bool), np.zeros(40, bool))
    save_result(folder / "result.npz", result)
    joints = kin.forward_kinematics(body, qpos).points[:, :len(JOINT_NAMES)]
    truth = dict(joint_names=np.array(JOINT_NAMES), joints_world=joints, camera_R=R, camera_t=cam.t, fps=30.0)
    save_npz(folder / "truth.npz", **truth)
    return folder, truth


def test_a_run_equal_to_the_truth_scores_zero(case):
    folder, _ = case
    scores = evaluate(folder / "result.npz", folder / "truth.npz")["truth"]["final"]
    for key in ("mpjpe_root_mm", "mpjpe_procrustes_mm", "global_root_mm", "global_mpjpe_mm", "e_smooth_mm",
                "acceleration_error"):
        assert abs(scores[key]) < 1e-6, key
    assert scores["pck150"] == 100.0


def test_a_shifted_truth_moves_only_the_global_errors(case, tmp_path):
    folder, truth = case
    shifted = dict(truth, joints_world=truth["joints_world"] + np.array([0.010, 0.0, 0.0]))
    save_npz(tmp_path / "truth.npz", **shifted)
    scores = evaluate(folder / "result.npz", tmp_path / "truth.npz")["truth"]["final"]
    assert abs(scores["global_root_mm"] - 10.0) < 1e-6
    assert abs(scores["mpjpe_root_mm"]) < 1e-6


def test_evaluate_command_writes_json_and_rejects_a_bad_truth(case, tmp_path, capsys):
    folder, _ = case
    out = tmp_path / "evaluation.json"
    assert main(["evaluate", str(folder / "result.npz"), "--truth", str(folder / "truth.npz"), "-o", str(out)]) == 0
    data = json.loads(out.read_text())
    assert "mean_acceleration" in data["run"] and "final" in data["truth"]
    save_npz(tmp_path / "bad.npz", fps=30.0)
    with pytest.raises(InputError):
        evaluate(folder / "result.npz", tmp_path / "bad.npz")
    assert main(["evaluate", str(folder / "result.npz"), "--truth", str(tmp_path / "bad.npz")]) == 2


@pytest.mark.parametrize("key, change, words", [
    ("joint_names", lambda a: a[::-1][:5], "joint_names must list each"),
    ("joint_names", lambda a: np.arange(len(a)), "joint_names must list each"),
    ("joints_world", lambda a: a.astype(str), "joints_world must be numbers of shape"),
    ("joints_world", lambda a: np.where(a > 1.0, np.nan, a), "joints_world holds a value that is not a finite"),
    ("joints_world", lambda a: a[:-1], "the truth has 39 frames and the run"),
    ("camera_R", lambda a: 2 * a, "camera_R is not a rotation"),
    ("camera_R", lambda a: a.reshape(-1), "camera_R must be numbers of shape"),
    ("camera_t", lambda a: np.full(3, np.inf), "camera_t holds a value"),
    ("fps", lambda a: np.float64(0.0), "fps must be positive"),
])
def test_a_truth_file_from_other_code_is_refused_in_one_sentence(case, tmp_path, capsys, key, change, words):
    """Truth files written by other programs: each breakage of what scoring reads ends in exit 2 and a sentence
    naming the file and the key, not in a traceback or in NaN scores."""
    folder, truth = case
    broken = dict(truth, **{key: change(np.asarray(truth[key]))})
    np.savez(tmp_path / "truth.npz", **broken)
    assert main(["evaluate", str(folder / "result.npz"), "--truth", str(tmp_path / "truth.npz")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and words in err and "truth.npz" in err
