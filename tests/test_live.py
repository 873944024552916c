import logging
import time

import numpy as np
import pytest

from conftest import DEMO_VIDEO
from physmocap.config import Settings
from physmocap.kinematics.stage import fit_motion
from physmocap.live import DROPPED_REASON, WARNING_INTERVAL_SECONDS, stream_capture

pytestmark = pytest.mark.slow  # live capture in real time


def test_streaming_capture_equals_the_causal_fit_of_the_same_detections():
    settings = Settings(online=True).replace("body", calibration_frames=8)  # a warm-up that ends within 45 frames
    poses = []
    report = stream_capture(str(DEMO_VIDEO), settings, max_frames=45, on_pose=lambda i, q, details: poses.append(i))
    assert report.observations.num_frames == 45
    assert sorted(poses) == list(range(45))
    # Warm-up holds back the calibration frames; afterwards every frame is delivered in order.
    assert report.warmup_frames < 45 and poses[report.warmup_frames:] == list(range(report.warmup_frames, 45))
    batch = fit_motion(report.observations, settings)
    assert np.allclose(batch.qpos, report.motion.qpos, atol=1e-9)
    assert report.frames_per_second > 0 and np.isfinite(report.latency_median_ms)


def test_streaming_physics_equals_the_physics_stage_on_the_same_inputs():
    from physmocap.contacts.footlock import lock_feet
    from physmocap.contacts.predict import predict_contacts
    from physmocap.dynamics.stage import run_physcap

    settings = Settings(online=True).replace("physics", method="physcap")
    report = stream_capture(str(DEMO_VIDEO), settings, max_frames=40)
    assert report.physics is not None and report.contacts.shape == (40, 4)
    batch = run_physcap(report.motion.body, report.motion.qpos, report.observations.fps, report.contacts,
                        report.stationary, settings.physics)
    assert np.allclose(batch.qpos, report.physics.qpos, atol=1e-9)
    assert np.allclose(batch.grf, report.physics.grf, atol=1e-6)
    # Each frame's contacts from the frames it has, as the causal network gives them on the whole clip
    flags, _, _ = predict_contacts(report.observations, "causal")
    assert np.array_equal(lock_feet(flags, report.motion.body, report.motion.qpos, settings.physics), report.contacts)


def test_each_frames_own_window_gives_the_whole_clips_causal_probabilities(demo_detections):
    """Live capture runs the causal network on each frame's own window (causal_window_start); that must give what
    the network gives on the whole clip, probabilities and not only flags (a window one frame short agrees on the
    demo's flags but not on its probabilities)."""
    from physmocap.contacts.predict import causal_window_start, load_weights, network_probabilities

    obs, weights = demo_detections, load_weights("causal")
    kp, valid, fps = obs.keypoints_2d, obs.valid, obs.fps
    whole, _ = network_probabilities(kp, valid, fps, weights, "causal")
    own, short = [], []
    for t in range(len(valid)):
        for rows, start in ((own, causal_window_start(t)), (short, min(t, causal_window_start(t) + 1))):
            rows.append(network_probabilities(kp[start:t + 1], valid[start:t + 1], fps, weights, "causal")[0][-1])
    np.testing.assert_allclose(np.array(own), whole, atol=1e-6)
    assert np.abs(np.array(short) - whole).max() > 1e-3


FRAME_RATE = 23.976  # the demo clip's
SHORT_WARMUP = Settings(online=True).replace("body", calibration_frames=8)  # poses come after 8 seen frames


@pytest.fixture(scope="module")
def demo_detections():
    """MediaPipe's detections of the demo's 96 frames (4 s), for a stand-in detector that replays them."""
    return stream_capture(str(DEMO_VIDEO), SHORT_WARMUP).observations


@pytest.fixture(scope="module")
def looped_demo(tmp_path_factory):
    """The demo played twice over (192 frames, 8 s): a steady state after even a slow warm-up."""
    from physmocap.io.video import VideoWriter, iter_frames

    reader = iter_frames(DEMO_VIDEO)
    path = tmp_path_factory.mktemp("looped") / "demo_twice.mp4"
    with VideoWriter(path, reader.info.fps, *reader.output_size, preset="ultrafast") as writer:
        for _ in range(2):
            for _, frame in reader:
                writer.write(frame)
    return path


@pytest.fixture
def replayed_detector(monkeypatch, demo_detections):
    """Replaces the detector by one that returns demo_detections' frames, each after `seconds`; returns the
    setter of `seconds`."""
    delay = {"seconds": 0.0}

    class ReplayedFollower:
        def __init__(self, image_size, fps, **_):
            self.seconds = 0.0

        def detect(self, index, frame):
            time.sleep(delay["seconds"])
            self.seconds += delay["seconds"]
            obs, frame = demo_detections, index % demo_detections.num_frames  # the looped demo starts again
            return obs.keypoints_2d[frame], obs.landmarks_3d[frame], str(obs.invalid_reason[frame])

        def close(self):
            pass

    monkeypatch.setattr("physmocap.detect.mediapipe_pose.PersonFollower", ReplayedFollower)
    return lambda seconds: delay.update(seconds=seconds)


