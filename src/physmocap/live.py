"""Live capture: the detector and the causal fit run concurrently, one frame at a time.

A reader thread decodes frames and runs the detector; the calling thread fits each detection as it arrives
(OnlineFitter), so on two cores the throughput is set by the slower of the two, not their sum.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .config import Settings
from .contacts.features import CAUSAL_WINDOW
from .contacts.footlock import lock_feet
from .contacts.baselines import CAUSAL_SIZE_WINDOW, velocity_2d
from .contacts.predict import load_weights, network_probabilities
from .dynamics.stage import PhysicsMotion, PhysicsStream, onto_refined_floor
from .errors import InputError
from .kinematics.online import OnlineFitter
from .kinematics.stage import KinematicMotion, reprojection_errors
from .landmarks import NUM_LANDMARKS
from .motion import Observations
from .stages import stored_precision

_END = object()


@dataclass
class LiveReport:
    """What a live run did. Latency runs from a frame being decoded to its final pose being ready (after
    physics when it runs); the first `warmup_frames` wait for the calibration and are reported apart."""

    observations: Observations
    motion: KinematicMotion
    contacts: np.ndarray  # (T, 4) causal network flags
    stationary: np.ndarray  # (T,)
    physics: PhysicsMotion | None
    wall_seconds: float
    frames_per_second: float
    latency_median_ms: float
    latency_p95_ms: float
    warmup_frames: int
    detect_ms_per_frame: float
    fit_ms_per_frame: float
    contacts_physics_ms_per_frame: float


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
                   on_pose: Callable[[int, np.ndarray, dict], None] | None = None) -> LiveReport:
    """Capture from a camera index or video file frame by frame: detection, causal fit, causal contacts and,
    with settings.physics.method == "physcap", the physics tracker.

    realtime: feed a video file at its own frame rate, as a camera would (frames the pipeline cannot keep up
        with queue up and show as latency); otherwise as fast as the detector goes.
    on_pose: called with (frame index, final qpos, details) as soon as each pose is ready; details holds the
        frame's contacts (4,), stationary flag and, with physics, grf (4, 3) and residual (6,).
    """
    frames, fps, image_size, close = _open_source(source)
    reader = _DetectionThread(frames, fps, image_size, close, settings, realtime, max_frames)
    fitter = OnlineFitter(settings, fps, image_size)
    after = _AfterFit(settings, fps)
    keypoints: list[np.ndarray] = []
    world: list[np.ndarray] = []
    reasons: list[str] = []
    fit_seconds = 0.0
    started = time.perf_counter()
    reader.start()

    def deliver(results):
        for index, q in results:
            final, details = after.push(index, q, fitter.body, keypoints, reasons)
            after.latency[index] = time.perf_counter() - reader.decoded_at[index]
            if on_pose:
                on_pose(index, final, details)

    for _, kp, wl, reason in reader.detections():
        kp, wl = stored_precision(kp), stored_precision(wl)  # as the observations file keeps them (stages.as_stored)
        keypoints.append(kp)
        world.append(wl)
        reasons.append(reason)
        t0 = time.perf_counter()
        results = fitter.push(kp, wl, reason == "")
        fit_seconds += time.perf_counter() - t0
        deliver(results)
    t0 = time.perf_counter()
    results = fitter.finish()
    fit_seconds += time.perf_counter() - t0
    deliver(results)
    wall = time.perf_counter() - started
    reader.join()
    if fitter.body is None:
        raise InputError(f"{source}: no person was found in any frame.")
    T = len(reasons)
    obs = _observations(keypoints, world, reasons, fps, image_size, str(source), reader.seconds / max(T, 1))
    q = np.stack([after.qpos[i] for i in range(T)])
    motion = KinematicMotion(fitter.body, fitter.calibration, fitter.camera, fitter.floor, q,
                             reprojection_errors(fitter.body, fitter.camera, q, obs), obs.valid.copy(), fit_seconds,
                             True)
    physics = after.physics_motion(T)
    if physics is not None:  # both on the floor the physics refined, which becomes z = 0
        motion, physics = onto_refined_floor(motion, physics)
    warmup = min(T, int(np.argmax(np.cumsum(obs.valid) >= fitter.warmup)) + 1) if obs.valid.any() else T
    steady = np.array([after.latency[i] for i in range(warmup, T)]) * 1000
    contacts, stationary = after.contact_flags(T)
    median, p95 = (float(np.median(steady)), float(np.percentile(steady, 95))) if len(steady) else (np.nan, np.nan)
    return LiveReport(obs, motion, contacts, stationary, physics, wall, T / wall, median, p95, warmup,
                      reader.seconds / max(T, 1) * 1000, fit_seconds / max(T, 1) * 1000,
                      after.seconds / max(T, 1) * 1000)


def _observations(keypoints: list[np.ndarray], world: list[np.ndarray], reasons: list[str], fps: float,
                  image_size: tuple[int, int], source: str, seconds_per_frame: float) -> Observations:
    """The frames' detections gathered into Observations ("" reasons mark valid frames)."""
    why = np.array(reasons, dtype=object)
    empty = np.zeros((0, NUM_LANDMARKS, 3))
    return Observations(np.stack(keypoints) if keypoints else empty, np.stack(world) if world else empty, fps,
                        image_size, valid=why == "", invalid_reason=why, source=source,
                        seconds_per_frame=seconds_per_frame)


