"""The stage runner and its cache contract: keys from inputs, settings and code; damaged, foreign and stale caches
recomputed; the run folder's lock, partial files and stale outputs; the same result fresh, cached and from the
observations file."""

import fcntl
import json
import logging
import os
import shutil
from pathlib import Path

import av
import numpy as np
import pytest

from conftest import DEMO_VIDEO
from physmocap import stages
from physmocap.config import Settings
from physmocap.errors import OutputLocationError
from physmocap.evaluation import evaluate, write_evaluation
from physmocap.motion import Observations
from physmocap.pipeline import run_capture
from physmocap.result import load_result
from physmocap.run_folder import LOCK_FILE, locked_run_folder

pytestmark = pytest.mark.slow  # whole captures through the stage runner

FRAMES = 48  # of the demo clip's observations: enough for calibration, refinement and physics, and quick


KINEMATICS_ONLY = Settings().replace("physics", method="none")  # the runs these tests make need no physics

@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory):
    """A fresh run of the demo video without physics or overlay (its cache holds the detections)."""
    out = tmp_path_factory.mktemp("demo")
    run_capture(out, KINEMATICS_ONLY, video=DEMO_VIDEO, overlay=False)
    return out


@pytest.fixture(scope="module")
def short_observations(demo_folder, tmp_path_factory):
    """The first FRAMES frames of the demo's detections, as an observations file."""
    obs = Observations.load(demo_folder / "cache" / "observations.npz")
    path = tmp_path_factory.mktemp("obs") / "short.npz"
    Observations(obs.keypoints_2d[:FRAMES], obs.landmarks_3d[:FRAMES], obs.fps, obs.image_size,
                 valid=obs.valid[:FRAMES], invalid_reason=obs.invalid_reason[:FRAMES]).save(path)
    return path


# ---- keys -------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("stage", stages.STAGES, ids=lambda s: s.file)
def test_each_stage_key_changes_when_its_code_changes(stage, monkeypatch):
    settings = Settings()
    before = stage.key(settings, "inputs")
    closure = stages.code_closure(*stage.code)
    assert stage.code[0] in closure and "physmocap.errors" in closure
    original = stages.module_source
    # The stage's own module, one it imports deep down (the body model or the landmarks), and the wiring module.
    deep = "physmocap.body.model" if "physmocap.body.model" in closure else "physmocap.landmarks"
    for changed in (stage.code[0], deep, "physmocap.stages"):
        monkeypatch.setattr(stages, "module_source",
                            lambda name, changed=changed: original(name) + (b"\n# edited" if name == changed else b""))
        assert stage.key(settings, "inputs") != before, changed
    # Code the stage never runs leaves its key alone.
    monkeypatch.setattr(stages, "module_source",
                        lambda name: original(name) + (b"\n# edited" if name == "physmocap.viz.report" else b""))
    assert "physmocap.viz.report" not in closure
    assert stage.key(settings, "inputs") == before


def test_keys_change_with_inputs_and_the_stages_own_settings():
    settings = Settings()
    key = stages.KINEMATICS.key(settings, "a")
    assert stages.KINEMATICS.key(settings, "b") != key
    assert stages.KINEMATICS.key(settings.replace("body", height=1.8), "a") != key
    assert stages.KINEMATICS.key(settings.replace("physics", method="physcap"), "a") == key  # not its setting
    assert stages.DETECT.key(settings.replace("detect", accept_truncated=True), "v") == stages.DETECT.key(
        settings, "v")


def test_a_stage_naming_a_missing_module_fails_loudly():
    with pytest.raises(ValueError, match="physmocap.kinematics.moved_away"):
        stages.code_version("physmocap.kinematics.moved_away")


def test_the_code_closure_follows_imports_inside_functions():
    # evaluation imports viz.report inside a function; a module's version must cover it.
    assert "physmocap.viz.report" in stages.code_closure("physmocap.evaluation")


# ---- containers round trip ----------------------------------------------------------------------------------------

