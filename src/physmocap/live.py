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
from .contacts.features import CAUSAL_WINDOW
from .contacts.footlock import lock_feet
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
    contact_weights = load_weights("causal")
    keypoints, world, reasons, latency = [], [], [], {}
    qpos: dict[int, np.ndarray] = {}
    fit_seconds = after_fit_seconds = 0.0  # the kinematic fit; contacts and physics after it
    started = time.perf_counter()
    reader = threading.Thread(target=detect_all, name="physmocap-detect", daemon=True)
    reader.start()

    physics_on = settings.physics.method == "physcap"
    contacts_by_frame: dict[int, tuple[np.ndarray, bool]] = {}
    physics_frames: dict[int, tuple] = {}
    physics: PhysicsStream | None = None

    def deliver(results):
        nonlocal physics, after_fit_seconds
        for index, q in results:
            qpos[index] = q
            t0 = time.perf_counter()
            start = max(0, index - CAUSAL_WINDOW.length + 1)
            window = np.array(keypoints[start:index + 1])
            valid = np.array([r == "" for r in reasons[start:index + 1]])
            _, flags = network_probabilities(window, valid, fps, contact_weights, "causal")
            stationary = bool(flags[-1, 4])
            contacts = lock_feet(flags[-1:, :4], fitter.body, q[None], settings.physics)[0]
            contacts_by_frame[index] = (contacts, stationary)
            details = dict(contacts=contacts, stationary=stationary)
            final = q
            if physics_on:
                if physics is None:
                    physics = PhysicsStream(fitter.body, settings.physics, fps, settings.camera.floor is None)
                final, frame, corrected = physics.push(q, contacts, stationary)
                physics_frames[index] = (final, frame, corrected)
                details.update(grf=frame.contact_forces, residual=frame.residual)
            after_fit_seconds += time.perf_counter() - t0
            latency[index] = time.perf_counter() - decoded_at[index]
            if on_pose:
                on_pose(index, final, details)

    while True:
        item = detections.get()
        if item[0] is _END:
            detect_seconds = item[1]
            break
        index, kp, wl, reason = item
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
    contacts = np.array([contacts_by_frame[i][0] for i in range(T)])
    stationary = np.array([contacts_by_frame[i][1] for i in range(T)])
    physics_motion = None
    if physics_on:
        frames = [physics_frames[i] for i in range(T)]
        physics_motion = PhysicsMotion(np.stack([f[0] for f in frames]),
                                       np.stack([f[1].contact_forces for f in frames]),
                                       np.stack([f[1].residual for f in frames]), np.stack([f[1].active for f in frames]),
                                       np.array([f[2] for f in frames]), np.array([f[1].qp_failures for f in frames]),
                                       after_fit_seconds, physics.floor_plane if physics is not None else None)
    motion = KinematicMotion(fitter.body, fitter.calibration, fitter.camera, fitter.floor, q,
                             reprojection_errors(fitter.body, fitter.camera, q, obs), obs.valid.copy(), fit_seconds,
                             True)
    if physics_motion is not None:  # both on the floor the physics refined, which becomes z = 0
        motion, physics_motion = onto_refined_floor(motion, physics_motion)
    warmup = min(T, int(np.argmax(np.cumsum(obs.valid) >= fitter.warmup)) + 1) if obs.valid.any() else T
    steady = np.array([latency[i] for i in range(warmup, T)]) * 1000
    return LiveReport(obs, motion, contacts, stationary, physics_motion, wall, T / wall, float(np.median(steady)) if len(steady) else float("nan"),
                      float(np.percentile(steady, 95)) if len(steady) else float("nan"), warmup,
                      detect_seconds / max(T, 1) * 1000, fit_seconds / max(T, 1) * 1000,
                      after_fit_seconds / max(T, 1) * 1000)
