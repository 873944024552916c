"""The command line end to end: the happy path on the shipped demo clip, and every kind of bad input with real
files, each answered by one clear sentence, a non-zero exit code, no traceback and no half-written result."""

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import DEMO_VIDEO
from physmocap.io.video import VideoWriter
from physmocap.motion import Observations
from physmocap.result import REQUIRED_KEYS, RESULT_POINTS, load_result
from test_bad_inputs import run_cli

pytestmark = pytest.mark.slow  # the command line on real clips


def physmocap(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "physmocap.cli", *map(str, args)], capture_output=True,
                          text=True, cwd=cwd, timeout=600)


def physmocap_in_process(*args):
    """The command line run in this process (no interpreter and torch start-up), as a CompletedProcess."""
    code, out, err = run_cli(*args)
    return subprocess.CompletedProcess(args, code, out, err)


def assert_clean_failure(proc, *words):
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    assert lines, "an error must say what went wrong"
    message = lines[-1]
    for word in words:
        assert word.lower() in message.lower(), message


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    proc = physmocap("capture", DEMO_VIDEO, "-o", out)
    assert proc.returncode == 0, proc.stderr
    return out, proc


def test_capture_writes_every_output(demo_run):
    out, proc = demo_run
    for name in ("result.npz", "motion.bvh", "overlay.mp4", "summary.json"):
        assert (out / name).is_file(), name
    result = load_result(out / "result.npz")
    T = len(result["qpos"])
    assert all(k in result for k in REQUIRED_KEYS)
    assert tuple(result["joint_names"][:20]) == RESULT_POINTS[:20]
    assert result["joints_world"].shape == (T, len(RESULT_POINTS), 3)
    assert result["contacts"].shape == (T, 4) and result["grf"].shape == (T, 4, 3)
    assert result["keypoints_2d"].shape == (T, 33, 3)
    # The world is Z up with the floor at z = 0: the soles sit near it, the head far above.
    names = list(result["joint_names"])
    soles = result["joints_world"][:, [names.index(n) for n in ("left_heel", "left_toe", "right_heel",
                                                                 "right_toe")], 2]
    assert abs(np.median(soles.min(axis=1))) < 0.05
    assert 1.3 < np.median(result["joints_world"][:, names.index("head"), 2]) < 1.8
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == T and summary["valid_frames"] > 0.9 * T
    assert summary["median_reprojection_error_percent_of_height"] < 2.0
    assert "median reprojection error" in proc.stdout and "results in" in proc.stdout


def test_rerun_reuses_cached_stages(demo_run):
    out, _ = demo_run
    proc = physmocap("capture", DEMO_VIDEO, "-o", out, "--no-overlay")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cached_stages"] == ["detect", "kinematics", "refine", "physics"]
    # A new fit setting re-runs the fit but not the detector.
    proc = physmocap("capture", DEMO_VIDEO, "-o", out, "--no-overlay", "--height", "1.80")
    assert json.loads((out / "summary.json").read_text())["cached_stages"] == ["detect"]
    assert abs(float(load_result(out / "result.npz")["body_height"]) - 1.80) < 1e-9


def test_observations_file_round_trip_and_online(demo_run, tmp_path):
    out, _ = demo_run
    proc = physmocap("capture", "--observations", out / "cache" / "observations.npz", "-o", tmp_path / "r",
                     "--online")
    assert proc.returncode == 0, proc.stderr
    assert "online" in proc.stdout
    assert (tmp_path / "r" / "result.npz").is_file() and not (tmp_path / "r" / "overlay.mp4").exists()


def test_observations_with_their_video_are_fitted_and_drawn_over_it(demo_run, tmp_path):
    out, _ = demo_run
    observations = Observations.load(out / "cache" / "observations.npz")
    moved = dataclasses.replace(observations, keypoints_2d=observations.keypoints_2d.copy())
    moved.keypoints_2d[..., 0] += 40.0  # the person 40 px to the right: not what the detector would find
    moved.save(tmp_path / "moved.npz")
    proc = physmocap_in_process("capture", DEMO_VIDEO, "--observations", tmp_path / "moved.npz", "-o", tmp_path / "r",
                                "--physics", "none")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["input"].endswith("moved.npz") and "detect" not in summary["stage_seconds"]
    assert (tmp_path / "r" / "overlay.mp4").is_file()
    np.testing.assert_allclose(load_result(tmp_path / "r" / "result.npz")["keypoints_2d"], moved.keypoints_2d,
                               atol=1e-4)

    short = observations.select(slice(None, -5))
    short.save(tmp_path / "short.npz")
    assert_clean_failure(physmocap_in_process("capture", DEMO_VIDEO, "--observations", tmp_path / "short.npz",
                                              "-o", tmp_path / "s"), "short.npz", "frames")
    assert not (tmp_path / "s" / "result.npz").exists()