def test_motion_containers_round_trip_through_arrays(demo_folder):
    from physmocap.dynamics.stage import PhysicsMotion
    from physmocap.kinematics.stage import KinematicMotion
    from physmocap.trajopt.stage import TrajoptMotion, WindowReport

    motion = stages.KINEMATICS.read(demo_folder / "cache" / "kinematics.npz")
    again = KinematicMotion.from_arrays(motion.to_arrays())
    assert stages.motion_digest(again) == stages.motion_digest(motion)
    assert again.body.lengths == motion.body.lengths and again.calibration == motion.calibration
    T = len(motion.qpos)
    physics = PhysicsMotion(motion.qpos, np.ones((T, 4, 3)), np.zeros((T, 6)), np.ones((T, 4), bool),
                            np.zeros(T, bool), np.zeros(T, int), 1.5, np.array([0.0, 0.0, 1.0, 0.1]))
    back = PhysicsMotion.from_arrays(physics.to_arrays())
    assert back.seconds == 1.5 and np.array_equal(back.floor_plane, physics.floor_plane)
    assert PhysicsMotion.from_arrays({**physics.to_arrays(), "floor_plane": np.full(4, np.nan)}).floor_plane is None
    window = WindowReport(0, T - 1, T, True, "dynamics", [], 10, 5, 0.1, 1.0, com_departure=0.01,
                          feet_departure=0.02, com_departure_max=0.03)
    trajopt = TrajoptMotion(motion.qpos, np.zeros((T, 4, 3)), np.zeros((T, 6)), np.ones((T, 4), bool),
                            np.ones(T, bool), np.zeros(T, bool), np.zeros(T, int), np.zeros((T, 3)),
                            np.zeros((T, 3)), np.zeros((T, 3)), np.zeros((T, 4, 3)), [window], 2.0)
    back = TrajoptMotion.from_arrays(trajopt.to_arrays())
    assert back.windows == [window] and np.array_equal(back.qpos, trajopt.qpos) and back.seconds == 2.0


# ---- damaged and foreign caches -----------------------------------------------------------------------------------

def _truncate(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _empty(path):
    path.write_bytes(b"")


def _drop_an_array(path):
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays.pop(sorted(arrays)[0])
    np.savez_compressed(path, **arrays)


@pytest.mark.parametrize("damage", [_truncate, _empty, _drop_an_array],
                         ids=lambda f: f.__name__.strip("_"))
def test_a_damaged_cache_of_every_stage_is_rebuilt_to_the_clean_result(short_observations, tmp_path, damage, caplog):
    settings = Settings().replace("physics", method="physcap")
    clean = tmp_path / "clean"
    run_capture(clean, settings, observations=short_observations, overlay=False)
    expected = load_result(clean / "result.npz")
    for entry in ("kinematics", "refined", "physics"):
        damaged = tmp_path / entry
        shutil.copytree(clean, damaged)
        damage(damaged / "cache" / f"{entry}.npz")
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="physmocap"):
            summary = run_capture(damaged, settings, observations=short_observations, overlay=False)
        notes = [r.getMessage() for r in caplog.records if f"{entry}.npz" in r.getMessage()]
        assert len(notes) == 1 and "recomputing" in notes[0], caplog.text
        rebuilt_stage = {"kinematics": "kinematics", "refined": "refine", "physics": "physics"}[entry]
        assert rebuilt_stage not in summary.cached_stages
        result = load_result(damaged / "result.npz")
        for key in ("joints_world", "joints_world_kinematic", "grf", "contacts"):
            np.testing.assert_array_equal(result[key], expected[key], err_msg=f"{entry}: {key}")
        # ... and the entry is whole again: the next run takes it from the cache.
        again = run_capture(damaged, settings, observations=short_observations, overlay=False)
        assert rebuilt_stage in again.cached_stages


def _stage_outputs(motion, obs):
    """An output of every stage, as CacheFolder stores it."""
    from physmocap.dynamics.stage import PhysicsMotion
    from physmocap.trajopt.stage import TrajoptMotion

    T = len(motion.qpos)
    zeros = np.zeros((T, 3))
    return {
        "observations": obs,
        "kinematics": motion,
        "refined": stages.RefinedMotion(motion, np.ones((T, 4), bool), {"seconds": 1.0}),
        "physics": PhysicsMotion(motion.qpos, np.ones((T, 4, 3)), np.zeros((T, 6)), np.ones((T, 4), bool),
                                 np.zeros(T, bool), np.zeros(T, int), 1.0),
        "trajopt": TrajoptMotion(motion.qpos, np.ones((T, 4, 3)), np.zeros((T, 6)), np.ones((T, 4), bool),
                                 np.ones(T, bool), np.zeros(T, bool), np.zeros(T, int), zeros, zeros, zeros,
                                 np.zeros((T, 4, 3)), [], 1.0),
    }


