"""A reader started mid-video (`start_frame`): exactly the frames, and the indices, of a pass from frame 0."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

from physmocap.io.video import iter_frames
from test_video_io import DEMO, write_timed_video


def numbered_frames(count: int, width: int = 64, height: int = 48) -> list[np.ndarray]:
    """Frames told apart by their grey level and a bar whose length is the frame's number."""
    frames = []
    for i in range(count):
        frame = np.full((height, width, 3), 20 + (i * 7) % 200, np.uint8)
        frame[: height // 4, : 1 + i % width] = 255
        frames.append(frame)
    return frames


def write_gop_video(path: Path, frames: list[np.ndarray], times: list[int], time_base: Fraction, *, gop: int,
                    b_frames: int, container_format: str = "mp4") -> Path:
    """H.264 with a keyframe every `gop` frames and `b_frames` B-frames (decode order differs from display)."""
    height, width = frames[0].shape[:2]
    with av.open(str(path), "w", format=container_format) as container:
        stream = container.add_stream("libx264", rate=Fraction(1, 1) / time_base)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.time_base = stream.codec_context.time_base = time_base
        stream.options = {"crf": "18", "g": str(gop), "keyint_min": str(gop), "bf": str(b_frames)}
        for frame, time in zip(frames, times, strict=True):
            video_frame = av.VideoFrame.from_ndarray(frame, format="bgr24")
            video_frame.pts, video_frame.time_base = time, time_base
            container.mux(stream.encode(video_frame))
        container.mux(stream.encode(None))
    return path


def assert_starts_match_a_pass_from_zero(path: Path, **reader_options) -> int:
    whole = [(index, frame) for index, frame in iter_frames(path, **reader_options)]
    count = len(whole)
    assert [index for index, _ in whole] == list(range(count))
    for start in sorted({1, 2, 3, count // 3, count // 2, count - 2, count - 1, count, count + 3}):
        reader = iter_frames(path, start_frame=start, **reader_options)
        part = list(reader)
        assert [index for index, _ in part] == list(range(start, count)), start
        assert all(np.array_equal(frame, whole[index][1]) for index, frame in part), start
        assert reader.frames_read == max(start, count) and reader.missing_frames == 0
    return count


def test_start_in_a_video_with_keyframes_and_b_frames(tmp_path: Path) -> None:
    frames = numbered_frames(60)
    path = write_gop_video(tmp_path / "gop.mp4", frames, list(range(60)), Fraction(1, 25), gop=7, b_frames=2)
    assert assert_starts_match_a_pass_from_zero(path) == 60
    assert assert_starts_match_a_pass_from_zero(path, prefetch=3, max_width=32) == 60


def test_start_in_a_variable_rate_video_keeps_the_resampled_indices(tmp_path: Path) -> None:
    # 25 fps with a stretch at 12.5 fps (frames shown twice) and a burst at 50 fps (frames dropped).
    steps = [2] * 12 + [4] * 8 + [1] * 8 + [2] * 12
    times = list(np.cumsum([0] + steps))
    frames = numbered_frames(len(times))
    path = write_gop_video(tmp_path / "vfr.mp4", frames, times, Fraction(1, 50), gop=5, b_frames=0)
    from physmocap.io.video import probe_video

    info = probe_video(path)
    assert info.repeated_frames > 0 and info.dropped_frames > 0
    assert assert_starts_match_a_pass_from_zero(path) == info.frame_count


def test_start_in_a_rotated_video(tmp_path: Path) -> None:
    path = write_timed_video(tmp_path / "phone.mp4", numbered_frames(12), list(range(12)), Fraction(1, 30),
                             rotation_cw=90)
    assert assert_starts_match_a_pass_from_zero(path) == 12


def test_start_in_the_demo_clip_and_as_yuv420_pictures() -> None:
    assert assert_starts_match_a_pass_from_zero(DEMO, max_width=160) == 96
    whole = [picture.to_ndarray(format="bgr24") for _, picture in iter_frames(DEMO, pixel_format="yuv420p")]
    part = list(iter_frames(DEMO, pixel_format="yuv420p", start_frame=50))
    assert [index for index, _ in part] == list(range(50, 96))
    assert all(np.array_equal(picture.to_ndarray(format="bgr24"), whole[index]) for index, picture in part)


def test_stream_without_timestamps_is_decoded_from_its_first_frame(tmp_path: Path) -> None:
    """A raw H.264 stream has no container timestamps to seek by: the frames before the start are skipped."""
    path = write_gop_video(tmp_path / "raw.h264", numbered_frames(30), list(range(30)), Fraction(1, 25), gop=6,
                           b_frames=0, container_format="h264")
    assert assert_starts_match_a_pass_from_zero(path) == 30


def test_start_frame_must_not_be_negative() -> None:
    with pytest.raises(ValueError, match="start_frame"):
        iter_frames(DEMO, start_frame=-1)


def test_a_refused_seek_decodes_from_the_first_frame(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from physmocap.io.video import FrameReader

    path = write_gop_video(tmp_path / "gop.mp4", numbered_frames(30), list(range(30)), Fraction(1, 25), gop=5,
                           b_frames=0)
    whole = [frame for _, frame in iter_frames(path)]

    def refuse(self, container, stream):
        raise av.error.InvalidDataError(1094995529, "Invalid data found when processing input")
    monkeypatch.setattr(FrameReader, "_seek", refuse)
    part = list(iter_frames(path, start_frame=12))
    assert [index for index, _ in part] == list(range(12, 30))
    assert all(np.array_equal(frame, whole[index]) for index, frame in part)
