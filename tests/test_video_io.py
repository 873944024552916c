"""Video reading, writing and trimming on real files made inside the tests."""

from __future__ import annotations

import struct
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

import physmocap
from physmocap.errors import InputError
from physmocap.io.video import VideoWriter, copy_yuv420, iter_frames, probe_video, trim_video, yuv420_planes

DEMO = Path(physmocap.__file__).parent / "data" / "demo" / "taiji_demo.mp4"


def gradient_frames(count: int, width: int, height: int) -> list[np.ndarray]:
    """Smooth moving colour gradients (compress well, so a re-read frame stays close to what was written)."""
    x = np.linspace(0, 1, width)[None, :]
    y = np.linspace(0, 1, height)[:, None]
    frames = []
    for i in range(count):
        phase = i / count
        channels = [128 + 100 * np.sin(2 * np.pi * (x + phase + k / 3)) * np.cos(np.pi * y) for k in range(3)]
        frames.append(np.clip(np.stack(channels, axis=2), 0, 255).astype(np.uint8))
    return frames


def test_probe_demo_clip() -> None:
    info = probe_video(DEMO)
    assert (info.width, info.height) == (640, 360)
    assert info.fps == pytest.approx(24000 / 1001)
    assert info.frame_count == 96


def file_with(name: str, content: bytes):
    """A maker of a file `name` holding `content` in the test's folder."""

    def make(tmp_path: Path) -> Path:
        path = tmp_path / name
        path.write_bytes(content)
        return path

    return make


def zero_frame_video(tmp_path: Path) -> Path:
    """The demo clip cut just after the start of its media data: headers announce frames, none decodes."""
    data = DEMO.read_bytes()
    path = tmp_path / "headers_only.mp4"
    path.write_bytes(data[: data.index(b"mdat") + 8])
    return path


@pytest.mark.parametrize(
    "make_path, problem",
    [
        (lambda tmp: tmp / "missing.mp4", "no such video file"),
        (lambda tmp: tmp, "is a directory"),
        (file_with("empty.mp4", b""), "empty"),
        (file_with("notes.mp4", b"These are notes, not a video.\n"), "not a readable video"),
        (zero_frame_video, "no decodable frame"),
    ],
    ids=["missing", "directory", "empty", "text", "zero-frames"],
)
def test_probe_rejects_with_one_sentence_naming_the_file(tmp_path: Path, make_path, problem: str) -> None:
    path = make_path(tmp_path)
    with pytest.raises(InputError) as caught:
        probe_video(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ")
    assert problem in message
    assert message.endswith(".") and "\n" not in message


def test_iter_frames_reads_all_and_can_scale_down() -> None:
    reader = iter_frames(DEMO, max_width=320)
    shapes = {frame.shape for _, frame in reader}
    assert shapes == {(180, 320, 3)}
    assert reader.frames_read == 96 and reader.missing_frames == 0


@pytest.mark.parametrize("name, codec, pixel_format, options", [
    ("vp9.webm", "libvpx-vp9", "yuv420p", {"deadline": "realtime", "cpu-used": "8"}),
    ("mjpeg.avi", "mjpeg", "yuvj420p", {}),
    ("hevc.mp4", "libx265", "yuv420p", {"preset": "ultrafast", "x265-params": "log-level=none"}),
    ("h264_444.mp4", "libx264", "yuv444p", {"preset": "ultrafast"}),
    ("h264_10bit.mkv", "libx264", "yuv420p10le", {"preset": "ultrafast"}),
    ("grey.mkv", "ffv1", "gray", {}),
    ("prores.mov", "prores_ks", "yuv422p10le", {}),
])
def test_other_codecs_and_pixel_formats_read_as_upright_bgr(tmp_path: Path, name: str, codec: str,
                                                              pixel_format: str, options: dict) -> None:
    """Phones, editors and cameras write more than 8-bit 4:2:0 H.264; every frame reads as (H, W, 3) uint8 BGR."""
    frames = gradient_frames(6, 96, 64)
    path = tmp_path / name
    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=24)
        stream.width, stream.height, stream.pix_fmt, stream.options = 96, 64, pixel_format, options
        for bgr in frames:
            picture = av.VideoFrame.from_ndarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), format="rgb24")
            out.mux(stream.encode(picture.reformat(format=pixel_format)))
        out.mux(stream.encode())
    info = probe_video(path)
    assert (info.width, info.height, round(info.fps)) == (96, 64, 24)
    read = [frame for _, frame in iter_frames(path)]
    assert len(read) == 6 and all(f.shape == (64, 96, 3) and f.dtype == np.uint8 for f in read)
    if pixel_format != "gray":  # colour survives the codec
        assert np.abs(read[3].astype(int) - frames[3]).mean() < 12


