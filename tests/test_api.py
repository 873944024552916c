"""The public Python API, used only through `import physmocap` as a notebook would."""

import os
import subprocess
import sys

import numpy as np
import pytest

import physmocap
from conftest import DEMO_VIDEO
from physmocap.errors import InputError

pytestmark = pytest.mark.slow  # whole captures through the Python API


@pytest.fixture(scope="module")
def captured(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "taiji"
    return physmocap.capture(DEMO_VIDEO, out, overlay=False, height=1.70, fit_weight_smooth=0.2)


def test_capture_returns_the_result_with_its_summary(captured):
    result = captured
    assert result.path.name == "result.npz" and result.folder.name == "taiji"
    T = result.num_frames
    assert 23.9 < result.fps < 24.1 and T == 96 and result.physics == "physcap"
    assert result.joints_world.shape == (T, len(result.joint_names), 3)
    assert result.joint("left_ankle").shape == (T, 3) and np.isfinite(result.joint("head")).all()
    assert result.contacts.shape == (T, 4) and result.grf.shape == (T, 4, 3) and result.valid.all()
    assert abs(float(result["body_height"]) - 1.70) < 1e-9
    assert '"weight_smooth": 0.2' in str(result["settings"])
    assert result.summary["frames"] == T and "overlay" not in result.summary["files"]
    with pytest.raises(InputError, match="no joint named 'tail'"):
        result.joint("tail")


def test_load_result_takes_the_folder_or_the_file(captured):
    for where in (captured.folder, captured.path, str(captured.path)):
        again = physmocap.load_result(where)
        assert np.array_equal(again.qpos, captured.qpos) and again.summary == captured.summary
    with pytest.raises(InputError, match="no such result file"):
        physmocap.load_result(captured.folder / "none.npz")


def test_capture_from_observations_with_physics_and_export(captured, tmp_path):
    result = physmocap.capture(captured.folder / "cache" / "observations.npz", tmp_path / "p", physics="physcap")
    assert result.physics == "physcap" and (result.grf[..., 2] >= -1e-6).all() and result.grf.any()
    written = physmocap.export(result, to="bvh", out=tmp_path / "bvh", units="cm")
    assert written["bvh"] == tmp_path / "bvh" / "motion.bvh" and written["bvh"].is_file()
    assert physmocap.export(tmp_path / "p", to="glb")["glb"] == tmp_path / "p" / "motion.glb"


def test_bad_arguments_are_one_sentence_input_errors(tmp_path):
    with pytest.raises(InputError, match="unknown setting 'fit_no_such_thing'"):
        physmocap.capture(DEMO_VIDEO, tmp_path / "x", fit_no_such_thing=1)
    with pytest.raises(InputError, match="unknown setting 'physics_correction_rate' \\(did you mean "
                                         "physics_correction_time\\?\\)"):
        physmocap.capture(DEMO_VIDEO, tmp_path / "x", physics_correction_rate=0.1)
    with pytest.raises(InputError, match="physics.method"):
        physmocap.capture(DEMO_VIDEO, tmp_path / "x", physics="magic")
    with pytest.raises(InputError, match="no such video"):
        physmocap.capture(tmp_path / "missing.mp4", tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_importing_physmocap_after_numpy_still_gives_blas_one_thread():
    """The thread variables act only before numpy loads; a program that loaded numpy first (and, say, let BLAS use
    two threads) gets one thread from `import physmocap` too, so its results are the command line's. A variable
    the user set is kept."""
    program = ("import numpy, threadpoolctl; threadpoolctl.threadpool_limits(2, user_api='blas'); import physmocap; "
               "print(sorted({i['num_threads'] for i in threadpoolctl.threadpool_info() if i['user_api'] == 'blas'}))")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                              "MKL_NUM_THREADS")}
    run = subprocess.run([sys.executable, "-c", program], env=env, capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "[1]"
    kept = subprocess.run([sys.executable, "-c", program], env={**env, "OPENBLAS_NUM_THREADS": "2"},
                          capture_output=True, text=True, check=True)
    assert kept.stdout.strip() == "[2]"
