"""Reading videos and writing browser-playable H.264 MP4 files, both through PyAV (FFmpeg).

Frames are BGR uint8 arrays of shape (H, W, 3), upright: a video's rotation metadata (the display matrix phones
write) is applied to every frame. Time comes from the container's presentation timestamps (PTS): a video with a
variable frame rate is resampled to a constant rate, its typical (median) frame interval, by giving each time
on that grid the source frame nearest to it, so that frame i is always at time i / fps (see README, "Time and
orientation"). A reader can also hand out the decoder's yuv420p pictures (`pixel_format="yuv420p"`), which a
writer encodes as they are (`VideoWriter.write_yuv420`): no colour conversion either way.
"""

from __future__ import annotations

import contextlib
import functools
import os
import queue
import re
import threading
from collections.abc import Generator, Iterator, Sequence
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Generic, Literal, TypeVar, cast, overload

import av
import cv2
import numpy as np

from ..errors import InputError
from .atomic import atomic_path

RATE_SNAP = 0.01
"""A stated frame rate within this fraction of the median frame interval's rate is taken as the exact rate."""

_UPRIGHT = {90: cv2.ROTATE_90_CLOCKWISE, 180: cv2.ROTATE_180, 270: cv2.ROTATE_90_COUNTERCLOCKWISE}


@dataclass(frozen=True)
class VideoInfo:
    """What a video file says about itself, after resampling to a constant rate and turning frames upright.

    fps: frames per second of the constant-rate frames. frame_count: frames the container announces, on that
    grid (a truncated file may hold fewer). width, height: size in pixels of an upright decoded frame.
    rotation: degrees clockwise (0, 90, 180, 270) that turn the stored frames upright.
    source_frames: frames the container holds. repeated_frames, dropped_frames: source frames shown twice or
    more, or not at all, on the constant-rate grid (both 0 for a constant-rate video).
    """

    path: Path
    fps: float
    frame_count: int
    width: int
    height: int
    rotation: int = 0
    source_frames: int = 0
    repeated_frames: int = 0
    dropped_frames: int = 0

    @property
    def variable_rate(self) -> bool:
        """True when resampling to the constant rate repeats or drops source frames."""
        return self.repeated_frames > 0 or self.dropped_frames > 0


@dataclass(frozen=True)
class _Timeline:
    """How the source frames map onto the constant-rate grid: slots[pts] grid frames show the frame at pts.
    pts, counts: every source frame's presentation timestamp, sorted, and its number of grid frames (both empty
    for a stream without usable timestamps, which cannot be sought)."""

    info: VideoInfo
    slots: dict[int, int]
    pts: np.ndarray
    counts: np.ndarray

    def source_of(self, frame: int) -> tuple[int, int] | None:
        """(pts of the source frame that grid frame `frame` shows, the grid frame where that source frame first
        shows), or None where the stream cannot be sought or `frame` lies past its last source frame."""
        shown_until = np.cumsum(self.counts)
        source = int(np.searchsorted(shown_until, frame, side="right"))
        if source >= len(self.pts):
            return None
        return int(self.pts[source]), int(shown_until[source] - self.counts[source])


def _open_container(path: Path) -> av.container.InputContainer:
    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, UnicodeDecodeError, ValueError):
        raise InputError(f"{path}: not a readable video file.") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{path}: not a readable video file (it holds no video stream).")
    return container


def _upright_rotation(frame: av.VideoFrame) -> int:
    """Degrees clockwise (0, 90, 180, 270) that turn `frame` upright, from its display matrix."""
    # PyAV gives the display matrix's counter-clockwise angle; a phone held upright records -90.
    return int(round(-frame.rotation / 90.0)) % 4 * 90