def test_truncated_file_yields_the_decodable_frames_then_stops(tmp_path: Path) -> None:
    data = DEMO.read_bytes()
    truncated = tmp_path / "truncated.mp4"
    truncated.write_bytes(data[: int(len(data) * 0.6)])
    reader = iter_frames(truncated)
    indices = [index for index, frame in reader]
    assert indices == list(range(len(indices)))
    assert 20 < reader.frames_read < 96
    assert reader.missing_frames == 96 - reader.frames_read


def test_writer_makes_browser_playable_h264(tmp_path: Path) -> None:
    frames = gradient_frames(12, 65, 49)  # odd size: padded to even for yuv420p
    path = tmp_path / "out.mp4"
    with VideoWriter(path, 25.0, 65, 49) as writer:
        for frame in frames:
            writer.write(frame)
        assert not path.exists()  # only the temporary file exists while writing
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.mp4"]

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        assert stream.codec_context.pix_fmt == "yuv420p"
        assert (stream.width, stream.height) == (66, 50)
        assert stream.average_rate == 25
    head = path.read_bytes()
    assert head.index(b"moov") < head.index(b"mdat")  # +faststart: playable while downloading

    reread = [frame for _, frame in iter_frames(path)]
    assert len(reread) == 12
    error = np.abs(reread[5][:49, :65].astype(float) - frames[5]).mean()
    assert error < 4.0


def test_writer_rate_control_and_index_placement(tmp_path: Path) -> None:
    frames = gradient_frames(6, 64, 48)
    for name, options in (("crf", {}), ("cqp", {"qp": 19, "faststart": False})):
        path = tmp_path / f"{name}.mp4"
        with VideoWriter(path, 25.0, 64, 48, preset="ultrafast", **options) as writer:
            for frame in frames:
                writer.write(frame)
        data = path.read_bytes()
        assert f"rc={name}".encode() in data  # x264 states its settings in the stream
        if name == "cqp":
            assert b" qp=19 " in data
            assert data.index(b"mdat") < data.index(b"moov")  # no faststart: the index stays at the end
        reread = [frame for _, frame in iter_frames(path)]
        assert len(reread) == 6 and np.abs(reread[3].astype(float) - frames[3]).mean() < 4.0


def test_writer_leaves_nothing_when_interrupted(tmp_path: Path) -> None:
    path = tmp_path / "out.mp4"
    with pytest.raises(KeyboardInterrupt):
        with VideoWriter(path, 30.0, 32, 32) as writer:
            writer.write(np.zeros((32, 32, 3), np.uint8))
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_writer_rejects_bad_frames_and_empty_videos(tmp_path: Path) -> None:
    writer = VideoWriter(tmp_path / "out.mp4", 30.0, 32, 32)
    with pytest.raises(ValueError, match="expected a"):
        writer.write(np.zeros((16, 32, 3), np.uint8))
    with pytest.raises(ValueError, match="no frames"):
        writer.close()
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="mp4"):
        VideoWriter(tmp_path / "out.avi", 30.0, 32, 32)


def test_trim_video(tmp_path: Path) -> None:
    info = trim_video(DEMO, tmp_path / "trim.mp4", start_s=1.0, duration_s=0.5, width=320)
    assert (info.width, info.height) == (320, 180)
    assert info.fps == pytest.approx(24000 / 1001)
    assert info.frame_count == 12  # frames 24 .. 35
    with pytest.raises(InputError, match="no frames between"):
        trim_video(DEMO, tmp_path / "late.mp4", start_s=60.0, duration_s=1.0, width=320)
    assert not (tmp_path / "late.mp4").exists()


