"""MediaPipe Pose (legacy solution, BlazePose full) on the frames of a video, following one person.

Person following: the first person found (MediaPipe's choice on the whole frame, or the person inside a given
box) is the track. In each later frame MediaPipe sees only a search region around the track's last landmark box
(the rest of the frame is blanked), grown by a margin, and more the longer the person has been unseen, up to the
whole frame. A sighting whose torso centre moved or whose torso size changed more than a person plausibly can
since the last sighting is rejected as a "track jump"; frames without a person are "no person". Rejected frames
are invalid and hold zeros.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, BinaryIO

import cv2
import numpy as np

from ..errors import InputError
from ..io.video import iter_frames, resize_to_width
from ..landmarks import LANDMARK_INDEX, NUM_LANDMARKS
from ..motion import Observations
from .repeats import RepeatMarker

logger = logging.getLogger(__name__)

SEARCH_MARGIN = 0.5
"""The search region adds this fraction of the landmark box's larger side on every side of the box."""
MAX_STEP = 0.75
"""Torso sizes the torso centre may move between consecutive frames before the sighting counts as a jump."""
MAX_SIZE_RATIO = 1.5
"""Factor by which the torso size may grow or shrink per frame before the sighting counts as a jump."""
MAX_SPEED = 8.0
"""Torso sizes per second a person may move while unseen (about 4 m/s): widens the gate and the search region."""
PREFETCH_FRAMES = 4
"""Frames decoded ahead of detection in the reader's thread (docs/decisions/decode-thread.md)."""
_TORSO = [LANDMARK_INDEX[name] for name in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")]

# Informational lines that MediaPipe's C++ code writes straight to stderr; any other line is passed through.
_BENIGN_NATIVE_LOG_LINES = (
    "Created TensorFlow Lite XNNPACK delegate for CPU",
    "All log messages before absl::InitializeLog() is called are written to STDERR",
    "inference_feedback_manager.cc",
    "Using NORM_RECT without IMAGE_DIMENSIONS is only supported for the square ROI",
)

Box = tuple[float, float, float, float]
"""(x0, y0, x1, y1) in pixels of the native frame."""


def torso_centre_and_size(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (2,) of the shoulders and hips and the torso size in pixels, from (33, 2) landmark positions.

    The size is the longer diagonal of the shoulder-hip quadrilateral, which stays large whether the person faces
    the camera, turns sideways or leans towards it.
    """
    left_shoulder, right_shoulder, left_hip, right_hip = xy[_TORSO]
    size = max(np.linalg.norm(left_shoulder - right_hip), np.linalg.norm(right_shoulder - left_hip))
    return xy[_TORSO].mean(axis=0), float(size)


@dataclass(frozen=True)
class Sighting:
    """The tracked person in one frame: landmark box (x0, y0, x1, y1), torso centre (2,) and size, in pixels."""

    frame: int
    box: np.ndarray
    centre: np.ndarray
    size: float

    @classmethod
    def from_landmarks(cls, frame: int, xy: np.ndarray) -> Sighting:
        """From (33, 2) landmark positions in pixels."""
        centre, size = torso_centre_and_size(xy)
        return cls(frame, np.concatenate([xy.min(axis=0), xy.max(axis=0)]), centre, size)


def is_track_jump(last: Sighting, new: Sighting, fps: float) -> bool:
    """True if `new` is implausibly far from, or of implausibly different size than, the `last` sighting."""
    frames = new.frame - last.frame
    step = np.linalg.norm(new.centre - last.centre)
    allowed_step = (MAX_STEP + MAX_SPEED * (frames - 1) / fps) * last.size
    size_ratio = max(new.size, 1e-6) / max(last.size, 1e-6)
    allowed_ratio = MAX_SIZE_RATIO**frames
    return bool(step > allowed_step or size_ratio > allowed_ratio or size_ratio < 1 / allowed_ratio)


def grow_box(box: Sequence[float] | np.ndarray, margin: float,
             image_size: tuple[int, int]) -> tuple[int, int, int, int]:
    """`box` (x0, y0, x1, y1) grown by `margin` pixels on every side, as whole pixels clamped to the image."""
    width, height = image_size
    x0, y0, x1, y1 = box
    return (
        max(0, int(np.floor(x0 - margin))),
        max(0, int(np.floor(y0 - margin))),
        min(width, int(np.ceil(x1 + margin))),
        min(height, int(np.ceil(y1 + margin))),
    )


def search_region(last: Sighting, frame: int, fps: float, image_size: tuple[int, int]) -> tuple[int, int, int, int]:
    """Where to look for the person last seen as `last` in `frame`: pixel region (x0, y0, x1, y1), end exclusive."""
    box_side = max(last.box[2] - last.box[0], last.box[3] - last.box[1])
    unseen_s = (frame - last.frame - 1) / fps
    return grow_box(last.box, SEARCH_MARGIN * box_side + MAX_SPEED * last.size * unseen_s, image_size)


class _PoseModel:
    """MediaPipe Pose on pixel regions of BGR frames, with its native log spam filtered out of stderr.

    MediaPipe logs while it loads its models, when it is reset and on its first landmark inference, never in
    between; only those calls are filtered, so that other threads' output (a progress bar beside a second graph)
    goes straight to the terminal the rest of the time."""

    def __init__(self) -> None:
        import mediapipe as mp

        with _native_stderr_filtered():
            self._pose = mp.solutions.pose.Pose(
                static_image_mode=False,
                model_complexity=1,
                smooth_landmarks=True,
                min_detection_confidence=0.5,
                min_tracking_confidence=0.5,
            )
            self._wait_until_ready()
        self._landmarks_seen = False

    def detect(
        self, frame: np.ndarray, region: tuple[int, int, int, int], max_width: int | None
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Landmarks of the person in `region` of (H, W, 3) BGR `frame`, or None if there is nobody there.

        The frame is scaled down to `max_width` and blanked outside the region, so that MediaPipe keeps seeing
        images of one geometry (its tracking and smoothing work in normalised image coordinates).
        Returns keypoints (33, 3): x, y in native pixels (integer coordinates at pixel centres) and visibility;
        and world landmarks (33, 3) in metres, hip-centred, x right, y down, z away from the camera.
        """
        height, width = frame.shape[:2]
        if max_width is not None and width > max_width:
            frame = resize_to_width(frame, max_width)
        scale_x, scale_y = frame.shape[1] / width, frame.shape[0] / height
        x0, y0 = int(region[0] * scale_x), int(region[1] * scale_y)
        x1, y1 = int(np.ceil(region[2] * scale_x)), int(np.ceil(region[3] * scale_y))
        if (x0, y0, x1, y1) == (0, 0, frame.shape[1], frame.shape[0]):
            image = frame
        else:
            image = np.zeros_like(frame)
            image[y0:y1, x0:x1] = frame[y0:y1, x0:x1]
        with _native_stderr_filtered() if not self._landmarks_seen else contextlib.nullcontext():
            result: Any = self._pose.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
        if result.pose_landmarks is None:
            return None
        self._landmarks_seen = True
        keypoints = np.array([(p.x, p.y, p.visibility) for p in result.pose_landmarks.landmark])
        world = np.array([(p.x, p.y, p.z) for p in result.pose_world_landmarks.landmark])
        # MediaPipe's normalised coordinates run from the left/top edge (0) to the right/bottom edge (1).
        keypoints[:, :2] = keypoints[:, :2] * (width, height) - 0.5
        return keypoints, world

    def reset(self) -> None:
        """Forget the tracked region: the next frame runs MediaPipe's person detector again."""
        with _native_stderr_filtered():
            self._pose.reset()
            self._wait_until_ready()
        self._landmarks_seen = False

    def _wait_until_ready(self) -> None:
        """Process a blank image: MediaPipe loads its models (and logs about it) in the background until then."""
        self._pose.process(np.zeros((64, 64, 3), dtype=np.uint8))

    def close(self) -> None:
        self._pose.close()


class _NativeStderrFilter:
    """Sends file descriptor 2 to a temporary file while any thread is inside a filtered block, then writes what
    came, less MediaPipe's benign lines, to stderr as it was. File descriptor 2 is one per process, so the graphs
    of all threads share one filter: the first thread in redirects it, the last one out restores it."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._inside = 0
        self._saved_fd = -1
        self._log: BinaryIO | None = None

    @contextlib.contextmanager
    def __call__(self) -> Iterator[None]:
        with self._lock:
            if self._inside == 0:
                sys.stderr.flush()
                if self._log is None:
                    self._log = tempfile.TemporaryFile()
                self._saved_fd = os.dup(2)
                os.dup2(self._log.fileno(), 2)
            self._inside += 1
        try:
            yield
        finally:
            with self._lock:
                self._inside -= 1
                if self._inside == 0:
                    self._restore()

    def _restore(self) -> None:
        assert self._log is not None
        os.dup2(self._saved_fd, 2)
        os.close(self._saved_fd)
        self._log.seek(0)
        text = self._log.read().decode(errors="replace")
        self._log.seek(0)
        self._log.truncate()
        # Pieces end at "\n" or "\r", so a progress bar's "\r" updates caught in between come back as they were.
        kept = "".join(piece for piece in text.splitlines(keepends=True)
                       if not any(benign in piece for benign in _BENIGN_NATIVE_LOG_LINES))
        if kept:
            sys.stderr.write(kept)
            sys.stderr.flush()


_native_stderr_filtered = _NativeStderrFilter()


def _check_person_box(path: object, person_box: Sequence[float], image_size: tuple[int, int]) -> Box:
    box = tuple(float(v) for v in person_box)
    if len(box) != 4 or not np.all(np.isfinite(box)) or box[0] >= box[2] or box[1] >= box[3]:
        raise InputError(f"{path}: person_box must be (x0, y0, x1, y1) pixels with x0 < x1 and y0 < y1, got {box}.")
    width, height = image_size
    if box[2] <= 0 or box[3] <= 0 or box[0] >= width or box[1] >= height:
        raise InputError(f"{path}: person_box {box} lies outside the {width}x{height} frame.")
    return box


class PersonFollower:
    """Follows one person through frames given one at a time: the per-frame core of detect_video, also
    driven directly by live capture.

    image_size: (width, height) of the frames; fps: their rate (how far the person may move between sightings);
    person_box, max_width: as in detect_video.
    """

    def __init__(self, image_size: tuple[int, int], fps: float, *, person_box: Box | None = None,
                 max_width: int | None = None) -> None:
        self.image_size, self.fps, self.max_width = image_size, fps, max_width
        self.start_box = person_box
        if person_box is None:
            self.start_region = (0, 0, image_size[0], image_size[1])
        else:
            side = max(person_box[2] - person_box[0], person_box[3] - person_box[1])
            self.start_region = grow_box(person_box, SEARCH_MARGIN * side, image_size)
        self.last: Sighting | None = None
        self.seconds = 0.0
        self._model = _PoseModel()

    def detect(self, index: int, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
        """Keypoints (33, 3) px + visibility, world landmarks (33, 3) m, and why the frame is not the followed
        person ("" when it is; zeros are returned then)."""
        started = time.perf_counter()
        region = self.start_region if self.last is None else search_region(self.last, index, self.fps,
                                                                           self.image_size)
        found = self._model.detect(frame, region, self.max_width)
        if found is None:
            reason = "no person"
        else:
            sighting = Sighting.from_landmarks(index, found[0][:, :2])
            reason = _rejection(self.last, sighting, self.start_box, self.fps)
            if reason:
                self._model.reset()  # MediaPipe would keep following whomever it found
            else:
                self.last = sighting
        self.seconds += time.perf_counter() - started
        if found is None or reason:
            return np.zeros((NUM_LANDMARKS, 3)), np.zeros((NUM_LANDMARKS, 3)), reason
        return found[0], found[1], ""

    def close(self) -> None:
        self._model.close()


def detect_video(
    path: str | os.PathLike,
    *,
    person_box: Sequence[float] | None = None,
    max_width: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    graphs: int | None = 1,
) -> Observations:
    """MediaPipe Pose landmarks of one person followed through the video at `path`.

    person_box: (x0, y0, x1, y1) native pixels around the person to follow, in the first frames where they
        appear; default: the person MediaPipe finds first on the whole frame.
    max_width: frames wider than this are scaled down to it before detection; default None, the native
        resolution: MediaPipe's cost hardly depends on the frame size (it runs fixed-size networks on its own
        crops), and downscaling loses accuracy on people who fill little of the frame.
        Coordinates are always returned in native pixels.
    progress: called as progress(frames_done, frames_announced) as frames are done.
    graphs: MediaPipe graphs detecting parts of a long video at once: 1 (the default: one follower, as every
        caller had before), 2, or None to choose (two_graphs.graphs_to_run: 2 where this process has two cores of
        its own); the capture's detect stage passes the detect.graphs setting, None by default.
    Frames stream through (decoded a few ahead in a thread, detected, dropped); the video's constant-rate,
    upright frames are those of io.video (variable frame rates resampled, with a warning; rotation applied).
    Returns Observations with T = frames decoded (pixel coordinates: integers at pixel centres, as in OpenCV);
    frames without the followed person are invalid and all zero; seconds_per_frame: the detector's seconds per
    frame (with two graphs, the wall seconds of both at once per frame, what the stage costs a user).
    Raises InputError for an unreadable video or when no frame shows a person.
    """
    from .two_graphs import detect_in_two_parts, two_part_plan

    reader = iter_frames(path, prefetch=PREFETCH_FRAMES)
    info = reader.info
    image_size = (info.width, info.height)
    start_box = None if person_box is None else _check_person_box(path, person_box, image_size)
    if info.variable_rate:
        logger.warning("%s: variable frame rate: resampled to a constant %.3f fps (%d of %d frames shown more than "
                       "once, %d dropped).", path, info.fps, info.repeated_frames, info.source_frames,
                       info.dropped_frames)
    plan = two_part_plan(info, graphs)
    follower = PersonFollower(image_size, info.fps, person_box=start_box, max_width=max_width)
    frames = iter(reader)
    try:
        if plan is None:
            detections = Detections(0)

            def report(index: int) -> None:
                if progress is not None:
                    progress(index + 1, max(info.frame_count, index + 1))
            detections.detect(follower, frames, report)
            seconds = follower.seconds
        else:
            detections, seconds = detect_in_two_parts(path, plan, follower, frames, start_box, max_width, progress)
    finally:
        frames.close()  # stops the decoding thread where detection stopped early
        follower.close()
    return _observations(path, info, detections, start_box, seconds)


def _observations(path: str | os.PathLike, info, detections: Detections, start_box, seconds: float) -> Observations:
    """The detections of the video at `path` (its io.video info) as Observations, `seconds` of detection in all;
    InputError where no frame shows the person (inside start_box if given), a warning where decoding stopped
    before the frames the file announces."""
    keypoints, world, invalid_reason, repeated = detections.arrays()
    if not (invalid_reason == "").any():
        where = "" if start_box is None else f" inside person_box {start_box}"
        raise InputError(f"{path}: no person was found{where} in any frame.")
    if detections.end < info.frame_count:
        logger.warning(
            "%s: decoding stopped after %d of the %d frames the file announces (truncated file?); "
            "detection covers the frames that decoded.",
            path, detections.end, info.frame_count,
        )
    return Observations(keypoints_2d=keypoints, landmarks_3d=world, fps=info.fps,
                        image_size=(info.width, info.height), valid=invalid_reason == "",
                        invalid_reason=invalid_reason, repeated=repeated, source=str(path),
                        seconds_per_frame=seconds / max(detections.end, 1))


class Detections:
    """One follower's detections of consecutive frames from frame `first` on: keypoints and world landmarks
    (float32, as the observations file stores them), why each frame is invalid ("" where it is valid), and whether
    a valid frame repeats the last new picture of the person (repeats.picture_unchanged)."""

    def __init__(self, first: int) -> None:
        self.first = first
        self.keypoints, self.world = _FrameArrays(), _FrameArrays()
        self.reasons: list[str] = []
        self.repeated: list[bool] = []
        self._repeats: RepeatMarker | None = None  # made with the first frame's follower

    @property
    def end(self) -> int:
        """The frame after the last one held."""
        return self.first + len(self.reasons)

    def detect(self, follower: PersonFollower, frames: Iterator[tuple[int, np.ndarray]],
               on_frame: Callable[[int], None], stop_before: int | None = None,
               stop: threading.Event | None = None) -> None:
        """Detect the frames `frames` yields, from this object's end on, up to the one before `stop_before` (None:
        all), or until `stop` is set. The frame at `stop_before` stays in `frames` for a later call."""
        if stop_before is not None and self.end >= stop_before:
            return
        for index, frame in frames:
            kp, wl, reason = follower.detect(index, frame)
            if self._repeats is None:
                self._repeats = RepeatMarker(follower.image_size)
            repeated = self._repeats.repeated(frame, kp, reason)
            del frame
            self.keypoints.append(kp)
            self.world.append(wl)
            self.reasons.append(reason)
            self.repeated.append(repeated)
            on_frame(index)
            if (stop_before is not None and index + 1 >= stop_before) or (stop is not None and stop.is_set()):
                return

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Keypoints (T, 33, 3), world landmarks (T, 33, 3), float32, the invalid reasons (T,) as objects, and the
        repeated pictures (T,) bool."""
        return (self.keypoints.array(), self.world.array(), np.array(self.reasons, dtype=object),
                np.array(self.repeated, dtype=bool))

    def spliced(self, later: Detections, junction: int) -> Detections:
        """This object's frames before `junction`, then `later`'s from `junction` on."""
        whole = Detections(self.first)
        for source, frames in ((self, range(self.first, junction)), (later, range(junction, later.end))):
            keypoints, world = source.keypoints.block, source.world.block
            for frame in frames:
                whole.keypoints.append(keypoints[frame - source.first])
                whole.world.append(world[frame - source.first])
                whole.reasons.append(source.reasons[frame - source.first])
                whole.repeated.append(source.repeated[frame - source.first])
        return whole


class _FrameArrays:
    """Per-frame (33, 3) arrays gathered into one growing float32 block (doubling when full): as compact as the
    observations cache file, which stores float32, so fresh and cached detections hold the same numbers."""

    def __init__(self) -> None:
        self._block = np.zeros((256, NUM_LANDMARKS, 3), dtype=np.float32)
        self._count = 0

    def append(self, values: np.ndarray) -> None:
        if self._count == len(self._block):
            self._block = np.concatenate([self._block, np.zeros_like(self._block)])
        self._block[self._count] = values
        self._count += 1

    @property
    def block(self) -> np.ndarray:
        """(frames, 33, 3) float32, a view."""
        return self._block[: self._count]

    def array(self) -> np.ndarray:
        """(frames, 33, 3) float32."""
        return self.block.copy()


def _rejection(last: Sighting | None, sighting: Sighting, start_box: Box | None, fps: float) -> str:
    """Why `sighting` is not the followed person ("" if it is), given the `last` accepted sighting."""
    if last is not None:
        return "track jump" if is_track_jump(last, sighting, fps) else ""
    x, y = sighting.centre
    if start_box is not None and not (start_box[0] <= x <= start_box[2] and start_box[1] <= y <= start_box[3]):
        return "outside person box"
    return ""