@pytest.mark.parametrize("damage", [_truncate, _empty, _drop_an_array], ids=lambda f: f.__name__.strip("_"))
def test_every_stage_entry_is_checked_before_use(demo_folder, tmp_path, damage, caplog):
    obs = Observations.load(demo_folder / "cache" / "observations.npz")
    motion = stages.KINEMATICS.read(demo_folder / "cache" / "kinematics.npz")
    cache = stages.CacheFolder(tmp_path)
    outputs = _stage_outputs(motion, obs)
    for stage in stages.STAGES:
        cache.store(stage, "k", outputs[stage.file])
        loaded = cache.load(stage, "k")
        assert type(loaded) is type(outputs[stage.file])
        assert cache.load(stage, "another key") is None  # other inputs, settings or code
        damage(cache.paths(stage)[0])
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="physmocap"):
            assert cache.load(stage, "k") is None
        assert f"{stage.file}.npz is damaged" in caplog.text and "recomputing" in caplog.text


def test_a_damaged_key_file_is_recomputed(short_observations, tmp_path, caplog):
    run_capture(tmp_path, KINEMATICS_ONLY, observations=short_observations, overlay=False)
    (tmp_path / "cache" / "kinematics.key").write_text("{not json")
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        summary = run_capture(tmp_path, KINEMATICS_ONLY, observations=short_observations, overlay=False)
    assert summary.cached_stages == [] and "kinematics.key is damaged" in caplog.text


def test_a_foreign_observations_cache_is_not_trusted(demo_folder, short_observations, tmp_path, caplog):
    out = tmp_path / "run"
    shutil.copytree(demo_folder / "cache", out / "cache")
    # Another clip's detections put in place of this video's, its key file left as it was.
    shutil.copy(short_observations, out / "cache" / "observations.npz")
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        summary = run_capture(out, KINEMATICS_ONLY, video=DEMO_VIDEO, overlay=False)
    assert "detect" not in summary.cached_stages and summary.frames == 96
    assert "checksum" in caplog.text
    # Another video's cache folder, key files and all: its key names other bytes, so detection runs again.
    other = tmp_path / "other.mp4"
    other.write_bytes(DEMO_VIDEO.read_bytes() + b"\0")  # a different file that decodes to the same frames
    summary = run_capture(out, KINEMATICS_ONLY, video=other, overlay=False)
    assert "detect" not in summary.cached_stages


# ---- the run folder ---------------------------------------------------------------------------------------------

def test_a_second_run_into_a_locked_folder_is_refused(short_observations, tmp_path):
    tmp_path.joinpath(LOCK_FILE).write_text("")
    with open(tmp_path / LOCK_FILE, "r+") as held:  # another run holds the folder
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        held.write("4242")
        held.flush()
        with pytest.raises(OutputLocationError, match="another physmocap run .*4242.* writing into this folder"):
            run_capture(tmp_path, KINEMATICS_ONLY, observations=short_observations, overlay=False)
    assert not (tmp_path / "result.npz").exists()
    run_capture(tmp_path, KINEMATICS_ONLY, observations=short_observations, overlay=False)  # released: runs
    with locked_run_folder(tmp_path), locked_run_folder(tmp_path):  # one process may nest
        pass


def test_an_output_folder_that_is_a_file_is_refused(short_observations, tmp_path):
    target = tmp_path / "taken"
    target.write_text("")
    with pytest.raises(OutputLocationError, match="is a file"):
        run_capture(target, KINEMATICS_ONLY, observations=short_observations, overlay=False)