def write_timed_video(path: Path, frames: list[np.ndarray], times: list[int], time_base: Fraction,
                      rotation_cw: int = 0) -> Path:
    """An H.264 MP4 whose frame i is shown at times[i] * time_base seconds (a variable rate when the steps
    differ), with a display matrix that shows the stored frames turned `rotation_cw` degrees clockwise (0, 90,
    -90 or 180; 90 as a phone held upright writes it); PyAV cannot write one, so the track header is patched."""
    height, width = frames[0].shape[:2]
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=Fraction(1, 1) / time_base)
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.time_base = stream.codec_context.time_base = time_base
        stream.options = {"crf": "10", "bf": "0"}
        for frame, time in zip(frames, times, strict=True):
            video_frame = av.VideoFrame.from_ndarray(frame, format="bgr24")
            video_frame.pts, video_frame.time_base = time, time_base
            container.mux(stream.encode(video_frame))
        container.mux(stream.encode(None))
    if rotation_cw:
        # tkhd version 0: version/flags, times and track id, reserved, duration, reserved, layer..volume, then
        # the 3x3 matrix a b u / c d v / x y w (a..d in 16.16 fixed point).
        cos, sin = round(np.cos(np.radians(rotation_cw))), round(np.sin(np.radians(rotation_cw)))
        data = bytearray(path.read_bytes())
        start = data.index(b"tkhd") + 4
        assert data[start] == 0, "expected a version-0 track header"
        offset = start + 4 + 12 + 4 + 4 + 8 + 8
        matrix = (cos << 16, sin << 16, 0, -sin << 16, cos << 16, 0, 0, 0, 1 << 30)
        data[offset: offset + 36] = struct.pack(">9i", *matrix)
        path.write_bytes(bytes(data))
    return path


def grey(level: int, width: int = 64, height: int = 48) -> np.ndarray:
    return np.full((height, width, 3), level, np.uint8)


def test_variable_frame_rate_is_resampled_to_the_typical_rate(tmp_path: Path) -> None:
    # 24 fps, then 12 fps, then 8 fps (times in 1/24 s): 12 intervals, their median one 24th of a second.
    times = [0, 1, 2, 3, 4, 5, 6, 7, 9, 11, 13, 16, 19]
    path = write_timed_video(tmp_path / "vfr.mp4", [grey(10 + 12 * i) for i in range(13)], times, Fraction(1, 24))
    info = probe_video(path)
    assert info.fps == 24 and info.frame_count == 20 and info.source_frames == 13
    assert info.variable_rate and info.dropped_frames == 0 and info.repeated_frames == 6
    reader = iter_frames(path)
    shown = [round((frame.mean() - 10) / 12) for _, frame in reader]
    # Grid time k / 24 s shows the source frame nearest to it (the earlier on a tie): each frame keeps its time.
    expected_source_times = [0, 1, 2, 3, 4, 5, 6, 7, 7, 9, 9, 11, 11, 13, 13, 16, 16, 16, 19, 19]
    assert shown == [times.index(t) for t in expected_source_times]
    assert reader.frames_read == 20 and reader.missing_frames == 0


def test_variable_rate_faster_than_typical_drops_frames(tmp_path: Path) -> None:
    # Mostly 10 fps (times in 1/30 s) with a burst at 30 fps: the burst's in-between frames are dropped.
    times = [0, 3, 6, 9, 10, 11, 12, 15, 18, 21, 24]
    path = write_timed_video(tmp_path / "burst.mp4", [grey(10 + 20 * i) for i in range(11)], times, Fraction(1, 30))
    info = probe_video(path)
    assert info.fps == 10 and info.frame_count == 9 and info.dropped_frames == 2
    shown = [round((frame.mean() - 10) / 20) for _, frame in iter_frames(path)]
    assert shown == [0, 1, 2, 3, 6, 7, 8, 9, 10]


