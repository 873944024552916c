"""Video reading, writing and trimming on real files made inside the tests."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

import physmocap
from physmocap.errors import InputError
from physmocap.io.video import VideoWriter, iter_frames, probe_video, trim_video

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