class _DetectionThread(threading.Thread):
    """Decodes frames and runs the detector on them, handing (index, keypoints, landmarks, invalid reason) to
    the fitting thread through a short queue; an exception in it is raised again by `join`."""

    def __init__(self, frames, fps: float, image_size: tuple[int, int], close: Callable[[], None],
                 settings: Settings, realtime: bool, max_frames: int | None):
        super().__init__(name="physmocap-detect", daemon=True)
        self.frames, self.fps, self.image_size, self.close = frames, fps, image_size, close
        self.settings, self.realtime, self.max_frames = settings, realtime, max_frames
        self.queue: queue.Queue = queue.Queue(maxsize=8)
        self.decoded_at: dict[int, float] = {}  # perf_counter when each frame was decoded
        self.seconds = 0.0  # spent detecting
        self.failure: BaseException | None = None

    def run(self) -> None:
        from .detect.mediapipe_pose import PersonFollower

        follower = PersonFollower(self.image_size, self.fps, person_box=self.settings.detect.person_box,
                                  max_width=self.settings.detect.max_width)
        start = time.perf_counter()
        try:
            for index, frame in self.frames:
                if self.max_frames is not None and index >= self.max_frames:
                    break
                if self.realtime:
                    time.sleep(max(0.0, start + index / self.fps - time.perf_counter()))
                self.decoded_at[index] = time.perf_counter()
                self.queue.put((index, *follower.detect(index, frame)))
        except BaseException as exc:  # handed to the fitting thread, which raises it
            self.failure = exc
        finally:
            follower.close()
            self.close()
            self.seconds = follower.seconds
            self.queue.put(_END)

    def detections(self) -> Iterator[tuple[int, np.ndarray, np.ndarray, str]]:
        while (item := self.queue.get()) is not _END:
            yield item

    def join(self, timeout: float | None = None) -> None:
        super().join(timeout)
        if self.failure is not None:
            raise self.failure


class _AfterFit:
    """What follows the fit, one frame at a time: the causal contact network, foot-lock (contacts.footlock, as
    the offline pipeline) and, with physcap, the physics tracker; it keeps every frame's output for the report."""

    def __init__(self, settings: Settings, fps: float):
        self.settings, self.fps = settings, fps
        self.weights = load_weights("causal")
        self.physics_on = settings.physics.method == "physcap"
        self.stream: PhysicsStream | None = None
        self.qpos: dict[int, np.ndarray] = {}
        self.latency: dict[int, float] = {}  # seconds from decoding to the final pose
        self.contacts: dict[int, np.ndarray] = {}  # (4,) bool after foot-lock
        self.stationary: dict[int, bool] = {}
        self.physics_frames: dict[int, tuple] = {}
        self.seconds = 0.0

    def push(self, index: int, q: np.ndarray, body, keypoints: list, reasons: list) -> tuple[np.ndarray, dict]:
        """Frame `index`'s fitted pose q (nq,) -> its final pose and the details `on_pose` receives."""
        started = time.perf_counter()
        self.qpos[index] = q
        first = max(0, index - CAUSAL_WINDOW.length + 1)
        window = np.array(keypoints[first:index + 1])
        valid = np.array([r == "" for r in reasons[first:index + 1]])
        _, flags = network_probabilities(window, valid, self.fps, self.weights, "causal")
        # the stationary flag of the causal 2D root-speed heuristic, over the frames it reads (clamped at 0, as the
        # whole-clip computation of pipeline.contacts_stage is)
        past = np.clip(np.arange(index - CAUSAL_SIZE_WINDOW.length + 1, index + 1), 0, None)
        stationary = bool(velocity_2d(np.array([keypoints[i] for i in past]),
                                      np.array([reasons[i] == "" for i in past]), self.fps, causal=True)[1][-1])
        contacts = lock_feet(flags[-1:, :4], body, q[None], self.settings.physics)[0]
        self.contacts[index], self.stationary[index] = contacts, stationary
        details: dict[str, Any] = dict(contacts=contacts, stationary=stationary)
        final = q
        if self.physics_on:
            if self.stream is None:
                self.stream = PhysicsStream(body, self.settings.physics, self.fps, self.settings.camera.floor is None)
            final, frame, corrected = self.stream.push(q, contacts, stationary)
            self.physics_frames[index] = (final, frame, corrected)
            details.update(grf=frame.contact_forces, residual=frame.residual)
        self.seconds += time.perf_counter() - started
        return final, details

    def contact_flags(self, T: int) -> tuple[np.ndarray, np.ndarray]:
        """(T, 4) contacts after foot-lock and (T,) stationary flags of frames 0 .. T-1."""
        return (np.array([self.contacts[i] for i in range(T)], bool).reshape(T, 4),
                np.array([self.stationary[i] for i in range(T)], bool))

    def physics_motion(self, T: int) -> PhysicsMotion | None:
        """The tracked motion of frames 0 .. T-1 (in the kinematic world), None without physics."""
        if not self.physics_on:
            return None
        frames = [self.physics_frames[i] for i in range(T)]
        return PhysicsMotion(
            qpos=np.stack([f[0] for f in frames]), grf=np.stack([f[1].contact_forces for f in frames]),
            residual=np.stack([f[1].residual for f in frames]), contacts=np.stack([f[1].active for f in frames]),
            corrected=np.array([f[2] for f in frames]), qp_failures=np.array([f[1].qp_failures for f in frames]),
            seconds=self.seconds, floor_plane=None if self.stream is None else self.stream.floor_plane,
            unexplained=np.array([f[1].unexplained_flag for f in frames], bool))
