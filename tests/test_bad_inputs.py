"""Issue 22's table of bad inputs, each made here as a real file and run through the command line in-process:
the exit code is the documented one (physmocap.errors), stderr holds no traceback, and nothing half-written is
left in the output folder. Also: every writer holds non-finite frames and names them, and progress off a
terminal is plain lines."""

from __future__ import annotations

import contextlib
import io
import os
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import DEMO_VIDEO
from physmocap.body.model import build_body_model, template_lengths
from physmocap.camera import Camera
from physmocap.cli import _join_negative_number_lists, _progress_factory, main
from physmocap.errors import EXIT_CODES
from test_fit import observe, walking_motion

TRUE_FLOOR = "0,-0.990268,0.139173,1.188322"  # the camera below: 1.2 m high, pitched 8 degrees down


def scene_camera() -> Camera:
    """A 1280x720 camera 4 m in front of the walker, 1.2 m high, looking 8 degrees down (as in test_fit)."""
    pitch = np.radians(8)
    R = np.array([[1, 0, 0], [0, -np.sin(pitch), -np.cos(pitch)], [0, np.cos(pitch), -np.sin(pitch)]])
    return Camera.from_settings((1280, 720), fov=60).with_extrinsics(R, -R @ np.array([0.5, -4.0, 1.2]))


def observation_arrays(frames: int) -> dict[str, np.ndarray]:
    """The arrays of an observations file of a person walking, seen perfectly (float64, no camera_K)."""
    body = build_body_model(template_lengths(1.75), 72.0)
    obs = observe(body, walking_motion(body, max(frames, 1)), scene_camera())
    return dict(keypoints_2d=obs.keypoints_2d[:frames], landmarks_3d=obs.landmarks_3d[:frames], fps=np.float64(30),
                image_size=np.array([1280, 720]))