@pytest.mark.parametrize("rotation_cw, upright", [(90, cv2.ROTATE_90_CLOCKWISE), (-90, cv2.ROTATE_90_COUNTERCLOCKWISE),
                                                  (180, cv2.ROTATE_180)])
def test_rotation_metadata_turns_frames_upright(tmp_path: Path, rotation_cw: int, upright: int) -> None:
    stored = grey(40)
    stored[:12, :16] = (255, 255, 255)  # a white block in the stored frame's top-left corner
    stored[-12:, :16] = (0, 0, 255)  # a red block in its bottom-left corner
    path = write_timed_video(tmp_path / "rotated.mp4", [stored] * 3, [0, 1, 2], Fraction(1, 25), rotation_cw)
    info = probe_video(path)
    expected = cv2.rotate(stored, upright)
    assert (info.height, info.width) == expected.shape[:2]
    frames = [frame for _, frame in iter_frames(path)]
    assert len(frames) == 3 and frames[0].shape == expected.shape
    assert np.abs(frames[0].astype(int) - expected).mean() < 6
    small = next(iter(iter_frames(path, max_width=info.width // 2)))[1]
    assert small.shape[:2] == (expected.shape[0] // 2, expected.shape[1] // 2)


def test_prefetching_reader_gives_the_same_frames_and_stops_early_cleanly() -> None:
    plain = [frame for _, frame in iter_frames(DEMO, max_width=160)]
    prefetched = iter_frames(DEMO, max_width=160, prefetch=4)
    assert all(np.array_equal(a, b) for a, (_, b) in zip(plain, prefetched, strict=True))
    for index, _ in prefetched:  # leaving the loop early stops the decoding thread
        if index == 5:
            break
    assert prefetched.frames_read <= 6 + 4 + 1


@pytest.mark.parametrize("rotation_cw", [0, 90])
def test_yuv420_pictures_are_the_bgr_frames_without_conversion(tmp_path: Path, rotation_cw: int) -> None:
    # A variable rate (one frame shown twice) and odd scaled sizes: the pictures follow the BGR frames.
    stored = gradient_frames(4, 64, 48)
    path = write_timed_video(tmp_path / "video.mp4", stored, [0, 1, 3, 4], Fraction(1, 25), rotation_cw)
    for max_width in (None, 47):
        bgr = iter_frames(path, max_width=max_width)
        yuv = iter_frames(path, max_width=max_width, prefetch=2, pixel_format="yuv420p")
        width, height = bgr.output_size
        assert yuv.output_size == (width + width % 2, height + height % 2)
        pairs = list(zip(bgr, yuv, strict=True))
        assert len(pairs) == 5
        for (_, frame), (_, picture) in pairs:
            assert picture.format.name == "yuv420p" and (picture.width, picture.height) == yuv.output_size
            as_bgr = cv2.resize(picture.to_ndarray(format="bgr24"), (width, height), interpolation=cv2.INTER_AREA)
            assert np.abs(as_bgr.astype(int) - frame).mean() < 4.0
    with pytest.raises(ValueError, match="pixel_format"):
        iter_frames(path, pixel_format="rgb24")


def test_writer_encodes_one_reused_yuv420_picture_frame_after_frame(tmp_path: Path) -> None:
    path = tmp_path / "yuv.mp4"
    levels = [30, 200, 90, 160]
    picture = None
    with VideoWriter(path, 25.0, 64, 48, preset="ultrafast") as writer:
        for level in levels:
            source = av.VideoFrame.from_ndarray(grey(level), format="bgr24").reformat(format="yuv420p")
            picture = copy_yuv420(source, picture)  # the same picture, rewritten for every frame
            luma = yuv420_planes(picture)[0]
            luma[:8] = 255  # drawn on after the copy
            writer.write_yuv420(picture)
        with pytest.raises(ValueError, match="64x48 yuv420p"):
            writer.write_yuv420(av.VideoFrame(32, 48, "yuv420p"))
    frames = [frame for _, frame in iter_frames(path)]
    assert [round(float(frame[8:].mean())) for frame in frames] == pytest.approx(levels, abs=3)
    assert all(frame[:6].min() > 240 for frame in frames)