def _slow_poses(delivered: list):
    """on_pose that notes the frames it was given and takes 0.1 s (2.4 frames of the demo) for those after the
    8-frame warm-up (its frames come at once)."""
    def on_pose(index, qpos, details):
        delivered.append(index)
        if index >= SHORT_WARMUP.body.calibration_frames:
            time.sleep(0.1)
    return on_pose


def test_dropping_stale_frames_keeps_the_latency_bounded_when_poses_are_slow(replayed_detector, looped_demo,
                                                                             caplog):
    delivered: list[int] = []
    with caplog.at_level(logging.WARNING, logger="physmocap"):
        report = stream_capture(str(looped_demo), SHORT_WARMUP, realtime=True, on_pose=_slow_poses(delivered))
    assert report.frames_arrived == 192 and report.frames_dropped_before_fit > 0
    assert report.frames_processed + report.frames_dropped == 192 == len(delivered) + report.frames_dropped
    dropped = np.flatnonzero(report.observations.invalid_reason == DROPPED_REASON)
    assert len(dropped) == report.frames_dropped and not set(dropped) & set(delivered)
    # Kept every frame, the lag would grow by about 0.06 s a frame, to 11 s (270 frames) by the end.
    assert report.latency_median_ms / 1000 * FRAME_RATE < 20, (report.latency_median_ms, report.latency_p95_ms)
    warnings = [r.message for r in caplog.records if "falls behind" in r.message]
    assert 1 <= len(warnings) <= 1 + report.wall_seconds / WARNING_INTERVAL_SECONDS


def test_keeping_every_frame_processes_every_frame(replayed_detector, demo_detections):
    delivered: list[int] = []
    report = stream_capture(str(DEMO_VIDEO), SHORT_WARMUP, realtime=True, max_frames=40,
                            on_pose=_slow_poses(delivered), drop_stale_frames=False)
    assert report.frames_dropped == 0 and sorted(delivered) == list(range(40))
    assert np.array_equal(report.observations.valid, demo_detections.valid[:40])


def test_dropped_frames_are_flagged_finite_and_tracked_by_the_physics(replayed_detector):
    from physmocap.dynamics.stage import run_physcap

    replayed_detector(2.5 / FRAME_RATE)  # a detector that takes 2.5 frame intervals
    # The floor kept as fitted (not refined while tracking), so that the physics stage below starts from it too.
    settings = SHORT_WARMUP.replace("physics", method="physcap", floor_refit_interval=None)
    report = stream_capture(str(DEMO_VIDEO), settings, realtime=True)
    obs = report.observations
    dropped = obs.invalid_reason == DROPPED_REASON
    assert report.frames_dropped_before_detection > 0 and dropped.sum() == report.frames_dropped
    assert not obs.valid[dropped].any() and not obs.keypoints_2d[dropped].any()
    assert np.all(np.isfinite(report.motion.qpos)) and np.all(np.isfinite(report.physics.grf))
    assert np.all(np.isfinite(report.motion.reprojection_error[obs.valid]))
    # The physics stepped through the dropped frames as through frames without a person: it is the physics stage
    # of the same motion.
    batch = run_physcap(report.motion.body, report.motion.qpos, obs.fps, report.contacts, report.stationary,
                        settings.physics, valid=obs.valid)
    assert np.allclose(batch.qpos, report.physics.qpos, atol=1e-9)
    # and writes the same forces: none on the dropped frames, each other frame's at its instant
    assert np.allclose(batch.grf, report.physics.grf, atol=1e-6)
    assert np.allclose(batch.residual, report.physics.residual, atol=1e-6)
    assert not report.physics.grf[dropped].any() and not report.physics.contacts[dropped].any()


def test_live_says_where_it_saves_or_that_nothing_is_saved(replayed_detector, capsys, tmp_path):
    from physmocap.cli import main

    assert main(["live", str(DEMO_VIDEO), "--max-frames", "12", "--as-fast-as-possible", "--physics", "none"]) == 0
    out = capsys.readouterr()
    assert "nothing will be saved" in out.err and "12 frames arrived" in out.out and "0 dropped" in out.out
    # 12 frames end within the 3 s calibration warm-up: no latency after it to report (it once said "nan ms,
    # after the 1-frame warm-up")
    assert "ended within the calibration warm-up (12 frames)" in out.out and "nan" not in out.out
    assert main(["live", str(DEMO_VIDEO), "--max-frames", "12", "--as-fast-as-possible", "--physics", "none",
                 "-o", str(tmp_path / "run")]) == 0
    assert f"saving to {tmp_path / 'run'}/" in capsys.readouterr().err
    assert (tmp_path / "run" / "result.npz").is_file()