def test_help_teaches_the_commands():
    proc = physmocap("--help")
    assert proc.returncode == 0
    for word in ("capture", "detect", "--online", "result.npz", "motion.bvh"):
        assert word in proc.stdout
    assert "--height" in physmocap("capture", "--help").stdout


def test_missing_video(tmp_path):
    assert_clean_failure(physmocap("capture", tmp_path / "nope.mp4", "-o", tmp_path / "o"), "nope.mp4", "no such")
    assert not (tmp_path / "o").exists()


def test_text_file_named_mp4(tmp_path):
    fake = tmp_path / "notes.mp4"
    fake.write_text("this is not a video\n" * 50)
    assert_clean_failure(physmocap("capture", fake, "-o", tmp_path / "o"), "notes.mp4", "video")
    assert not (tmp_path / "o").exists()


def test_empty_video(tmp_path):
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    assert_clean_failure(physmocap("capture", empty, "-o", tmp_path / "o"), "empty.mp4", "empty")


def test_truncated_video(tmp_path):
    cut = tmp_path / "cut.mp4"
    data = DEMO_VIDEO.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    proc = physmocap("capture", cut, "-o", tmp_path / "o")
    assert_clean_failure(proc, "cut.mp4", "truncated")
    assert not (tmp_path / "o" / "result.npz").exists()


def test_video_without_a_person(tmp_path):
    blank = tmp_path / "blank.mp4"
    rng = np.random.default_rng(0)
    with VideoWriter(blank, 10.0, 320, 240) as writer:
        for _ in range(8):
            writer.write(rng.integers(0, 40, size=(240, 320, 3), dtype=np.uint8))
    proc = physmocap("capture", blank, "-o", tmp_path / "o")
    assert_clean_failure(proc, "blank.mp4", "no person")
    assert not (tmp_path / "o" / "result.npz").exists()


def test_unreadable_observations_file(tmp_path):
    bad = tmp_path / "obs.npz"
    bad.write_bytes(b"PK\x03\x04 definitely not a zip archive")
    assert_clean_failure(physmocap("capture", "--observations", bad, "-o", tmp_path / "o"), "obs.npz")
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, keypoints_2d=np.zeros((4, 17, 3)))
    assert_clean_failure(physmocap("capture", "--observations", wrong, "-o", tmp_path / "o"), "wrong.npz")
    text = tmp_path / "text.npz"  # written by other code, with text where a number belongs
    np.savez(text, keypoints_2d=np.zeros((4, 33, 3)), landmarks_3d=np.zeros((4, 33, 3)), fps="thirty",
             image_size=[640, 480])
    assert_clean_failure(physmocap("capture", "--observations", text, "-o", tmp_path / "o"), "text.npz", "fps")


@pytest.mark.parametrize("args, words", [
    (["--height", "-1.7"], ["body.height", "-1.7"]),
    (["--mass", "0"], ["body.mass"]),
    (["--fov", "400"], ["camera.fov"]),
    (["--floor", "0,0,0,1"], ["floor"]),
    (["--person-box", "10,10,5,5"], ["person_box"]),
    (["--fps", "0"], ["camera.fps", "1 .. 1000 fps"]),
    (["--character-map", "map.toml"], ["map.toml", "--character RIG"]),  # a map with no character to map
])
def test_nonsense_settings(tmp_path, args, words):
    proc = physmocap_in_process("capture", DEMO_VIDEO, "-o", tmp_path / "o", *args)
    assert_clean_failure(proc, *words)
    assert not (tmp_path / "o").exists()