def _grid_slots(times: np.ndarray, stated_rates: list[Fraction]) -> tuple[Fraction, np.ndarray]:
    """The constant rate and, per source frame, how many grid frames show it.

    times: (N,) sorted presentation times in seconds from the first frame. The rate is that of the median frame
    interval, or the stated rate closest to it if within RATE_SNAP (keeps 24000/1001 exact). Grid time k / rate
    shows the source frame nearest to it (the earlier one on a tie).
    """
    if len(times) < 2:
        return next((r for r in stated_rates if r), Fraction(30)), np.ones(len(times), dtype=np.int64)
    typical = float(np.median(np.diff(times)))
    mismatch = {r: abs(float(r) * typical - 1.0) for r in stated_rates if r}
    closest = min(mismatch, key=lambda r: mismatch[r], default=None)
    rate = closest if closest is not None and mismatch[closest] < RATE_SNAP \
        else Fraction(1.0 / typical).limit_denominator(1001)
    grid = np.arange(int(round(times[-1] * rate)) + 1) / float(rate)
    after = np.clip(np.searchsorted(times, grid), 0, len(times) - 1)
    before = np.maximum(after - 1, 0)
    tie = 1e-9  # s: rounding of the timestamps, so that exact ties go to the earlier frame
    nearest = np.where(np.abs(times[before] - grid) <= np.abs(times[after] - grid) + tie, before, after)
    return rate, np.bincount(nearest, minlength=len(times))


def _timeline(path: str | os.PathLike) -> _Timeline:
    """The timeline of `path`, read once per version of the file (a run probes its video several times)."""
    path = Path(path)
    if not path.exists():
        if re.match(r"[a-zA-Z][a-zA-Z0-9+.-]+:/", str(path)):  # a URL (not a drive letter); Path folds its "//"
            raise InputError(f"{path}: looks like a URL; network streams are not read: download the video first.")
        raise InputError(f"{path}: no such video file.")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a video file.")
    stat = path.stat()
    if stat.st_size == 0:
        raise InputError(f"{path}: the video file is empty (0 bytes).")
    return _read_timeline(path, stat.st_size, stat.st_mtime_ns)


