"""MediaPipe detection and person following on real video files."""

from __future__ import annotations

import logging
import os
import threading
from pathlib import Path

import numpy as np
import pytest

import physmocap
from physmocap.detect.mediapipe_pose import (
    Sighting,
    _native_stderr_filtered,
    detect_video,
    is_track_jump,
    search_region,
)
from physmocap.errors import InputError
from physmocap.io.video import VideoWriter, iter_frames, trim_video
from physmocap.landmarks import LANDMARK_INDEX

pytestmark = pytest.mark.slow  # MediaPipe on the demo clip

DEMO = Path(physmocap.__file__).parent / "data" / "demo" / "taiji_demo.mp4"
SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SPORTS2D = SHARED / "data" / "videos" / "sports2d_demo.mp4"
FPS = 24000 / 1001


def joint(name: str) -> int:
    return LANDMARK_INDEX[name]


@pytest.fixture(scope="module")
def demo_start(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first 20 frames of the demo clip, at its native 640 x 360."""
    path = tmp_path_factory.mktemp("clips") / "demo_start.mp4"
    trim_video(DEMO, path, start_s=0.0, duration_s=20 / FPS, width=640)
    return path


@pytest.fixture(scope="module")
def demo_observations(demo_start: Path):
    return detect_video(demo_start)


def test_demo_keypoints_are_plausible(demo_observations, demo_start: Path) -> None:
    obs = demo_observations
    assert obs.num_frames == 20 and obs.valid.all()
    assert obs.keypoints_2d.shape == (20, 33, 3) and obs.landmarks_3d.shape == (20, 33, 3)
    assert obs.image_size == (640, 360) and obs.fps == pytest.approx(FPS)
    assert obs.source == str(demo_start) and 0 < obs.seconds_per_frame < 1

    xy, confidence = obs.keypoints_2d[..., :2], obs.keypoints_2d[..., 2]
    body = [joint(n) for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip", "left_knee", "left_ankle")]
    assert confidence[:, body].min() > 0.5
    # Native pixels: the person stands in the middle of the 640 x 360 frame, head near the top, feet near the bottom.
    assert np.all((xy[..., 0] > 0) & (xy[..., 0] < 640) & (xy[..., 1] > 0) & (xy[..., 1] < 360))
    y = xy[..., 1]
    for upper, lower in [("nose", "left_shoulder"), ("left_shoulder", "left_hip"), ("left_hip", "left_knee"),
                         ("left_knee", "left_ankle"), ("right_hip", "right_ankle")]:
        assert np.all(y[:, joint(upper)] < y[:, joint(lower)]), (upper, lower)
    assert np.all(y[:, joint("left_ankle")] - y[:, joint("nose")] > 200)  # a standing person ~ 270 px tall

    # World landmarks: metres, hip-centred, y down.
    world = obs.landmarks_3d
    hip_centre = world[:, [joint("left_hip"), joint("right_hip")]].mean(axis=1)
    assert np.abs(hip_centre).max() < 0.05
    leg = world[:, joint("left_ankle"), 1] - world[:, joint("left_hip"), 1]
    assert np.all((leg > 0.5) & (leg < 1.2))


def test_downscaled_detection_reports_native_pixels(demo_observations, demo_start: Path) -> None:
    half = detect_video(demo_start, max_width=320)
    body = slice(11, 29)  # shoulders to ankles
    difference = np.abs(half.keypoints_2d[:, body, :2] - demo_observations.keypoints_2d[:, body, :2])
    assert np.median(difference) < 3.0  # pixels of the 640-wide frame, not of the 320-wide one


def test_progress_is_reported_and_mediapipe_log_spam_is_not(demo_start: Path, capfd) -> None:
    calls = []
    detect_video(demo_start, progress=lambda done, total: calls.append((done, total)))
    assert calls == [(i, 20) for i in range(1, 21)]
    assert capfd.readouterr().err == ""


def test_native_stderr_filter_passes_real_messages(capfd) -> None:
    with _native_stderr_filtered():
        os.write(2, b"W0000 00:00:1.0 1 inference_feedback_manager.cc:114] Feedback manager requires...\n")
        os.write(2, b"E0000 something real went wrong\n")
    assert capfd.readouterr().err == "E0000 something real went wrong\n"


def test_native_stderr_filter_is_shared_by_threads_and_keeps_progress_bars(capfd) -> None:
    """Two graphs' threads inside the filter at once: stderr comes back once both are out, with a progress bar's
    carriage returns as they were written."""
    inside, bar_written, leave = threading.Barrier(3), threading.Event(), threading.Event()

    def graph(name: bytes) -> None:
        with _native_stderr_filtered():
            inside.wait()  # both threads and the caller's
            bar_written.wait()
            os.write(2, b"I0000 Created TensorFlow Lite XNNPACK delegate for CPU.\n")
            os.write(2, name + b" done\n")
            leave.wait()
    threads = [threading.Thread(target=graph, args=(name,)) for name in (b"first", b"second")]
    for thread in threads:
        thread.start()
    inside.wait()
    os.write(2, b"\r  detect: 10%\r  detect: 20%\n")
    bar_written.set()
    leave.set()
    for thread in threads:
        thread.join()
    err = capfd.readouterr().err
    assert "XNNPACK" not in err and "first done\n" in err and "second done\n" in err
    assert "\r  detect: 10%\r  detect: 20%\n" in err
    os.write(2, b"after\n")  # file descriptor 2 is the terminal's again
    assert capfd.readouterr().err == "after\n"


def test_video_without_person_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "noise.mp4"
    rng = np.random.default_rng(0)
    with VideoWriter(path, 30.0, 160, 120) as writer:
        for _ in range(6):
            writer.write(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8))
    with pytest.raises(InputError, match="no person was found in any frame"):
        detect_video(path)


def test_person_box_without_person_is_an_input_error(demo_start: Path) -> None:
    # The person stands around x = 330; a box at the left edge (grown by its margin) does not reach them.
    with pytest.raises(InputError, match="inside person_box"):
        detect_video(demo_start, person_box=(0, 200, 60, 300))
    with pytest.raises(InputError, match="person_box must be"):
        detect_video(demo_start, person_box=(100, 0, 50, 10))


def test_truncated_video_gives_the_decodable_frames(demo_start: Path, tmp_path: Path, caplog) -> None:
    data = demo_start.read_bytes()
    truncated = tmp_path / "truncated.mp4"
    truncated.write_bytes(data[: int(len(data) * 0.6)])
    with caplog.at_level(logging.WARNING):
        obs = detect_video(truncated)
    assert 5 < obs.num_frames < 20 and obs.valid.all()
    assert "decoding stopped" in caplog.text


def sighting(frame: int, centre: tuple[float, float], size: float = 100.0) -> Sighting:
    cx, cy = centre
    box = np.array([cx - size, cy - 2 * size, cx + size, cy + 2 * size])
    return Sighting(frame, box, np.array(centre), size)


def test_track_jump_gate() -> None:
    last = sighting(10, (500, 400))
    assert not is_track_jump(last, sighting(11, (560, 410)), fps=30)
    assert is_track_jump(last, sighting(11, (700, 400)), fps=30)  # two torso sizes in one frame
    assert is_track_jump(last, sighting(11, (500, 400), size=200), fps=30)  # doubled in one frame
    assert not is_track_jump(last, sighting(11, (500, 400), size=130), fps=30)
    assert not is_track_jump(last, sighting(25, (700, 400)), fps=30)  # unseen for half a second


def test_search_region_grows_while_the_person_is_unseen() -> None:
    last = sighting(10, (500, 400))  # box 400..600 x 200..600, larger side 400
    assert search_region(last, 11, 30, (1920, 1080)) == (200, 0, 800, 800)
    assert search_region(last, 41, 30, (1920, 1080)) == (0, 0, 1600, 1080)


@pytest.mark.skipif(not SPORTS2D.is_file(), reason="needs ../shared/data/videos beside the repository")
def test_person_box_follows_the_walker_not_the_jumper(tmp_path: Path) -> None:
    """Frames 60..71 show a jumping-jack person on a roof (x ~ 640 px) and a walker on the lawn (x ~ 1300 px)."""
    clip = tmp_path / "two_people.mp4"
    with VideoWriter(clip, 30.0, 1768, 994) as writer:
        for index, frame in iter_frames(SPORTS2D):
            if index >= 72:
                break
            if index >= 60:
                writer.write(frame)

    def hips_x(obs) -> np.ndarray:
        assert obs.valid.all()
        return obs.keypoints_2d[:, [joint("left_hip"), joint("right_hip")], 0]

    assert np.all(hips_x(detect_video(clip, person_box=(1150, 540, 1520, 960))) > 1100)
    assert np.all(np.abs(hips_x(detect_video(clip, person_box=(540, 20, 740, 420))) - 640) < 150)
    # Without a box: whomever MediaPipe picks first (here the walker), and then only them.
    assert np.all(hips_x(detect_video(clip)) > 1100)


def test_phone_video_with_rotation_metadata_is_detected_upright(demo_observations, demo_start: Path,
                                                                 tmp_path: Path) -> None:
    """The demo clip stored sideways, as a phone held upright stores it, with the display matrix that turns it
    back: keypoints come out in the upright frame, as from the upright clip."""
    from fractions import Fraction

    import cv2

    from test_video_io import write_timed_video

    sideways = [cv2.rotate(frame, cv2.ROTATE_90_COUNTERCLOCKWISE) for _, frame in iter_frames(demo_start)]
    phone = write_timed_video(tmp_path / "phone.mp4", sideways, list(range(len(sideways))),
                              Fraction(1001, 24000), rotation_cw=90)
    obs = detect_video(phone)
    assert obs.image_size == (640, 360) and obs.num_frames == 20 and obs.valid.all()
    assert obs.fps == pytest.approx(FPS)
    body = slice(11, 29)  # shoulders to ankles
    difference = np.abs(obs.keypoints_2d[:, body, :2] - demo_observations.keypoints_2d[:, body, :2])
    assert np.median(difference) < 3.0


def test_detections_are_float32_exact_as_the_cache_stores_them(demo_observations, tmp_path: Path) -> None:
    from physmocap.motion import Observations

    demo_observations.save(tmp_path / "observations.npz")
    reloaded = Observations.load(tmp_path / "observations.npz")
    assert np.array_equal(reloaded.keypoints_2d, demo_observations.keypoints_2d)
    assert np.array_equal(reloaded.landmarks_3d, demo_observations.landmarks_3d)