def test_train_contacts_on_bad_data_fails_with_one_sentence(tmp_path):
    """Before any training starts: no mocap/ folder, a mocap/ folder without BVH files, folders that hold none, a
    text file named .bvh."""
    out = tmp_path / "weights"
    train = ("train-contacts", "--data", tmp_path, "--out", out)
    assert_clean_failure(physmocap_in_process(*train), "no mocap/ folder")
    (tmp_path / "mocap" / "cmu_raw_cgspeed").mkdir(parents=True)
    assert_clean_failure(physmocap_in_process(*train), "no .bvh files")
    (tmp_path / "mocap" / "cmu_raw_cgspeed" / "01_01.bvh").write_text("not a motion capture file\n")
    assert_clean_failure(physmocap_in_process(*train, "--folders", "no_such_folder"), "no .bvh files in the folders",
                         "no_such_folder")
    assert_clean_failure(physmocap_in_process(*train), "01_01.bvh", "not a BVH")
    assert not out.exists()


def test_bad_settings_file(tmp_path):
    cfg = tmp_path / "s.toml"
    run = ("capture", DEMO_VIDEO, "-o", tmp_path / "o", "--config", cfg)
    cfg.write_text("[fit]\nweight_2d = 'heavy'\n")
    assert_clean_failure(physmocap_in_process(*run), "weight_2d")
    cfg.write_text("[fit\n")
    assert_clean_failure(physmocap_in_process(*run), "s.toml")
    cfg.write_text("[physics]\nfloor_tilt_rate = 500\n")  # deg/s, allowed 0.01 .. 90
    assert_clean_failure(physmocap_in_process(*run), "physics.floor_tilt_rate", "500")
    cfg.write_text("[physics]\nrotation_velocity_share = 2.0\n")  # a share, 0 .. 1
    assert_clean_failure(physmocap_in_process(*run), "physics.rotation_velocity_share", "2.0")
    cfg.write_text('[fit]\nangle_speed_huber_frames = "sometimes"\n')  # "running" or "all"
    assert_clean_failure(physmocap_in_process(*run), "fit.angle_speed_huber_frames", "sometimes", "running, all")


def test_online_capture_of_a_video_streams_and_caches(tmp_path):
    out = tmp_path / "live"
    proc = physmocap("capture", DEMO_VIDEO, "-o", out, "--online", "--no-overlay")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["online"] and summary["cached_stages"] == []
    proc = physmocap("capture", DEMO_VIDEO, "-o", out, "--online", "--no-overlay")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["physics"] == "physcap"  # the default online
    assert summary["cached_stages"] == ["detect", "kinematics", "physics"]
    result = load_result(out / "result.npz")
    assert np.abs(result["grf"]).sum() > 0 and result["grf"][..., 2].min() >= -1e-6  # feet push, never pull


def test_offline_physcap_tracks_the_refined_kinematics(demo_run, tmp_path):
    out, _ = demo_run
    obs = out / "cache" / "observations.npz"
    assert physmocap("capture", "--observations", obs, "-o", tmp_path / "p", "--no-overlay", "--physics",
                     "none").returncode == 0
    plain = load_result(tmp_path / "p" / "result.npz")  # the fit without physics
    proc = physmocap("capture", "--observations", obs, "-o", tmp_path / "p", "--physics", "physcap", "--no-overlay")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert "refine" in summary["stage_seconds"] and "floor" in summary["physics_report"]["refinement"]
    refined = load_result(tmp_path / "p" / "result.npz")
    # The physics' kinematic input is the B.4 motion: close to the plain fit, not equal to it.
    gap = np.linalg.norm(refined["joints_world_kinematic"] - plain["joints_world"], axis=-1)
    assert 0 < np.median(gap) < 0.1
    again = physmocap("capture", "--observations", obs, "-o", tmp_path / "p", "--physics", "physcap", "--no-overlay")
    assert again.returncode == 0, again.stderr
    assert json.loads((tmp_path / "p" / "summary.json").read_text())["cached_stages"] == ["kinematics", "refine",
                                                                                          "physics"]
    assert summary["physics_strayed_frames"] == [] and "strays" not in proc.stdout
    deviation = np.linalg.norm(refined["joints_world"] - refined["joints_world_kinematic"], axis=-1).mean(axis=1)
    np.testing.assert_allclose(refined["physics_deviation"], deviation)
    assert np.isfinite(summary["median_reprojection_error_final_px"]) and "after physics" in proc.stdout
    # The plain fit tracked instead; frames where physics strays from its input beyond a (here tiny) distance
    # are reported.
    config = tmp_path / "plain.toml"
    config.write_text("[physics]\nrefine_offline = false\nstray_distance = 0.02\n")
    unrefined = physmocap("capture", "--observations", obs, "-o", tmp_path / "p", "--physics", "physcap",
                          "--no-overlay", "--config", config)
    assert unrefined.returncode == 0, unrefined.stderr
    summary = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert "refine" not in summary["stage_seconds"] and "physics" not in summary["cached_stages"]
    unrefined_result = load_result(tmp_path / "p" / "result.npz")
    strayed = (unrefined_result["physics_deviation"] > 0.02) & unrefined_result["valid"]
    assert "warning: the physics motion strays more than 0.02 m" in unrefined.stdout
    ranges = [[int(x) for x in r.split("-")] for r in summary["physics_strayed_frames"]]
    assert ranges and sum(r[-1] - r[0] + 1 for r in ranges) == strayed.sum()
    np.testing.assert_allclose(unrefined_result["joints_world_kinematic"],
                               plain["joints_world"], atol=1e-6)