@functools.lru_cache(maxsize=8)
def _read_timeline(path: Path, size: int, mtime_ns: int) -> _Timeline:
    """Demux every packet of `path` for its timestamps and decode the first frame; any problem raises InputError.
    size and mtime_ns key the cache (a file rewritten in place is read again)."""
    container = _open_container(path)
    try:
        stream = container.streams.video[0]
        pts: list[int] = []
        first: av.VideoFrame | None = None
        try:
            for packet in container.demux(stream):
                if packet.size == 0:
                    continue
                if packet.pts is not None:
                    pts.append(packet.pts)
                if first is None:
                    with contextlib.suppress(av.error.FFmpegError):
                        first = next(iter(stream.decode(packet)), None)
            if first is None:
                with contextlib.suppress(av.error.FFmpegError):
                    first = next(iter(stream.codec_context.decode(None)), None)
        except av.error.FFmpegError:
            pass  # a damaged tail: the packets before it count
        stated = [r for r in (stream.average_rate, stream.guessed_rate) if r is not None and r > 0]
        announced = int(stream.frames or 0)
        duration = float(stream.duration * stream.time_base) if stream.duration and stream.time_base else 0.0
        time_base = float(stream.time_base) if stream.time_base else 0.0  # read before close: it frees the stream
    finally:
        container.close()
    if first is None:
        raise InputError(f"{path}: the video has no decodable frame.")
    if not stated and len(pts) < 2:
        raise InputError(f"{path}: the video does not state a frame rate.")
    unique = np.unique(np.asarray(pts, dtype=np.int64))
    stream_has_times = len(unique) == len(pts) and len(unique) >= 2 and time_base > 0
    if stream_has_times:
        rate, slots = _grid_slots((unique - unique[0]) * time_base, stated)
    else:  # no usable timestamps (raw streams): frames are taken at the stated rate
        rate, slots = stated[0], np.ones(max(len(pts), 1), dtype=np.int64)
    rotation = _upright_rotation(first)
    width, height = (first.height, first.width) if rotation in (90, 270) else (first.width, first.height)
    source_frames = max(len(pts), 1)
    # A truncated file announces more frames, or a longer duration, than it holds.
    frame_count = max(int(slots.sum()), announced if not stream_has_times else 0, round(duration * float(rate)))
    info = VideoInfo(path=path, fps=float(rate), frame_count=frame_count, width=width, height=height,
                     rotation=rotation, source_frames=source_frames, repeated_frames=int((slots > 1).sum()),
                     dropped_frames=int((slots == 0).sum()))
    if not stream_has_times:
        return _Timeline(info, {}, np.zeros(0, np.int64), np.zeros(0, np.int64))
    return _Timeline(info, {int(p): int(s) for p, s in zip(unique, slots, strict=True) if s != 1}, unique, slots)


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Open `path`, read its timestamps, decode its first frame and return its VideoInfo; any problem raises
    InputError."""
    return _timeline(path).info


def scaled_height(width: int, height: int, new_width: int) -> int:
    """Height in whole pixels of a `width` x `height` image scaled to `new_width` pixels wide."""
    return max(1, round(height * new_width / width))


def resize_to_width(frame: np.ndarray, width: int) -> np.ndarray:
    """Scale (H, W, 3) `frame` to `width` pixels wide, keeping its aspect ratio."""
    size = (width, scaled_height(frame.shape[1], frame.shape[0], width))
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA if width < frame.shape[1] else cv2.INTER_LINEAR)


_END = object()
Frame = TypeVar("Frame", np.ndarray, av.VideoFrame)  # what a FrameReader yields: BGR arrays or yuv420p pictures


PIXEL_FORMATS = ("bgr24", "yuv420p")


class FrameReader(Generic[Frame]):
    """Iterable over (index, frame) of a video's upright, constant-rate frames; re-iterating starts again.

    Decoding stops quietly where the file stops decoding. After a pass, `frames_read` is the index after the last
    frame that came out and `missing_frames` how many of those the container announced did not (> 0 for a
    truncated file).
    start_frame: the first frame of a pass (0: the first of the video); frames keep their indices, those of a
    pass from 0. A stream with timestamps is sought to the keyframe before it (docs/decisions/detect-two-graphs.md).
    max_width: frames wider than this are scaled down to it (in the decoder's colour conversion).
    prefetch: frames decoded ahead in a background thread (0: decode in the caller's thread); decoding then
    overlaps with whatever the caller does with each frame.
    pixel_format: "bgr24" yields BGR arrays (H, W, 3) of the caller's own; "yuv420p" yields av.VideoFrame
    pictures in yuv420p at an even size (odd sizes are stretched by one pixel), often the decoder's own, shared
    with later frames: read them, or copy them (`copy_yuv420`) to draw on.
    """

    def __init__(self, path: str | os.PathLike, max_width: int | None = None, prefetch: int = 0,
                 pixel_format: str = "bgr24", start_frame: int = 0) -> None:
        if pixel_format not in PIXEL_FORMATS:
            raise ValueError(f"pixel_format must be one of {PIXEL_FORMATS}, got {pixel_format!r}.")
        if start_frame < 0:
            raise ValueError(f"start_frame must be 0 or more, got {start_frame}.")
        self._timeline = _timeline(path)
        self.info = self._timeline.info
        self._slots = self._timeline.slots
        self.start_frame = start_frame
        self.max_width = max_width
        self.prefetch = prefetch
        self.pixel_format = pixel_format
        self.frames_read = 0

    @property
    def output_size(self) -> tuple[int, int]:
        """(width, height) of the frames this reader yields."""
        width, height = self.info.width, self.info.height
        if self.max_width is not None and width > self.max_width:
            width, height = self.max_width, scaled_height(width, height, self.max_width)
        if self.pixel_format == "yuv420p":  # chroma is stored per 2 x 2 pixels
            width, height = width + width % 2, height + height % 2
        return width, height

    def __iter__(self) -> Generator[tuple[int, Frame], None, None]:  # close() stops a pass part-way
        self.frames_read = self.start_frame
        if self.prefetch <= 0:
            yield from self._decode(threading.Event())
            return
        frames: queue.Queue = queue.Queue(maxsize=self.prefetch)
        stop = threading.Event()

        def offer(item: object) -> None:
            while not stop.is_set():  # once the consumer has stopped, nobody takes items any more
                with contextlib.suppress(queue.Full):
                    frames.put(item, timeout=0.1)
                    return

        def produce() -> None:
            try:
                for item in self._decode(stop):
                    offer(item)
            except BaseException as error:  # handed to the consumer, which raises it
                offer(error)
            finally:
                offer(_END)

        producer = threading.Thread(target=produce, name="physmocap-decode", daemon=True)
        producer.start()
        try:
            while (item := frames.get()) is not _END:
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            stop.set()
            with contextlib.suppress(queue.Empty):
                while True:  # unblock a producer waiting on a full queue
                    frames.get_nowait()
            producer.join()

    def _decode(self, stop: threading.Event, seek: bool = True) -> Iterator[tuple[int, Frame]]:
        width, height = self.output_size
        rotation = self.info.rotation
        stored = (height, width) if rotation in (90, 270) else (width, height)
        container = _open_container(self.info.path)
        try:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            # index: the grid frame where the next source frame starts showing
            try:
                position = self._seek(container, stream) if seek else (0, None)
            except av.error.FFmpegError:  # a file FFmpeg cannot seek in is decoded from frame 0
                yield from self._decode(stop, seek=False)
                return
            if position is None:
                return
            index, first_pts = position
            for frame in _decoded_frames(container, stream):
                if stop.is_set():
                    return
                if first_pts is not None and frame.pts is not None and frame.pts < first_pts:
                    continue  # decoded from the keyframe before the start, only to decode what follows
                if first_pts is not None and frame.pts != first_pts:  # the seek missed the start: decode from 0
                    yield from self._decode(stop, seek=False)
                    return
                first_pts = None
                copies = 1 if frame.pts is None else self._slots.get(frame.pts, 1)
                first_copy = max(0, self.start_frame - index)
                index += copies
                if copies <= first_copy:
                    continue
                if self.pixel_format == "yuv420p":
                    # The same size and format come back as the decoder's picture itself, without a copy.
                    picture = frame.reformat(width=stored[0], height=stored[1], format="yuv420p",
                                             interpolation="AREA")
                    if rotation:
                        picture = _rotated_yuv420(picture, rotation)
                    for _ in range(first_copy, copies):  # repeats share the picture: callers copy before drawing
                        self.frames_read += 1
                        yield self.frames_read - 1, cast(Frame, picture)
                    continue
                image: np.ndarray = frame.to_ndarray(format="bgr24", width=stored[0], height=stored[1],
                                                     interpolation="AREA")
                if rotation:
                    image = cv2.rotate(image, _UPRIGHT[rotation])
                for copy in range(first_copy, copies):
                    self.frames_read += 1
                    # Each repeat is its own array: callers may draw on the frames they get.
                    yield self.frames_read - 1, cast(Frame, image if copy == copies - 1 else image.copy())
        finally:
            container.close()

    def _seek(self, container: av.container.InputContainer,
              stream: av.VideoStream) -> tuple[int, int | None] | None:
        """Position `container` for a pass from `start_frame`: (the grid frame where the next decoded source
        frame starts, the pts of the first source frame to keep, None to keep every one), or None when the start
        lies past the last frame. Seeks to the keyframe before the start where the stream has timestamps;
        otherwise decoding starts at frame 0 and the frames before the start are not converted to images."""
        if self.start_frame == 0:
            return 0, None
        source = self._timeline.source_of(self.start_frame)
        if source is None:
            return None if len(self._timeline.pts) else (0, None)
        first_pts, first_index = source
        container.seek(first_pts, stream=stream, backward=True, any_frame=False)
        return first_index, first_pts

    @property
    def missing_frames(self) -> int:
        """Announced frames that the last pass did not decode (0 for an intact file)."""
        return max(0, self.info.frame_count - self.frames_read)


def yuv420_planes(picture: av.VideoFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Views, without a copy, of a yuv420p picture's planes: Y (H, W) and U, V (H/2, W/2); writing to them writes
    the picture."""
    if picture.format.name != "yuv420p":
        raise ValueError(f"expected a yuv420p picture, got {picture.format.name}.")
    views = []
    for plane in picture.planes:
        rows = np.frombuffer(memoryview(plane), np.uint8).reshape(plane.height, plane.line_size)
        views.append(rows[:, :plane.width])
    return views[0], views[1], views[2]


def copy_yuv420(source: av.VideoFrame, target: av.VideoFrame | None = None) -> av.VideoFrame:
    """`source` (yuv420p) copied into `target`, a picture of the caller's own of the same size (a new one if None),
    so that drawing on it leaves the decoder's pictures untouched."""
    if target is None or (target.width, target.height) != (source.width, source.height):
        target = av.VideoFrame(source.width, source.height, "yuv420p")
    for source_plane, target_plane in zip(yuv420_planes(source), yuv420_planes(target), strict=True):
        target_plane[...] = source_plane
    return target


def _rotated_yuv420(picture: av.VideoFrame, rotation: int) -> av.VideoFrame:
    """A new yuv420p picture: `picture` turned `rotation` degrees clockwise, plane by plane."""
    planes = [cv2.rotate(plane, _UPRIGHT[rotation]) for plane in yuv420_planes(picture)]
    upright = av.VideoFrame(planes[0].shape[1], planes[0].shape[0], "yuv420p")
    for target, plane in zip(yuv420_planes(upright), planes, strict=True):
        target[...] = plane
    return upright


def _decoded_frames(container: av.container.InputContainer, stream: av.VideoStream) -> Iterator[av.VideoFrame]:
    """The frames of `stream` in presentation order; undecodable packets are skipped, a damaged tail ends it."""
    try:
        for packet in container.demux(stream):
            try:
                yield from stream.decode(packet)
            except av.error.InvalidDataError:
                continue
    except av.error.FFmpegError:
        return


@overload
def iter_frames(path: str | os.PathLike, max_width: int | None = None, prefetch: int = 0,
                pixel_format: Literal["bgr24"] = "bgr24", start_frame: int = 0) -> FrameReader[np.ndarray]: ...


@overload
def iter_frames(path: str | os.PathLike, max_width: int | None = None, prefetch: int = 0, *,
                pixel_format: Literal["yuv420p"], start_frame: int = 0) -> FrameReader[av.VideoFrame]: ...


def iter_frames(path: str | os.PathLike, max_width: int | None = None, prefetch: int = 0,
                pixel_format: str = "bgr24", start_frame: int = 0) -> FrameReader:
    """Frames of `path` as (index, upright BGR frame) at a constant rate; frames wider than `max_width` are
    scaled down to it, `prefetch` frames are decoded ahead in a thread (see FrameReader; pixel_format "yuv420p"
    yields the decoder's pictures instead of BGR arrays; start_frame: the first frame, indices unchanged).

    With max_width None the frames keep the native resolution. Raises InputError as probe_video does.
    """
    return FrameReader(path, max_width, prefetch, pixel_format, start_frame)


def mp4_output_path(path: str | os.PathLike) -> Path:
    """`path` as a Path; InputError unless it names an .mp4 file (the writers write MP4 only)."""
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise InputError(f"{path}: video output must be an .mp4 file.")
    return path


class VideoWriter:
    """Write BGR frames to an H.264 MP4 (libx264, yuv420p, moov atom first) that browsers play.

    Odd frame sizes are padded by one replicated row/column, as yuv420p needs even sizes. The file appears under
    `path` only when close() succeeds; until then it is written to a temporary file beside it, which is removed
    if the writer leaves its `with` block through an exception.
    crf: x264's constant rate factor (0-51, lower: better and larger); qp: a constant quantiser instead (0-51),
    which spares x264 the half-size analysis its rate control runs on every frame. faststart: the moov atom
    before the frames, so that a browser plays the file while loading it (closing then rewrites the file once);
    False for files only read back whole, such as the parts join_video_parts joins.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        fps: float,
        width: int,
        height: int,
        *,
        crf: int = 23,
        qp: int | None = None,
        preset: str = "medium",
        faststart: bool = True,
    ) -> None:
        self.path = mp4_output_path(path)
        if width <= 0 or height <= 0:
            raise ValueError(f"frame size must be positive, got {width}x{height}.")
        self.width, self.height = int(width), int(height)
        self.frames_written = 0
        self._files = contextlib.ExitStack()
        self._tmp_path = self._files.enter_context(atomic_path(self.path))
        self._closed = False
        try:
            self._container = av.open(str(self._tmp_path), "w", format="mp4",
                                      options={"movflags": "+faststart"} if faststart else {})
            # 23.976... fps must stay 24000/1001, not a long binary fraction.
            self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
            self._stream.width = self.width + self.width % 2
            self._stream.height = self.height + self.height % 2
            self._stream.pix_fmt = "yuv420p"
            rate = {"crf": str(crf)} if qp is None else {"qp": str(qp)}
            self._stream.options = {**rate, "preset": preset}
        except BaseException as error:
            self._abort(error)
            raise

    def write(self, frame: np.ndarray) -> None:
        """Append one (height, width, 3) uint8 BGR frame."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is already closed.")
        if frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise ValueError(
                f"expected a ({self.height}, {self.width}, 3) uint8 frame, got {frame.shape} {frame.dtype}."
            )
        pad_bottom, pad_right = self._stream.height - self.height, self._stream.width - self.width
        if pad_bottom or pad_right:
            frame = cv2.copyMakeBorder(frame, 0, pad_bottom, 0, pad_right, cv2.BORDER_REPLICATE)
        video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="bgr24")
        self._container.mux(self._stream.encode(video_frame.reformat(format="yuv420p")))
        self.frames_written += 1

    def write_yuv420(self, picture: av.VideoFrame) -> None:
        """Append one yuv420p picture of the stream's (even) size as it is, without a colour conversion. x264
        copies the picture while encoding it, so the caller may reuse it for the next frame."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is already closed.")
        expected = (self._stream.width, self._stream.height)
        if picture.format.name != "yuv420p" or (picture.width, picture.height) != expected:
            raise ValueError(f"expected a {expected[0]}x{expected[1]} yuv420p picture, got "
                             f"{picture.width}x{picture.height} {picture.format.name}.")
        picture.pts = None  # the encoder numbers the frames at the stream's constant rate
        self._container.mux(self._stream.encode(picture))
        self.frames_written += 1

    def close(self) -> None:
        """Finish the file and move it to its final name. Closing without any frame written is an error."""
        if self._closed:
            return
        if self.frames_written == 0:
            error = ValueError(f"{self.path}: no frames were written; no video was made.")
            self._abort(error)
            raise error
        try:
            self._container.mux(self._stream.encode(None))
            self._container.close()
        except BaseException as error:
            self._abort(error)
            raise
        self._closed = True
        self._tmp_path.chmod(0o644)  # the temporary file was created readable by its owner only
        self._files.close()

    def _abort(self, error: BaseException) -> None:
        """Drop the temporary file; nothing appears under the final name."""
        self._closed = True
        with contextlib.suppress(Exception):  # also when opening failed and there is no container
            self._container.close()
        # Handing the error to atomic_path makes it delete the temporary file instead of renaming it.
        self._files.__exit__(type(error), error, error.__traceback__)

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        if exc is None:
            self.close()
        elif not self._closed:
            self._abort(exc)


class PartsDiffer(ValueError):
    """Video parts that cannot be joined without re-encoding; `join_video_parts` wrote nothing."""


def _codec_parameters(stream: av.VideoStream) -> tuple:
    """What must be the same in every part of a joined video: codec, size, pixel format, rate, time base and
    extradata (H.264's SPS and PPS)."""
    codec = stream.codec_context
    return (codec.name, codec.width, codec.height, codec.pix_fmt, stream.average_rate, stream.time_base,
            bytes(codec.extradata or b""))


def join_video_parts(parts: Sequence[str | os.PathLike], path: str | os.PathLike) -> int:
    """Join the MP4 `parts`, written by VideoWriters with the same settings, into one MP4 `path` (moov first)
    without re-encoding: each part's packets follow the previous parts', their timestamps shifted by those parts'
    frames. Returns the frames written. The file appears under `path` only when it is complete.

    Raises PartsDiffer, writing nothing, where a part's codec parameters differ from the first's, its frame
    duration is not a whole number of time-base ticks, a part does not start on a keyframe or one before the last
    ends on one (two IDR pictures in a row may carry the same idr_pic_id, which H.264 forbids), or the decoding
    timestamps would not increase strictly across a joint.
    """
    path = mp4_output_path(path)
    if not parts:
        raise ValueError("join_video_parts needs at least one part.")
    with contextlib.ExitStack() as inputs:
        containers = [inputs.enter_context(_open_container(Path(part))) for part in parts]
        streams = [container.streams.video[0] for container in containers]
        first = streams[0]
        for part, stream in zip(parts[1:], streams[1:], strict=True):
            if _codec_parameters(stream) != _codec_parameters(first):
                raise PartsDiffer(f"{part}: its codec parameters differ from those of {parts[0]}.")
        if not first.average_rate or not first.time_base:
            raise PartsDiffer(f"{parts[0]}: states no frame rate or time base.")
        ticks_per_frame = 1 / (first.average_rate * first.time_base)
        if ticks_per_frame.denominator != 1:
            raise PartsDiffer(f"{parts[0]}: a frame lasts {ticks_per_frame} ticks of its time base, not a whole "
                              "number.")
        with atomic_path(path) as tmp, av.open(str(tmp), "w", format="mp4",
                                               options={"movflags": "+faststart"}) as output:
            joined = output.add_stream_from_template(first)
            joined.time_base = first.time_base
            frames, last_dts = 0, None
            for number, (part, container, stream) in enumerate(zip(parts, containers, streams, strict=True)):
                shift, part_frames, keyframe = frames * int(ticks_per_frame), 0, False
                for packet in container.demux(stream):
                    if packet.size == 0:
                        continue  # the demuxer's end-of-stream marker
                    keyframe = bool(packet.is_keyframe)
                    if part_frames == 0 and not keyframe:
                        raise PartsDiffer(f"{part}: does not start on a keyframe.")
                    if packet.pts is None or packet.dts is None:
                        raise PartsDiffer(f"{part}: a packet has no timestamp.")
                    packet.pts, packet.dts = packet.pts + shift, packet.dts + shift
                    if last_dts is not None and packet.dts <= last_dts:
                        raise PartsDiffer(f"{part}: its decoding timestamps would not follow the previous part's.")
                    last_dts = packet.dts
                    packet.stream = joined
                    output.mux(packet)
                    part_frames += 1
                if keyframe and number < len(parts) - 1:
                    raise PartsDiffer(f"{part}: ends on a keyframe, which the next part's first picture would follow.")
                frames += part_frames
    return frames


def trim_video(
    src: str | os.PathLike, dst: str | os.PathLike, start_s: float, duration_s: float, width: int
) -> VideoInfo:
    """Copy frames [start_s, start_s + duration_s) of `src`, scaled to `width` px wide, into H.264 MP4 `dst`.

    Frame i is at time i / fps. Returns the VideoInfo of the written file.
    """
    reader = iter_frames(src)
    info = reader.info
    first, stop = round(start_s * info.fps), round((start_s + duration_s) * info.fps)
    with VideoWriter(dst, info.fps, width, scaled_height(info.width, info.height, width)) as writer:
        for index, frame in reader:
            if index >= stop:
                break
            if index >= first:
                writer.write(resize_to_width(frame, width))
        if writer.frames_written == 0:
            raise InputError(f"{info.path}: has no frames between {start_s} s and {start_s + duration_s} s.")
    return probe_video(dst)
