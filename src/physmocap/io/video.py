"""Reading videos (OpenCV) and writing browser-playable H.264 MP4 files (PyAV).

Frames are BGR uint8 arrays of shape (H, W, 3), as OpenCV gives them.
"""

from __future__ import annotations

import contextlib
import math
import os
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Iterator

import av
import cv2
import numpy as np

from ..errors import InputError
from .atomic import atomic_path


@dataclass(frozen=True)
class VideoInfo:
    """What a video file says about itself.

    fps: frames per second. frame_count: frames the container announces (a truncated file may hold fewer).
    width, height: size of a decoded frame in pixels.
    """

    path: Path
    fps: float
    frame_count: int
    width: int
    height: int


def _open_capture(path: Path) -> cv2.VideoCapture:
    # CAP_FFMPEG only: the default backend list would read "x_%02d.png"-like names as image sequences.
    return cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Open `path`, decode its first frame and return its VideoInfo; any problem raises InputError."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such video file.")
    if path.is_dir():
        raise InputError(f"{path}: is a directory, not a video file.")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: the video file is empty (0 bytes).")
    capture = _open_capture(path)
    try:
        if not capture.isOpened():
            raise InputError(f"{path}: not a readable video file.")
        decoded, frame = capture.read()
        if not decoded or frame is None:
            raise InputError(f"{path}: the video has no decodable frame.")
        fps = float(capture.get(cv2.CAP_PROP_FPS))
        frame_count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        capture.release()
    if not math.isfinite(fps) or fps <= 0:
        raise InputError(f"{path}: the video does not state a frame rate.")
    # The first frame's shape, not CAP_PROP_FRAME_WIDTH/HEIGHT, so that rotation metadata is accounted for.
    height, width = frame.shape[:2]
    return VideoInfo(path=path, fps=fps, frame_count=max(frame_count, 0), width=width, height=height)


def scaled_height(width: int, height: int, new_width: int) -> int:
    """Height in whole pixels of a `width` x `height` image scaled to `new_width` pixels wide."""
    return max(1, round(height * new_width / width))


def resize_to_width(frame: np.ndarray, width: int) -> np.ndarray:
    """Scale (H, W, 3) `frame` to `width` pixels wide, keeping its aspect ratio."""
    size = (width, scaled_height(frame.shape[1], frame.shape[0], width))
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA if width < frame.shape[1] else cv2.INTER_LINEAR)


class FrameReader:
    """Iterable over (index, frame) of a video; re-iterating starts again from the first frame.

    Decoding stops quietly where the file stops decoding. After a pass, `frames_read` says how many frames came
    out and `missing_frames` how many of those the container announced did not (> 0 for a truncated file).
    """

    def __init__(self, path: str | os.PathLike, max_width: int | None = None) -> None:
        self.info = probe_video(path)
        self.max_width = max_width
        self.frames_read = 0

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        capture = _open_capture(self.info.path)
        self.frames_read = 0
        try:
            while True:
                decoded, frame = capture.read()
                if not decoded or frame is None:
                    return
                if self.max_width is not None and frame.shape[1] > self.max_width:
                    frame = resize_to_width(frame, self.max_width)
                self.frames_read += 1
                yield self.frames_read - 1, frame
        finally:
            capture.release()

    @property
    def missing_frames(self) -> int:
        """Announced frames that the last pass did not decode (0 for an intact file)."""
        return max(0, self.info.frame_count - self.frames_read)


def iter_frames(path: str | os.PathLike, max_width: int | None = None) -> FrameReader:
    """Frames of `path` as (index, BGR frame); frames wider than `max_width` are scaled down to it.

    With max_width None the frames keep the native resolution. Raises InputError as probe_video does.
    """
    return FrameReader(path, max_width)


class VideoWriter:
    """Write BGR frames to an H.264 MP4 (libx264, yuv420p, moov atom first) that browsers play.

    Odd frame sizes are padded by one replicated row/column, as yuv420p needs even sizes. The file appears under
    `path` only when close() succeeds; until then it is written to a temporary file beside it, which is removed
    if the writer leaves its `with` block through an exception.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        fps: float,
        width: int,
        height: int,
        *,
        crf: int = 23,
        preset: str = "medium",
    ) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise InputError(f"{self.path}: video output must be an .mp4 file.")
        if width <= 0 or height <= 0:
            raise ValueError(f"frame size must be positive, got {width}x{height}.")
        self.width, self.height = int(width), int(height)
        self.frames_written = 0
        self._files = contextlib.ExitStack()
        self._tmp_path = self._files.enter_context(atomic_path(self.path))
        self._closed = False
        try:
            self._container = av.open(str(self._tmp_path), "w", format="mp4", options={"movflags": "+faststart"})
            # 23.976... fps must stay 24000/1001, not a long binary fraction.
            self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
            self._stream.width = self.width + self.width % 2
            self._stream.height = self.height + self.height % 2
            self._stream.pix_fmt = "yuv420p"
            self._stream.options = {"crf": str(crf), "preset": preset}
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

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, traceback: TracebackType | None
    ) -> None:
        if exc is None:
            self.close()
        elif not self._closed:
            self._abort(exc)


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
