"""`physmocap batch` end to end on real files: a short clip, an observations file and a text file named .mp4,
through the process pool and through a local Ray; the same runs as `capture` gives, the broken input reported
and the batch finished; an interrupted batch resumed without redoing a finished run. Also the input expansion."""

import csv
import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import DEMO_VIDEO
from physmocap.batch import expand_inputs
from physmocap.errors import InputError
from physmocap.io.video import VideoWriter, iter_frames, probe_video
from physmocap.result import load_result

pytestmark = pytest.mark.slow  # batches of whole captures

FAST = ("--physics", "none", "--no-overlay")
CLIP_FRAMES = 40


def physmocap(*args, **kwargs):
    return subprocess.run([sys.executable, "-m", "physmocap.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=600, **kwargs)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """clip.mp4 (the demo's first 40 frames), obs.npz (its detections), broken.mp4 (text), and what `capture`
    writes for the two good ones."""
    folder = tmp_path_factory.mktemp("inputs")
    clip = folder / "clip.mp4"
    info = probe_video(DEMO_VIDEO)
    with VideoWriter(clip, info.fps, info.width, info.height) as writer:
        for index, frame in iter_frames(DEMO_VIDEO):
            if index == CLIP_FRAMES:
                break
            writer.write(frame)
    broken = folder / "broken.mp4"
    broken.write_text("this is not a video\n" * 50)
    reference = tmp_path_factory.mktemp("reference")
    proc = physmocap("capture", clip, "-o", reference / "clip", *FAST)
    assert proc.returncode == 0, proc.stderr
    obs = folder / "obs.npz"
    shutil.copy(reference / "clip" / "cache" / "observations.npz", obs)
    proc = physmocap("capture", "--observations", obs, "-o", reference / "obs", *FAST)
    assert proc.returncode == 0, proc.stderr
    return dict(clip=clip, obs=obs, broken=broken, reference=reference)


def read_rows(out: Path) -> dict[str, dict]:
    with open(out / "batch.csv", newline="") as f:
        return {row["name"]: row for row in csv.DictReader(f)}


def assert_batch_complete(out: Path, inputs: dict, proc) -> None:
    assert proc.returncode == 1, proc.stderr  # some input failed, the batch finished
    assert "Traceback" not in proc.stderr
    rows = read_rows(out)
    assert list(rows) == ["clip", "obs", "broken"]
    broken = rows["broken"]
    assert broken["status"] == "failed" and broken["exit_status"] == "2"
    assert broken["reason"] == f"{inputs['broken']}: not a readable video file."
    assert broken["reason"] in proc.stdout
    for name in ("clip", "obs"):
        row = rows[name]
        assert row["status"] == "done" and row["exit_status"] == "0" and row["reason"] == ""
        assert int(row["frames"]) == CLIP_FRAMES and 0 < int(row["valid_frames"]) <= CLIP_FRAMES
        assert row["physics"] == "none" and float(row["wall_seconds"]) > 0
        assert row["fps_by_jumps"] == ""  # no jump says the clip's rate is wrong (kinematics.clock)
        for field in ("reprojection_error_px", "skate_percent", "penetration_percent", "mean_acceleration"):
            assert np.isfinite(float(row[field])), field
        expected = load_result(inputs["reference"] / name / "result.npz")
        got = load_result(out / name / "result.npz")
        assert set(got) == set(expected)
        for key in set(expected) - {"stage_seconds"}:  # everything but the timings
            assert np.array_equal(got[key], expected[key]), key
        assert json.loads((out / name / "summary.json").read_text())["frames"] == CLIP_FRAMES
    index = (out / "index.html").read_text()
    for link in ("clip/report.html", "clip/viewer.html", "obs/report.html", "obs/viewer.html"):
        assert f'href="{link}"' in index
    assert "not a readable video file" in index
    assert not list(out.rglob("*.partial*"))


def test_process_pool_batch_equals_capture_and_isolates_a_broken_input(inputs, tmp_path):
    out = tmp_path / "batch"
    proc = physmocap("batch", inputs["clip"], inputs["obs"], inputs["broken"], "-o", out, "--workers", "2", *FAST)
    assert_batch_complete(out, inputs, proc)
    assert "batch: 3/3 inputs (1 failed), 80/80 frames" in proc.stderr  # the plain line when not a terminal


def test_ray_batch_equals_capture_and_isolates_a_broken_input(inputs, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "batch"
    proc = physmocap("batch", inputs["clip"], inputs["obs"], inputs["broken"], "-o", out, "--ray", "--workers",
                     "2", *FAST)
    assert_batch_complete(out, inputs, proc)


@pytest.mark.parametrize("address", ["127.0.0.1:1", "no-such-host.invalid:6379", "127.0.0.1:port"])
def test_a_cluster_address_nobody_answers_at_is_refused_at_once(inputs, tmp_path, address):
    """Ray itself retries an address for minutes; a batch checks it first and stops with one sentence."""
    pytest.importorskip("ray")
    proc = physmocap("batch", inputs["obs"], "-o", tmp_path / "batch", "--ray", address, *FAST)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith(f"physmocap: error: --ray: could not start or reach "
                                                            f"the Ray cluster at {address}")


def test_interrupted_batch_resumes_and_redoes_no_finished_run(inputs, tmp_path):
    out = tmp_path / "batch"
    more = tmp_path / "more.npz"
    shutil.copy(inputs["obs"], more)
    listing = tmp_path / "inputs.txt"
    listing.write_text(f"# two observations files and a clip\n{inputs['obs']}\nmore.npz\n\n{inputs['clip']}\n")
    command = [sys.executable, "-m", "physmocap.cli", "batch", listing, "-o", out, "--workers", "1", *FAST]
    # Ctrl-C as on a terminal: a test run in the background (a shell's `&`) would hand SIGINT on ignored.
    batch = subprocess.Popen(list(map(str, command)), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 300
    while not list(out.glob("*/batch.json")) and batch.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    batch.send_signal(signal.SIGINT)  # Ctrl-C once the first run finished
    _, stderr = batch.communicate(timeout=120)
    assert batch.returncode == 130, stderr
    assert "interrupted" in stderr and "Traceback" not in stderr
    finished = {p.parent.name: p.parent / "result.npz" for p in out.glob("*/batch.json")}
    assert finished and len(finished) < 3
    for summary in out.glob("*/summary.json"):
        json.loads(summary.read_text())  # complete, never half-written
    assert not list(out.rglob("*.partial*"))
    rows = read_rows(out)
    assert sum(row["status"] == "done" for row in rows.values()) == len(finished)
    assert sum(row["status"] == "pending" for row in rows.values()) == 3 - len(finished)
    written = {name: path.stat().st_mtime_ns for name, path in finished.items()}

    proc = physmocap("batch", listing, "-o", out, "--workers", "1", *FAST)
    assert proc.returncode == 0, proc.stderr
    assert f"({len(finished)} finished by an earlier run, skipped)" in proc.stdout
    rows = read_rows(out)
    assert [row["status"] for row in rows.values()] == ["done"] * 3
    for name, mtime in written.items():
        assert rows[name]["resumed"] == "1"
        assert (out / name / "result.npz").stat().st_mtime_ns == mtime  # not redone
    # Other settings: nothing counts as finished; every run is redone.
    proc = physmocap("batch", listing, "-o", out, "--workers", "1", "--height", "1.80", *FAST)
    assert proc.returncode == 0 and "earlier run" not in proc.stdout
    assert all(abs(float(load_result(out / n / "result.npz")["body_height"]) - 1.80) < 1e-9 for n in rows)


def test_inputs_expand_folders_and_lists_into_unique_names(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b" / "deep").mkdir(parents=True)
    for path in ("a/walk.mp4", "b/deep/walk.MOV", "b/notes.txt.bak", "a/.hidden.mp4", "b/run.npz"):
        (tmp_path / path).write_bytes(b"x")
    out = tmp_path / "a" / "runs"  # run folders inside an input folder are never inputs
    (out / "walk").mkdir(parents=True)
    (out / "walk" / "overlay.mp4").write_bytes(b"x")
    listing = tmp_path / "b" / "list.txt"
    listing.write_text("run.npz\n# a comment\n../a/walk.mp4\nmissing.mp4\n")
    found = expand_inputs([tmp_path / "a", tmp_path / "b", listing], out)
    assert [(i.path.relative_to(tmp_path).as_posix(), i.kind, i.name) for i in found] == [
        ("a/walk.mp4", "video", "walk"), ("b/deep/walk.MOV", "video", "walk-2"),
        ("b/run.npz", "observations", "run"), ("b/missing.mp4", "video", "missing")]
    listing.write_text(f"{listing}\n")
    with pytest.raises(InputError, match="includes itself"):
        expand_inputs([listing], out)
    (tmp_path / "empty.txt").write_text("# nothing yet\n")
    with pytest.raises(InputError, match="no video or observations file"):
        expand_inputs([tmp_path / "empty.txt"], out)


def test_batch_rejects_bad_arguments_with_one_sentence(inputs, tmp_path):
    proc = physmocap("batch", inputs["clip"], "-o", tmp_path / "o", "--workers", "0")
    assert proc.returncode == 2 and "--workers must be at least 1" in proc.stderr and "Traceback" not in proc.stderr
    proc = physmocap("batch", tmp_path, "-o", tmp_path / "o")
    assert proc.returncode == 2 and "no video or observations file found" in proc.stderr
    proc = physmocap("batch", inputs["clip"], "-o", inputs["broken"])
    assert proc.returncode == 2 and "is a file, not a batch folder" in proc.stderr and "Traceback" not in proc.stderr


def test_pool_retries_a_run_whose_worker_died_then_records_it(tmp_path):
    from concurrent.futures import Future
    from concurrent.futures.process import BrokenProcessPool

    from physmocap.batch.engines import ProcessPoolEngine
    from physmocap.batch.task import BatchTask
    from physmocap.config import Settings

    class DyingPool:  # every worker dies on its run, as one killed for memory would
        submitted = 0

        def submit(self, fn, task):
            DyingPool.submitted += 1
            future = Future()
            future.set_exception(BrokenProcessPool("a child process terminated abruptly"))
            return future

        def shutdown(self, wait=True, cancel_futures=False):
            pass

    engine = ProcessPoolEngine(1, max_retries=2)
    engine._executor.shutdown()
    engine._new_executor = DyingPool
    engine._executor = DyingPool()
    task = BatchTask("walk", str(tmp_path / "walk.mp4"), "video", str(tmp_path / "walk"), Settings(), False, "k")
    engine.submit(task)
    finished = []
    while engine.unfinished():
        finished += engine.wait(timeout=1.0)
    assert DyingPool.submitted == 3  # the first try and two retries
    [(_, record)] = finished
    assert record["status"] == "failed" and record["exit_status"] == 1
    assert record["reason"].startswith("the worker process running it died 3 times")


def test_a_batch_worker_keeps_to_one_core(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every batch worker runs limit_threads: then no stage starts work on a second core (the batch keeps each
    core busy with a run already)."""
    import os

    import cv2

    from physmocap.batch.task import limit_threads
    from physmocap.cores import may_use_two_cores

    monkeypatch.setattr(os, "environ", {key: value for key, value in os.environ.items()
                                        if key != "PHYSMOCAP_BATCH_WORKER"})
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    threads = cv2.getNumThreads()
    try:
        assert may_use_two_cores()
        limit_threads()
        assert not may_use_two_cores()
    finally:
        cv2.setNumThreads(threads)
