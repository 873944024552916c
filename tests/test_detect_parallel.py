"""Two MediaPipe graphs on two parts of a video (detect/two_graphs.py): the splice, the junction check, the fallback
to one follower, progress, Ctrl-C and errors, on real video files. MIN_FRAMES is lowered so that short clips take
the two-graph path."""

from __future__ import annotations

import dataclasses
import logging
import os
import threading
from pathlib import Path

import numpy as np
import pytest

import physmocap
from physmocap import cores
from physmocap.config import Settings
from physmocap.detect import two_graphs
from physmocap.detect.mediapipe_pose import Detections, detect_video
from physmocap.io.video import VideoWriter, iter_frames, probe_video, trim_video

DEMO = Path(physmocap.__file__).parent / "data" / "demo" / "taiji_demo.mp4"  # 96 frames, one person
SECOND_THREAD = "physmocap-detect-second"


@pytest.fixture
def short_videos_split(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(two_graphs, "MIN_FRAMES", 20)


@pytest.fixture(scope="module")
def demo_sequential():
    return detect_video(DEMO, graphs=1)


def plan_of(path: Path) -> two_graphs.Plan:
    plan = two_graphs.two_part_plan(probe_video(path), 2)
    assert plan is not None
    return plan


@pytest.mark.slow
def test_two_graphs_keep_the_sequential_frames_before_the_split(short_videos_split, demo_sequential, caplog,
                                                                  capfd) -> None:
    calls: list[tuple[int, int]] = []
    lock = threading.Lock()

    def progress(done: int, total: int) -> None:
        with lock:
            calls.append((done, total))
    with caplog.at_level(logging.INFO):
        spliced = detect_video(DEMO, graphs=2, progress=progress)
    plan = plan_of(DEMO)
    assert "may follow another person" not in caplog.text
    assert spliced.num_frames == 96 and spliced.valid.all() and demo_sequential.valid.all()
    assert np.array_equal(spliced.keypoints_2d[: plan.split], demo_sequential.keypoints_2d[: plan.split])
    assert np.array_equal(spliced.landmarks_3d[: plan.split], demo_sequential.landmarks_3d[: plan.split])
    after = np.abs(spliced.keypoints_2d[plan.split:, :, :2] - demo_sequential.keypoints_2d[plan.split:, :, :2])
    assert np.median(after) < 3.0  # the same person, through MediaPipe's smoothing started afresh
    # One count over both graphs: never backwards, finished only by the last report.
    done = [d for d, _ in calls]
    assert done == sorted(done) and calls[-1] == (96, 96) and all(d < t for d, t in calls[:-1])
    assert capfd.readouterr().err == ""


def demo_then_empty_frames(path: Path, person_frames: int, empty_frames: int) -> Path:
    """The demo clip's first `person_frames` frames, then grey frames without anybody."""
    info = probe_video(DEMO)
    with VideoWriter(path, info.fps, info.width, info.height) as writer:
        for index, frame in iter_frames(DEMO):
            if index >= person_frames:
                break
            writer.write(frame)
        for _ in range(empty_frames):
            writer.write(np.full((info.height, info.width, 3), 90, np.uint8))
    return path


@pytest.mark.slow
def test_no_person_in_the_overlap_falls_back_to_the_sequential_follower(short_videos_split, tmp_path: Path,
                                                                         caplog) -> None:
    video = demo_then_empty_frames(tmp_path / "leaves.mp4", 30, 70)
    plan = plan_of(video)
    assert plan.overlap_start > 30  # the second graph never sees the person
    sequential = detect_video(video, graphs=1)
    calls: list[tuple[int, int]] = []
    with caplog.at_level(logging.INFO):
        fallback = detect_video(video, graphs=2, progress=lambda done, total: calls.append((done, total)))
    assert caplog.text.count("may follow another person") == 1
    assert np.array_equal(fallback.keypoints_2d, sequential.keypoints_2d)
    assert np.array_equal(fallback.invalid_reason, sequential.invalid_reason)
    done = [d for d, _ in calls]
    assert done == sorted(done) and calls[-1][0] == calls[-1][1] > 100  # the redone frames count as more work


@pytest.mark.slow
def test_truncated_video_gives_the_sequential_frames(short_videos_split, tmp_path: Path, caplog) -> None:
    whole = tmp_path / "whole.mp4"
    trim_video(DEMO, whole, start_s=0.0, duration_s=4.0, width=640)
    truncated = tmp_path / "truncated.mp4"
    truncated.write_bytes(whole.read_bytes()[: int(whole.stat().st_size * 0.8)])
    sequential = detect_video(truncated, graphs=1)
    with caplog.at_level(logging.WARNING):
        two = detect_video(truncated, graphs=2)
    assert "decoding stopped" in caplog.text
    assert two.num_frames == sequential.num_frames < probe_video(truncated).frame_count
    split = plan_of(truncated).split
    assert np.array_equal(two.keypoints_2d[:split], sequential.keypoints_2d[:split])
    assert np.array_equal(two.valid, sequential.valid)


def second_threads() -> list[threading.Thread]:
    return [thread for thread in threading.enumerate() if thread.name == SECOND_THREAD]


@pytest.mark.slow
def test_ctrl_c_stops_both_graphs_and_restores_stderr(short_videos_split) -> None:
    stderr_before = os.fstat(2)

    def progress(done: int, total: int) -> None:
        if threading.current_thread() is threading.main_thread() and done == 20:
            raise KeyboardInterrupt
    with pytest.raises(KeyboardInterrupt):
        detect_video(DEMO, graphs=2, progress=progress)
    assert not second_threads()
    stderr_after = os.fstat(2)
    assert (stderr_after.st_dev, stderr_after.st_ino) == (stderr_before.st_dev, stderr_before.st_ino)


@pytest.mark.slow
def test_an_error_in_the_second_graph_reaches_the_caller(short_videos_split) -> None:
    def progress(done: int, total: int) -> None:
        if threading.current_thread().name == SECOND_THREAD:
            raise RuntimeError("second graph broke")
    with pytest.raises(RuntimeError, match="second graph broke"):
        detect_video(DEMO, graphs=2, progress=progress)
    assert not second_threads()


def detections(first: int, centres: list[tuple[float, float]], size: float = 100.0) -> Detections:
    """Detections whose torso (shoulders and hips) is a square of diagonal `size` around each centre."""
    result = Detections(first)
    half = size / 2 / np.sqrt(2)
    for cx, cy in centres:
        keypoints = np.zeros((33, 3))
        keypoints[11:13, :2] = [(cx - half, cy - half), (cx + half, cy - half)]  # shoulders
        keypoints[23:25, :2] = [(cx - half, cy + half), (cx + half, cy + half)]  # hips
        result.keypoints.append(keypoints)
        result.world.append(np.zeros((33, 3)))
        result.reasons.append("")
    return result


def test_junction_check_compares_torso_centres_and_sizes() -> None:
    plan = two_graphs.Plan(announced=40, split=20, overlap_start=10, compare_from=15)
    first = detections(0, [(300.0 + frame, 200.0) for frame in range(20)])
    same = detections(10, [(301.0 + frame, 202.0) for frame in range(10, 40)])
    assert two_graphs.junction_mismatch(first, same, plan) == ""
    other = detections(10, [(300.0 + frame + 60, 200.0) for frame in range(10, 40)])  # 0.6 torso sizes away
    assert "torso centres are 0.60 torso sizes apart" in two_graphs.junction_mismatch(first, other, plan)
    nearer = detections(10, [(300.0 + frame, 200.0) for frame in range(10, 40)], size=140.0)  # larger: nearer
    assert "a factor 1.40" in two_graphs.junction_mismatch(first, nearer, plan)
    lost = detections(10, [(301.0 + frame, 202.0) for frame in range(10, 40)])
    lost.reasons[5:] = ["no person"] * 25  # frames 15 on
    assert "on only 0 of the overlap's frames" in two_graphs.junction_mismatch(first, lost, plan)


def test_two_graphs_only_where_two_cores_are_free_and_the_video_is_long(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert two_graphs.graphs_to_run(None) == 2 and two_graphs.graphs_to_run(1) == 1
    monkeypatch.setattr(cores.multiprocessing, "parent_process", lambda: object())  # a pool's worker
    assert two_graphs.graphs_to_run(None) == 1 and two_graphs.graphs_to_run(2) == 2
    monkeypatch.setattr(cores.multiprocessing, "parent_process", lambda: None)
    monkeypatch.setenv(cores.BATCH_WORKER_VARIABLE, "1")  # a batch's worker, Ray's included
    assert two_graphs.graphs_to_run(None) == 1
    monkeypatch.delenv(cores.BATCH_WORKER_VARIABLE)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {3})
    assert two_graphs.graphs_to_run(None) == 1
    short = probe_video(DEMO)
    assert two_graphs.two_part_plan(short, 2) is None  # 96 frames: one graph
    long = dataclasses.replace(short, frame_count=1800, fps=30.0)
    plan = two_graphs.two_part_plan(long, 2)
    assert plan == two_graphs.Plan(announced=1800, split=915, overlap_start=885, compare_from=900)
    assert two_graphs.two_part_plan(long, 1) is None


def test_detection_cache_key_holds_the_graphs_run(monkeypatch: pytest.MonkeyPatch) -> None:
    from physmocap.stages import DETECT

    def key(graphs: int | None) -> str:
        return DETECT.key(Settings().replace("detect", graphs=graphs), "video-digest")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1})
    assert key(None) == key(2) != key(1)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0})
    assert key(None) == key(1) != key(2)