def test_export_command_writes_each_format_and_rejects_bad_input(demo_run, tmp_path):
    out, _ = demo_run
    for fmt, name in (("bvh", "motion.bvh"), ("glb", "motion.glb"), ("opensim", "grf.mot")):
        proc = physmocap("export", out / "result.npz", "--to", fmt, "-o", tmp_path / fmt)
        assert proc.returncode == 0, proc.stderr
        assert (tmp_path / fmt / name).is_file()
    proc = physmocap("export", out / "result.npz", "--to", "bvh", "--units", "furlongs", "-o", tmp_path / "x")
    assert_clean_failure(proc, "units")
    assert_clean_failure(physmocap("export", tmp_path / "none.npz", "--to", "glb"), "none.npz")


@pytest.mark.parametrize("key, change", [
    ("fps", lambda r: np.array("thirty")),
    ("joints_world", lambda r: r["joints_world"].astype(str)),
    ("joints_world", lambda r: np.full_like(r["joints_world"], np.nan)),
    ("qpos", lambda r: r["qpos"][:5]),
    ("grf", lambda r: r["grf"][:, :2]),
    ("body_mass", lambda r: np.array(-70.0)),
    ("body_lengths", lambda r: np.array("{not json")),
])
def test_a_result_file_edited_by_other_code_is_refused_in_one_sentence(demo_run, tmp_path, key, change):
    result = dict(np.load(demo_run[0] / "result.npz", allow_pickle=False))
    result[key] = change(result)
    edited = tmp_path / "edited.npz"
    np.savez(edited, **result)
    for command in (["export", edited, "--to", "bvh", "-o", tmp_path / "x"], ["evaluate", edited]):
        proc = physmocap_in_process(*command)
        assert proc.returncode == 2, proc.stderr  # bad input, not an internal error
        assert_clean_failure(proc, "edited.npz", key)


