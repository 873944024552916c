"""Repeated pictures (detect/repeats.py): detection marks the frames of a video that show the picture before them
again, and offline capture puts their detections on the straight line between the new pictures around them."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

from conftest import DEMO_VIDEO
from physmocap.config import Settings
from physmocap.detect.repeats import UNCHANGED_LEVEL, interpolate_repeated, person_box, picture_unchanged
from physmocap.motion import Observations
from physmocap.pipeline import run_capture
from physmocap.result import load_result

PICTURES = 30  # of the demo clip, each written twice


def observations(frames: int = 10) -> Observations:
    rng = np.random.default_rng(0)
    keypoints = rng.uniform(0, 500, (frames, 33, 3))
    keypoints[..., 2] = 1.0
    return Observations(keypoints, rng.normal(size=(frames, 33, 3)), 30.0, (640, 480))


def test_a_run_of_repeats_lies_on_the_line_between_the_pictures_around_it():
    obs = observations()
    obs.repeated[[2, 3, 4, 8, 9]] = True  # 2-4 between pictures 1 and 5; 8-9 end the clip after picture 7
    fixed = interpolate_repeated(obs)
    for frame, share in ((2, 0.25), (3, 0.5), (4, 0.75)):
        expected = (1 - share) * obs.landmarks_3d[1] + share * obs.landmarks_3d[5]
        np.testing.assert_allclose(fixed.landmarks_3d[frame], expected)
        np.testing.assert_allclose(fixed.keypoints_2d[frame], (1 - share) * obs.keypoints_2d[1]
                                   + share * obs.keypoints_2d[5])
    np.testing.assert_array_equal(fixed.keypoints_2d[8:], obs.keypoints_2d[[7, 7]])  # held at the last picture
    untouched = [0, 1, 5, 6, 7]
    np.testing.assert_array_equal(fixed.keypoints_2d[untouched], obs.keypoints_2d[untouched])
    assert fixed.repeated.tolist() == obs.repeated.tolist()


def test_repeats_after_a_frame_without_the_person_keep_their_detections():
    obs = observations()
    obs.valid[3] = False
    obs.repeated[[4, 5]] = True
    fixed = interpolate_repeated(obs)
    np.testing.assert_array_equal(fixed.keypoints_2d, obs.keypoints_2d)
    plain = observations()
    assert interpolate_repeated(plain) is plain  # nothing repeated: the same observations


def test_the_same_picture_decoded_again_is_unchanged_and_a_moved_one_is_not():
    rng = np.random.default_rng(1)
    picture = rng.integers(0, 256, (120, 160, 3), dtype=np.uint8)
    box = (40, 20, 120, 110)
    assert picture_unchanged(picture, picture.copy(), box)
    noisy = picture.astype(int)
    noisy[rng.random(picture.shape) < 0.2] += 1  # codec noise: a fifth of the values one level off
    assert picture_unchanged(picture, np.clip(noisy, 0, 255).astype(np.uint8), box)
    moved = np.roll(picture, 2, axis=1)  # the person two pixels on
    assert not picture_unchanged(picture, moved, box)
    assert not picture_unchanged(picture, picture, (50, 20, 50, 110))  # an empty box decides nothing
    assert UNCHANGED_LEVEL < 1.0


def test_the_person_box_stays_in_the_image():
    keypoints = np.array([[-30.0, 10.0, 1.0], [100.0, 300.0, 1.0], [50.0, 700.0, 0.2]])
    x0, y0, x1, y1 = person_box(keypoints, (640, 480))
    assert (x0, y0, y1) == (0, 0, 480) and 100 < x1 < 640  # grown by a tenth of the larger side, then clipped


def test_observations_keep_their_repeats_through_a_file(tmp_path):
    obs = observations()
    obs.repeated[[3, 4]] = True
    obs.save(tmp_path / "o.npz")
    assert Observations.load(tmp_path / "o.npz").repeated.tolist() == obs.repeated.tolist()
    first = obs.select(slice(5))  # every per-frame array alike, so that the file stays whole
    first.save(tmp_path / "first.npz")
    assert Observations.load(tmp_path / "first.npz").repeated.tolist() == [False, False, False, True, True]


@pytest.fixture(scope="module")
def doubled_video(tmp_path_factory) -> Path:
    """The demo clip's first PICTURES pictures, each written twice at twice the rate (x264, as a converter would)."""
    path = tmp_path_factory.mktemp("doubled") / "doubled.mp4"
    with av.open(str(DEMO_VIDEO)) as source, av.open(str(path), "w") as out:
        stream = source.streams.video[0]
        encoded = out.add_stream("libx264", rate=2 * stream.average_rate)
        encoded.width, encoded.height, encoded.pix_fmt = stream.width, stream.height, "yuv420p"
        encoded.options = {"preset": "veryfast", "crf": "20"}
        for index, frame in enumerate(source.decode(stream)):
            if index == PICTURES:
                break
            picture = frame.to_ndarray(format="rgb24")
            for _ in range(2):
                out.mux(encoded.encode(av.VideoFrame.from_ndarray(picture, format="rgb24")))
        out.mux(encoded.encode())
    return path


def test_capture_finds_the_repeats_of_a_doubled_video_and_interpolates_them(doubled_video, tmp_path):
    summary = run_capture(tmp_path / "run", Settings().replace("physics", method="none"), video=doubled_video,
                          overlay=False)
    result = load_result(tmp_path / "run" / "result.npz")
    repeated = result["repeated_picture"]
    second_showings = np.arange(1, 2 * PICTURES, 2)
    assert not repeated[::2].any()  # every new picture is new
    assert repeated[second_showings].mean() >= 0.9, np.flatnonzero(~repeated[second_showings])
    assert summary.repeated_frame_count == int(repeated.sum())
    inner = [f for f in np.flatnonzero(repeated) if f + 1 < len(repeated) and result["valid"][[f - 1, f + 1]].all()]
    keypoints = result["keypoints_2d"]
    np.testing.assert_allclose(keypoints[inner], 0.5 * (keypoints[np.add(inner, -1)] + keypoints[np.add(inner, 1)]),
                               atol=1e-3)


def test_online_capture_marks_the_repeats_as_they_arrive(doubled_video, tmp_path):
    """Online (detection and the causal fit in live order) the repeats are marked as offline, frame by frame, and
    reported; their detections stay as detected (the next new picture is still to come)."""
    summary = run_capture(tmp_path / "run", Settings().replace("physics", method="none").replace(None, online=True),
                          video=doubled_video, overlay=False)
    result = load_result(tmp_path / "run" / "result.npz")
    repeated = result["repeated_picture"]
    assert not repeated[::2].any()
    assert repeated[np.arange(1, 2 * PICTURES, 2)].mean() >= 0.9, np.flatnonzero(~repeated[1::2])
    assert summary.online and summary.repeated_frame_count == int(repeated.sum())
