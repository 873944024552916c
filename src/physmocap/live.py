"""Live capture: the detector and the causal fit run concurrently, one frame at a time.

A reader thread decodes frames and runs the detector; the calling thread fits each detection as it arrives
(OnlineFitter), so on two cores the throughput is set by the slower of the two, not their sum.
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterator

import cv2
import numpy as np

from .config import Settings
from .errors import InputError
from .kinematics.online import OnlineFitter
from .kinematics.stage import KinematicMotion, reprojection_errors
from .landmarks import NUM_LANDMARKS
from .motion import Observations

_END = object()


@dataclass
class LiveReport:
    """What a live run did. Latency runs from a frame being decoded to its pose being ready; the first
    `warmup_frames` wait for the calibration and are reported apart."""

    observations: Observations
    motion: KinematicMotion
    wall_seconds: float
    frames_per_second: float
    latency_median_ms: float
    latency_p95_ms: float
    warmup_frames: int
    detect_ms_per_frame: float
    fit_ms_per_frame: float


def _open_source(source) -> tuple[Iterator[tuple[int, np.ndarray]], float, tuple[int, int], Callable[[], None]]:
    """A camera index or a video path -> (frames, fps, (width, height), close)."""
    if isinstance(source, int) or (isinstance(source, str) and source.isdigit()):
        capture = cv2.VideoCapture(int(source))
        if not capture.isOpened():
            raise InputError(f"camera {source}: cannot be opened.")
        fps = capture.get(cv2.CAP_PROP_FPS) or 30.0
        ok, first = capture.read()
        if not ok:
            raise InputError(f"camera {source}: delivers no frames.")

        def camera_frames():
            index, frame = 0, first
            while frame is not None:
                yield index, frame
                ok, frame = capture.read()
                frame = frame if ok else None
                index += 1
        return camera_frames(), fps, (first.shape[1], first.shape[0]), capture.release
    from .io.video import iter_frames

    reader = iter_frames(source)
    return iter(reader), reader.info.fps, (reader.info.width, reader.info.height), lambda: None


def stream_capture(source, settings: Settings, *, realtime: bool = False, max_frames: int | None = None,
                   on_pose: Callable[[int, np.ndarray], None] | None = None) -> LiveReport:
    """Capture from a camera index or video file frame by frame.

    realtime: feed a video file at its own frame rate, as a camera would (frames the fit cannot keep up with
        queue up and show as latency); otherwise as fast as the detector goes.
    on_pose: called with (frame index, qpos) as soon as each pose is ready.
    """
    from .detect.mediapipe_pose import PersonFollower

    frames, fps, image_size, close = _open_source(source)
    detections: queue.Queue = queue.Queue(maxsize=8)
    decoded_at: dict[int, float] = {}
    failure: list[BaseException] = []

    def detect_all():
        follower = PersonFollower(image_size, fps, person_box=settings.detect.person_box,
                                  max_width=settings.detect.max_width)
        start = time.perf_counter()
        try:
            for index, frame in frames:
                if max_frames is not None and index >= max_frames:
                    break
                if realtime:
                    time.sleep(max(0.0, start + index / fps - time.perf_counter()))
                decoded_at[index] = time.perf_counter()
                detections.put((index, *follower.detect(index, frame)))
        except BaseException as exc:  # handed to the fitting thread, which raises it
            failure.append(exc)
        finally:
            follower.close()
            close()
            detections.put((_END, follower.seconds))

    fitter = OnlineFitter(settings, fps, image_size)
    keypoints, world, reasons, latency = [], [], [], {}
    qpos: dict[int, np.ndarray] = {}
    fit_seconds = 0.0
    started = time.perf_counter()
    reader = threading.Thread(target=detect_all, name="physmocap-detect", daemon=True)
    reader.start()

    def deliver(results):
        now = time.perf_counter()
        for index, q in results:
            qpos[index] = q
            latency[index] = now - decoded_at[index]
            if on_pose:
                on_pose(index, q)

    while True:
        item = detections.get()
        if item[0] is _END:
            detect_seconds = item[1]
            break
        index, kp, wl, reason = item
        keypoints.append(kp)
        world.append(wl)
        reasons.append(reason)
        t0 = time.perf_counter()
        results = fitter.push(kp, wl, reason == "")
        fit_seconds += time.perf_counter() - t0
        deliver(results)
    t0 = time.perf_counter()
    deliver(fitter.finish())
    fit_seconds += time.perf_counter() - t0
    wall = time.perf_counter() - started
    reader.join()
    if failure:
        raise failure[0]
    if fitter.body is None:
        raise InputError(f"{source}: no person was found in any frame.")
    T = len(reasons)
    reason_array = np.array(reasons, dtype=object)
    obs = Observations(np.stack(keypoints) if T else np.zeros((0, NUM_LANDMARKS, 3)), np.stack(world), fps,
                       image_size, valid=reason_array == "", invalid_reason=reason_array, source=str(source),
                       seconds_per_frame=detect_seconds / max(T, 1))
    q = np.stack([qpos[i] for i in range(T)])
    motion = KinematicMotion(fitter.body, fitter.calibration, fitter.camera, fitter.floor, q,
                             reprojection_errors(fitter.body, fitter.camera, q, obs), obs.valid.copy(), fit_seconds,
                             True)
    warmup = min(T, int(np.argmax(np.cumsum(obs.valid) >= fitter.warmup)) + 1) if obs.valid.any() else T
    steady = np.array([latency[i] for i in range(warmup, T)]) * 1000
    return LiveReport(obs, motion, wall, T / wall, float(np.median(steady)) if len(steady) else float("nan"),
                      float(np.percentile(steady, 95)) if len(steady) else float("nan"), warmup,
                      detect_seconds / max(T, 1) * 1000, fit_seconds / max(T, 1) * 1000)