def run_cli(*argv) -> tuple[int, str, str]:
    """main(argv) in-process: exit code, stdout, stderr."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def assert_clean(code: int, err: str, out_dir=None, expected=None) -> None:
    """A documented exit code, no traceback, no partial file and, after a failure, no result in `out_dir`."""
    assert code in EXIT_CODES, (code, err)
    assert "Traceback" not in err, err
    if expected is not None:
        assert code in expected, (code, err)
    if code != 0:
        lines = [line for line in err.splitlines() if line.strip()]
        assert lines and lines[-1].startswith("physmocap"), err
    if out_dir is not None and os.path.isdir(out_dir):
        leftovers = [p for p in os.listdir(out_dir) if ".partial" in p]
        assert not leftovers, leftovers
        if code != 0:
            assert not os.path.exists(os.path.join(out_dir, "result.npz")), err


def save_obs(path, frames=30, **changes):
    arrays = {**observation_arrays(frames), **changes}
    np.savez(path, **arrays)
    return path


def _one_frame_video(tmp_path, frames):
    from physmocap.io.video import probe_video, trim_video

    fps = probe_video(DEMO_VIDEO).fps
    path = tmp_path / f"v{frames}.mp4"
    trim_video(DEMO_VIDEO, path, 1.0, frames / fps, 320)
    return path


def _half_nan(tmp_path):
    arrays = observation_arrays(30)
    hidden = np.random.default_rng(0).random(arrays["keypoints_2d"].shape[:2]) < 0.5
    for key in ("keypoints_2d", "landmarks_3d"):
        arrays[key] = np.where(hidden[..., None], np.nan, arrays[key])
    return save_obs(tmp_path / "holes.npz", **arrays)


def _no_torso_first(tmp_path):
    arrays = observation_arrays(30)
    for key in ("keypoints_2d", "landmarks_3d"):
        arrays[key][0, 11:25] = np.nan
    return save_obs(tmp_path / "no_torso.npz", **arrays)


def _far_keypoints(tmp_path):
    arrays = observation_arrays(30)
    arrays["keypoints_2d"][..., :2] *= 1000
    return save_obs(tmp_path / "far.npz", **arrays)


def _damaged_cache(tmp_path, name, damage):
    obs = save_obs(tmp_path / "obs.npz", frames=8)
    out = tmp_path / "out"
    code, _, err = run_cli("capture", "--observations", obs, "-o", out, "--physics", "physcap", "--no-overlay")
    assert code == 0, err
    cache = out / "cache" / f"{name}.npz"
    data = cache.read_bytes()
    cache.write_bytes({"truncated": data[: len(data) // 2], "empty": b""}[damage])
    return obs


def _symlink_loop(tmp_path) -> Path:
    """A link that points at another that points back (resolving it fails)."""
    (tmp_path / "loop_a").symlink_to(tmp_path / "loop_b")
    (tmp_path / "loop_b").symlink_to(tmp_path / "loop_a")
    return tmp_path / "loop_a"


def _text(path, text):
    path.write_text(text)
    return path


def _file(tmp_path, name="in_the_way"):
    path = tmp_path / name
    path.write_text("a file")
    return path


def _result(tmp_path):
    obs = save_obs(tmp_path / "obs.npz", frames=5)
    code, _, err = run_cli("capture", "--observations", obs, "-o", tmp_path / "run", "--physics", "none",
                           "--no-overlay")
    assert code == 0, err
    return tmp_path / "run" / "result.npz"


ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
# (case, make(tmp_path) -> argv, expected exit codes, words the last stderr line holds)
CASES = [
    ("-o is an existing file (capture)",
     lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", _file(p)], {4}, ["in_the_way", "file"]),
    ("-o is an existing file (export)",
     lambda p: ["export", _result(p), "--to", "bvh", "-o", _file(p)], {4}, ["in_the_way"]),
    ("-o below a file", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", _file(p) / "run"],
     {4}, ["in_the_way"]),
    ("-o under /proc", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", "/proc/physmocap/run"],
     {4}, ["/proc/physmocap"]),
    ("-o under /proc (export)", lambda p: ["export", _result(p), "--to", "glb", "-o", "/proc/physmocap"], {4}, []),
    ("detect -o under /proc", lambda p: ["detect", DEMO_VIDEO, "-o", "/proc/physmocap.npz"], {4}, []),
    ("-o inside a symlink loop (capture)",
     lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", _symlink_loop(p) / "run"], {4}, ["loop"]),
    ("-o inside a symlink loop (batch)",
     lambda p: ["batch", save_obs(p / "o.npz"), "-o", _symlink_loop(p) / "runs"], {4}, ["loop"]),
    ("a video name longer than any file system allows",
     lambda p: ["capture", p / ("v" * 5000 + ".mp4"), "-o", p / "out"], {2}, ["vvv", "too long"]),
    ("live from a network stream", lambda p: ["live", "rtsp://127.0.0.1:1/cam"], {2}, ["rtsp://", "camera index"]),
    ("capture of a URL", lambda p: ["capture", "https://example.com/v.mp4", "-o", p / "out"], {2}, ["url"]),
    ("a batch list with a NUL character", lambda p: ["batch", _text(p / "l.txt", "a.mp4\nb\0.mp4\n"), "-o",
                                                     p / "out"], {2}, ["l.txt", "NUL"]),
    # root writes into a folder without write permission anyway: then the run succeeds (exit 0)
    ("-o folder without write permission",
     lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", _read_only_folder(p) / "run",
                "--physics", "none", "--no-overlay"], {0, 4} if ROOT else {4}, []),
    ("1-frame observations", lambda p: ["capture", "--observations", save_obs(p / "o.npz", 1), "-o", p / "out",
                                        "--physics", "none"], {0}, []),
    ("2-frame observations, trajopt", lambda p: ["capture", "--observations", save_obs(p / "o.npz", 2), "-o",
                                                 p / "out", "--physics", "trajopt"], {0}, []),
    ("1-frame observations, trajopt", lambda p: ["capture", "--observations", save_obs(p / "o.npz", 1), "-o",
                                                 p / "out", "--physics", "trajopt"], {3}, ["single frame"]),
    ("1-frame observations, online", lambda p: ["capture", "--observations", save_obs(p / "o.npz", 1), "-o",
                                                p / "out", "--online"], {0}, []),
    ("0-frame observations", lambda p: ["capture", "--observations", save_obs(p / "o.npz", 0), "-o", p / "out"],
     {2}, ["no frames"]),
    ("repeated flags for other frames", lambda p: ["capture", "--observations",
                                                   save_obs(p / "o.npz", repeated=np.zeros(29, bool)), "-o", p / "out"],
     {2}, ["o.npz", "repeated", "30 frames"]),
    ("every frame a repeat", lambda p: ["capture", "--observations", save_obs(p / "o.npz", repeated=np.ones(30, bool)),
                                        "-o", p / "out", "--physics", "physcap", "--no-overlay"], {0}, []),
    ("1-frame video", lambda p: ["capture", _one_frame_video(p, 1), "-o", p / "out", "--physics", "none"], {0}, []),
    ("2-frame video", lambda p: ["capture", _one_frame_video(p, 2), "-o", p / "out", "--no-overlay"], {0}, []),
    ("live on a 1-frame video", lambda p: ["live", _one_frame_video(p, 1), "-o", p / "out", "--as-fast-as-possible"],
     {0}, []),
    ("NaN for half the landmarks", lambda p: ["capture", "--observations", _half_nan(p), "-o", p / "out",
                                              "--physics", "physcap", "--no-overlay"], {0}, []),
    ("no torso on the first frame",
     lambda p: ["capture", "--observations", _no_torso_first(p), "-o", p / "out", "--physics", "none"], {0}, []),
    ("--floor with NaN", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out",
                                    "--floor", "nan,-1,0,1.2"], {2}, ["finite"]),
    ("--floor vertical plane", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out",
                                          "--floor", "1,0,0,2"], {2}, ["vertical"]),
    ("--floor wall facing the camera", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o",
                                                  p / "out", "--floor", "0,0,-1,4"], {2}, ["floor"]),
    ("--floor normal flipped", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out",
                                          "--floor", "-0,1,0,-1.415"], {2}, ["upside down"]),
    ("--floor normal flipped, on a video", lambda p: ["capture", _one_frame_video(p, 2), "-o", p / "out",
                                                      "--floor", "0,1,0,-1.415"], {2}, ["upside down"]),
    ("--floor normal flipped, on a video captured online",
     lambda p: ["capture", _one_frame_video(p, 3), "-o", p / "out", "--online", "--floor", "0,1,0,-1.415"], {2},
     ["upside down"]),
    ("--floor 4 m below the feet", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out",
                                              "--floor", "0,-1,0,5"], {2}, ["above"]),
    ("--floor negative first number as written",
     lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out", "--floor",
                "-0.0001,-0.990268,0.139173,1.188322",
                "--physics", "none", "--no-overlay"], {0}, []),
    ("keypoints far outside the image", lambda p: ["capture", "--observations", _far_keypoints(p), "-o", p / "out"],
     {2}, ["outside"]),
    ("settings file: floor of text", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out",
                                                "--config", _toml(p, '[camera]\nfloor = ["a", 1, 2, 3]\n')],
     {2}, ["camera.floor"]),
    ("settings file: NaN height", lambda p: ["capture", "--observations", save_obs(p / "o.npz"), "-o", p / "out",
                                             "--config", _toml(p, "[body]\nheight = nan\n")], {2}, ["body.height"]),
] + [
    pytest.param(f"damaged cache: {damage} {name}.npz",
                 lambda p, name=name, damage=damage: ["capture", "--observations", _damaged_cache(p, name, damage),
                                                      "-o", p / "out", "--physics", "physcap", "--no-overlay"], {0}, [])
    for name in ("kinematics", "refined", "physics") for damage in ("truncated", "empty")
]


def _read_only_folder(tmp_path):
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o500)
    return folder


def _toml(tmp_path, text):
    path = tmp_path / "settings.toml"
    path.write_text(text)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("case, make, expected, words", CASES, ids=[
    c.values[0] if hasattr(c, "values") else c[0] for c in CASES])
def test_bad_input_ends_in_one_sentence(tmp_path, case, make, expected, words):
    argv = make(tmp_path)
    out_dir = argv[argv.index("-o") + 1] if "-o" in argv else None
    code, _, err = run_cli(*argv)
    assert_clean(code, err, out_dir, expected)
    if code != 0:
        last = err.strip().splitlines()[-1]
        for word in words:
            assert str(word).lower() in last.lower(), last


@pytest.mark.slow
def test_the_true_floor_given_with_a_negative_number_passes_the_checks(tmp_path):
    obs = save_obs(tmp_path / "o.npz")
    code, _, err = run_cli("capture", "--observations", obs, "-o", tmp_path / "out", "--physics", "none",
                           "--no-overlay", "--floor", TRUE_FLOOR)
    assert code == 0, err
    result = np.load(tmp_path / "out" / "result.npz")
    assert np.allclose(result["floor"], np.array(TRUE_FLOOR.split(","), float), atol=1e-6)


def test_negative_number_lists_join_their_option():
    assert _join_negative_number_lists(["capture", "--floor", "-0.1,1,0,2", "-o", "x"]) == [
        "capture", "--floor=-0.1,1,0,2", "-o", "x"]
    assert _join_negative_number_lists(["--person-box", "-5,0,10,10"]) == ["--person-box=-5,0,10,10"]
    assert _join_negative_number_lists(["--floor", "--online"]) == ["--floor", "--online"]


def test_an_unexpected_error_becomes_a_sentence_and_a_crash_log(tmp_path, monkeypatch):
    import physmocap.cli as cli

    def broken(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setitem(cli.COMMANDS, "capture", broken)
    out = tmp_path / "run"
    out.mkdir()
    code, _, err = run_cli("capture", "--observations", tmp_path / "x.npz", "-o", out)
    assert code == 1 and "Traceback" not in err and "bug" in err
    logs = list(out.glob("physmocap-crash-*.log"))
    assert len(logs) == 1 and str(logs[0]) in err
    assert "Traceback" in logs[0].read_text() and "ZeroDivisionError: a bug" in logs[0].read_text()


def test_interrupt_exits_130(tmp_path, monkeypatch):
    import physmocap.cli as cli

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setitem(cli.COMMANDS, "capture", interrupted)
    code, _, err = run_cli("capture", "--observations", tmp_path / "x.npz")
    assert code == 130 and "interrupted" in err and "Traceback" not in err


def test_usage_errors_and_help_return_codes_in_process(capsys):
    assert main(["capture", "--bogus"]) == 2
    assert main(["--help"]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_plain_progress_lines_off_a_terminal(monkeypatch):
    import physmocap.cli as cli

    clock = iter([0.0, 1.0, 6.0, 7.0, 12.5, 13.0])
    monkeypatch.setattr(cli.time, "monotonic", lambda: next(clock))
    stream = io.StringIO()
    update = _progress_factory(terminal=False, stream=stream, interval=5.0)("fit", 100)
    for done in (10, 40, 50, 80, 100):
        update(done, 100)
    lines = stream.getvalue().splitlines()
    # 1 s: too soon; 6 s: a line; 7 s: too soon; 12.5 s: a line; 13 s: the end
    assert [re.sub(r", [\d.]+ frames/s", "", line) for line in lines] == [
        "physmocap: fit: 40/100 frames", "physmocap: fit: 80/100 frames", "physmocap: fit: 100/100 frames, done"]
    assert "6.7 frames/s" in lines[0]


# Writers: a NaN or infinite frame is held at the last finite frame and named in a warning.

@pytest.fixture(scope="module")
def result_with_holes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("holes")
    obs = save_obs(tmp / "o.npz", 6)
    code, _, err = run_cli("capture", "--observations", obs, "-o", tmp / "run", "--physics", "none", "--no-overlay")
    assert code == 0, err
    from physmocap.result import load_result

    result = load_result(tmp / "run" / "result.npz")
    for key in ("qpos", "joints_world", "joints_world_kinematic", "grf"):
        result[key] = np.array(result[key], float)
        result[key][2] = np.nan
        result[key][4] = np.inf
    return result


@pytest.mark.parametrize("writer", ["result", "bvh", "glb", "opensim", "viewer", "report"])
def test_writers_hold_non_finite_frames_and_name_them(result_with_holes, tmp_path, caplog, writer):
    from physmocap.export import EXPORTERS
    from physmocap.result import load_result, save_result
    from physmocap.viz.report import write_report
    from physmocap.viz.viewer import write_viewer

    result = result_with_holes
    if writer == "result":
        save_result(tmp_path / "result.npz", result)
        saved = load_result(tmp_path / "result.npz")
        for key in ("qpos", "joints_world", "grf"):
            assert np.isfinite(saved[key]).all()
            assert np.array_equal(saved[key][2], saved[key][1]) and np.array_equal(saved[key][4], saved[key][3])
    elif writer == "viewer":
        write_viewer(result, tmp_path / "viewer.html", video=None)
        assert "NaN" not in (tmp_path / "viewer.html").read_text().split("</script>")[0][-2000:]
    elif writer == "report":
        write_report(tmp_path, result)
        assert (tmp_path / "report.html").is_file() and (tmp_path / "plots" / "grf.png").is_file()
    else:
        files = EXPORTERS[writer](result, tmp_path)
        for path in files.values():
            text = open(path, "rb").read()
            if path.endswith((".bvh", ".trc", ".mot")):
                assert not re.search(rb"\b(nan|inf)\b", text, re.IGNORECASE), path
    assert "frames 2, 4 hold non-finite values" in caplog.text, caplog.text


@pytest.mark.parametrize("name, words", [("EROFS", "read-only"), ("ENOSPC", "disk is full"),
                                         ("EACCES", "no permission")])
def test_write_failures_of_the_output_folder_are_exit_4(tmp_path, monkeypatch, name, words):
    """A read-only file system, a full disk, no permission (which root cannot meet here) on the probe file, as
    the file system reports them."""
    import errno
    from pathlib import Path

    code = getattr(errno, name)

    def refuse(self, data):
        raise OSError(code, os.strerror(code), str(self))

    monkeypatch.setattr(Path, "write_bytes", refuse)
    obs = tmp_path / "o.npz"
    np.savez(obs, **observation_arrays(3))
    exit_code, _, err = run_cli("capture", "--observations", obs, "-o", tmp_path / "out")
    assert exit_code == 4 and words in err and str(tmp_path / "out") in err, err


def test_a_write_failure_during_the_run_is_exit_4(tmp_path, monkeypatch):
    import errno

    import physmocap.pipeline as pipeline

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "out" / "result.npz"))

    monkeypatch.setattr(pipeline, "save_result", full)
    obs = tmp_path / "o.npz"
    np.savez(obs, **observation_arrays(3))
    code, _, err = run_cli("capture", "--observations", obs, "-o", tmp_path / "out", "--physics", "none",
                           "--no-overlay")
    assert code == 4 and "result.npz" in err and "disk is full" in err, err


def test_live_without_an_output_folder_says_nothing_is_saved(tmp_path):
    code, _, err = run_cli("live", _one_frame_video(tmp_path, 3), "--as-fast-as-possible")
    assert code == 0 and "nothing will be saved" in err and "Traceback" not in err


def test_an_online_start_on_a_frame_too_little_seen_for_depth_is_placed_by_the_next(tmp_path):
    """The online warm-up's first frame shows one point: its depth (the skeleton's spread against the picture's)
    cannot be measured, the next frame's can. The start takes the next frame's depth (it took the unmeasured one,
    and every pose came out NaN)."""
    arrays = observation_arrays(6)
    arrays["keypoints_2d"][0, :, 2] = 0.0
    arrays["keypoints_2d"][0, 23, 2] = 0.9  # the left hip alone
    np.savez(tmp_path / "obs.npz", **arrays)
    code, _, err = run_cli("capture", "--observations", tmp_path / "obs.npz", "-o", tmp_path / "run", "--online",
                           "--physics", "none", "--no-overlay")
    assert_clean(code, err, tmp_path / "run", expected=(0,))
    from physmocap.result import load_result

    assert np.isfinite(load_result(tmp_path / "run" / "result.npz")["qpos"]).all()