def test_partial_files_and_stale_outputs_are_removed(demo_folder, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(demo_folder, out)
    partial = [out / ".result.x1y2.partial.npz", out / "cache" / ".physics.q9.partial.npz"]
    for path in partial:
        path.write_bytes(b"half")
    (out / "overlay.mp4").write_bytes(b"an earlier run's overlay")
    summary = run_capture(out, KINEMATICS_ONLY, video=DEMO_VIDEO, overlay=False)
    assert not any(p.exists() for p in partial)
    assert not (out / "overlay.mp4").exists() and str(out / "overlay.mp4") in summary.removed_stale_outputs
    assert "overlay.mp4" not in (out / "report.html").read_text()
    assert json.loads((out / "summary.json").read_text())["files"] == summary.files
    assert summary.overlay_parts == 0


def _strict_json(path: Path):
    def refuse(token):
        raise AssertionError(f"{path.name} holds {token}, which strict JSON parsers reject")
    return json.loads(path.read_text(), parse_constant=refuse)


def test_every_json_file_of_a_run_is_strict_json(demo_folder, tmp_path):
    """The demo has no jump, so its video clock has no fall to measure: null, not NaN (summary.json), and so on
    for the metrics no frame defines (metrics.json, evaluate's file)."""
    out = tmp_path / "run"
    shutil.copytree(demo_folder, out)
    run_capture(out, KINEMATICS_ONLY, video=DEMO_VIDEO, overlay=False)
    write_evaluation(out / "evaluation.json", evaluate(out / "result.npz"))
    files = sorted(out.glob("*.json"))
    assert {p.name for p in files} >= {"summary.json", "metrics.json", "evaluation.json"}
    for path in files:
        _strict_json(path)
    assert _strict_json(out / "summary.json")["video_clock"]["fall"] is None


@pytest.mark.parametrize("parts", [1, 2])
def test_the_overlay_parts_setting_is_followed_and_recorded(demo_folder, tmp_path, parts):
    out = tmp_path / "run"
    shutil.copytree(demo_folder, out)
    summary = run_capture(out, KINEMATICS_ONLY.replace(None, overlay_parts=parts), video=DEMO_VIDEO)
    assert (out / "overlay.mp4").stat().st_size > 0
    assert json.loads((out / "summary.json").read_text())["overlay_parts"] == summary.overlay_parts == parts


@pytest.mark.parametrize("online", [False, True], ids=["offline", "online"])
def test_a_given_filming_rate_times_the_motion_and_the_overlay(demo_folder, tmp_path, online):
    """camera.fps (--fps): a slow-motion file's frames timed at the rate they were filmed at; detection cached at
    the file's own rate, reused offline and written so by the online stream."""
    stored = Observations.load(demo_folder / "cache" / "observations.npz").fps
    filmed = 2.5 * stored
    out = tmp_path / "run"
    if not online:
        shutil.copytree(demo_folder, out)
    summary = run_capture(out, KINEMATICS_ONLY.replace("camera", fps=filmed).replace(None, online=online),
                          video=DEMO_VIDEO)
    assert summary.fps == filmed and load_result(out / "result.npz")["fps"] == filmed
    assert ("detect" in summary.cached_stages) is not online
    assert Observations.load(out / "cache" / "observations.npz").fps == stored
    with av.open(str(out / "overlay.mp4")) as video:
        assert float(video.streams.video[0].average_rate) == pytest.approx(filmed)
    assert set(summary.video_clock) == {"arcs", "fall", "consistent_fps", "warning"}


# ---- determinism -------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("online", [False, True], ids=["offline", "online"])
def test_fresh_cached_and_observations_runs_agree(demo_folder, tmp_path, online):
    settings = Settings(online=online).replace("physics", method="none")
    fresh = demo_folder if not online else tmp_path / "fresh"
    if online:
        run_capture(fresh, settings, video=DEMO_VIDEO, overlay=False)
    expected = load_result(fresh / "result.npz")["joints_world"]
    # From the cached detections, the fit run again.
    cached = tmp_path / "cached"
    shutil.copytree(fresh / "cache", cached / "cache")
    for entry in ("kinematics.npz", "kinematics.key"):
        os.remove(cached / "cache" / entry)
    summary = run_capture(cached, settings, video=DEMO_VIDEO, overlay=False)
    assert summary.cached_stages == ["detect"]
    # From the cached detections as an observations file.
    observed = tmp_path / "observed"
    run_capture(observed, settings, observations=fresh / "cache" / "observations.npz", overlay=False)
    for folder in (cached, observed):
        gap = np.linalg.norm(load_result(folder / "result.npz")["joints_world"] - expected, axis=-1)
        assert gap.max() <= 1e-6, (folder.name, gap.max())