def test_trajectory_optimisation_physics(demo_run, tmp_path):
    out, _ = demo_run
    whole = Observations.load(out / "cache" / "observations.npz")
    frames = 48  # the first two seconds: the command line's part, not the solver's (test_trajopt.py)
    obs = tmp_path / "first_frames.npz"
    whole.select(slice(frames)).save(obs)
    proc = physmocap("capture", "--observations", obs, "-o", tmp_path / "t", "--physics", "trajopt")
    assert proc.returncode == 0, proc.stderr
    result = load_result(tmp_path / "t" / "result.npz")
    assert str(result["physics"]) == "trajopt"
    converged = ~result["physics_fallback"]
    assert converged.mean() > 0.9
    # pushing only, to IPOPT's tolerance (a millinewton)
    assert result["grf"][converged][..., 2].min() >= -1e-3 and result["grf"][converged].any()
    # Every window's solver report in summary.json and in the terminal.
    report = json.loads((tmp_path / "t" / "summary.json").read_text())["physics_report"]
    assert report["converged_frames"] == converged.sum() and report["summary"] in proc.stdout
    kept = np.zeros(len(converged), int)
    for window in report["windows"]:
        kept[window["start"]:window["keep"]] += 1
        assert window["chosen"] == "dynamics" and [s["name"] for s in window["stages"]][:2] == ["fit", "dynamics"]
        assert f"frames {window['start']}-{window['keep'] - 1} (solved to {window['stop']})" in proc.stdout
        assert all(s["iterations"] > 0 and np.isfinite(s["objective"]) for s in window["stages"])
    assert (kept == 1).all()  # the windows' kept parts tile the clip
    # The same inputs and settings again: the stage comes from its cache, with the same motion and reports.
    again = physmocap("capture", "--observations", obs, "-o", tmp_path / "t", "--physics", "trajopt")
    assert again.returncode == 0, again.stderr
    assert "physics" in json.loads((tmp_path / "t" / "summary.json").read_text())["cached_stages"]
    assert np.array_equal(load_result(tmp_path / "t" / "result.npz")["qpos"], result["qpos"])
    assert report["summary"] in again.stdout
    # A changed setting recomputes; one IPOPT iteration converges nowhere, which must be loud: every frame flagged
    # and kinematic, no forces handed out, said in the terminal and summary.json.
    config = tmp_path / "one_iteration.toml"
    config.write_text("[trajopt]\nmax_iterations = 1\n")
    failed = physmocap("capture", "--observations", obs, "-o", tmp_path / "t", "--physics", "trajopt",
                       "--config", config)
    assert failed.returncode == 0, failed.stderr
    summary = json.loads((tmp_path / "t" / "summary.json").read_text())
    assert "physics" not in summary["cached_stages"] and summary["physics_report"]["converged_frames"] == 0
    assert summary["physics_fallback_frames"] == [f"0-{len(converged) - 1}"]
    result = load_result(tmp_path / "t" / "result.npz")
    assert result["physics_fallback"].all() and not result["grf"].any()
    assert np.array_equal(result["qpos"], result["qpos_kinematic"])
    assert "NOT converged" in failed.stdout and "did not converge" in failed.stdout
    assert_clean_failure(physmocap("capture", "--observations", obs, "-o", tmp_path / "u", "--physics", "trajopt",
                                   "--online"), "trajopt")


def test_train_contacts_passes_the_foot_keypoints(tmp_path, monkeypatch):
    """`--foot-keypoints` reaches the synthetic data's settings; the default is the shipped weights' "mediapipe"."""
    from physmocap.contacts import train

    seen = []
    monkeypatch.setattr(train, "train_contacts", lambda data, out, seed, settings: seen.append(settings))
    (tmp_path / "mocap").mkdir()
    base = ("train-contacts", "--data", tmp_path, "--out", tmp_path / "w")
    assert physmocap_in_process(*base).returncode == 0
    assert physmocap_in_process(*base, "--foot-keypoints", "sole").returncode == 0
    assert [s.synthetic.foot_keypoints for s in seen] == ["mediapipe", "sole"] and seen[0].folders is None
    assert_clean_failure(physmocap_in_process(*base, "--foot-keypoints", "heel"), "foot-keypoints")


@pytest.mark.parametrize("method, blended", [("physcap", True), ("trajopt", False)])
def test_unexplained_frames_note_says_what_each_method_hands_back(capsys, method, blended):
    from types import SimpleNamespace

    from physmocap.cli import _note_physics_floor_height

    summary = SimpleNamespace(physics=method, physics_unexplained_frame_count=3, physics_unexplained_frames=["4-6"],
                              floor=None, body_height_note="height: 1.70 m")
    _note_physics_floor_height(summary)
    note = capsys.readouterr().out.splitlines()[0]
    assert "3 frames (4-6)" in note and "the kinematic motion is kept there" in note
    assert ("blended" in note) == blended


@pytest.mark.parametrize("source, says", [("posture", "disagrees with the person's own vertical by 41 degrees"),
                                          ("unseen feet", "the feet are outside the picture on every frame")])
def test_an_untrusted_floor_says_why_in_one_line(capsys, source, says):
    from types import SimpleNamespace

    from physmocap.cli import _note_physics_floor_height

    summary = SimpleNamespace(physics="physcap", physics_unexplained_frame_count=0, body_height_note="height",
                              floor={"trusted": False, "source": source, "prior_disagreement_degrees": 41.0})
    _note_physics_floor_height(summary)
    warning = capsys.readouterr().out.splitlines()[0]
    assert warning.startswith("warning: ") and says in warning and "give --floor" in warning
