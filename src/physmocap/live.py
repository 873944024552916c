"""Live capture: frames arrive, a detector thread and the calling thread's causal fit work on them concurrently.

Three stages, each in its own thread: the source (a camera read as fast as it delivers, or a video file played at
its own frame rate, as a camera would), the detector, and the fit with contacts and physics (the caller's thread).
On two cores the throughput is set by the slowest stage, not their sum.

The drop policy (`drop_stale_frames`, on for `physmocap live`): from the end of the calibration warm-up on, a stage
that falls behind skips to the newest frame that has reached it, so that the latency from a frame's arrival to its
pose stays bounded. The detector takes the newest arrived frame (older ones were read and are discarded); the fit
takes the newest detection (older ones are discarded). A skipped frame stays in the result on the frame grid,
invalid with reason DROPPED_REASON: its pose is the causal fit's constant-velocity prediction (OnlineFitter.skip),
its contacts are the network's for an unseen frame (none) and the physics steps through it, so every stage keeps
its time step of 1 / fps, and a dropped frame costs the fit thread a few milliseconds, a fraction of a fitted one.
Without the policy every frame is processed and the lag grows for as long as the pipeline is slower than the
source. A file fed as fast as possible (realtime=False) is never dropped: its
reader waits for the pipeline.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .config import Settings
from .contacts.baselines import CAUSAL_SIZE_WINDOW, velocity_2d
from .contacts.footlock import lock_feet
from .contacts.networks import NUM_OUTPUTS
from .contacts.predict import causal_window_start, load_weights, network_probabilities
from .dynamics.stage import PhysicsMotion, PhysicsStream, onto_refined_floor, written_forces
from .errors import InputError
from .kinematics.online import OnlineFitter
from .kinematics.stage import KinematicMotion, reprojection_errors
from .landmarks import NUM_LANDMARKS
from .motion import Observations
from .stages import stored_precision

log = logging.getLogger("physmocap")

DROPPED_REASON = "dropped: the pipeline fell behind"
LAG_WARNING_SECONDS = 0.5  # latency (s, > 0) from arrival to pose above which the pipeline is said to fall behind
WARNING_INTERVAL_SECONDS = 5.0  # the falling-behind warning is repeated at most once per this many seconds
FILE_READ_AHEAD = 4  # frames decoded ahead of the detector for a file fed as fast as possible (memory bound)


@dataclass
class LiveReport:
    """What a live run did. Latency is true latency: from a frame's arrival (read from the camera; for a file
    played at its frame rate its scheduled time, start + index / fps) to its final pose being ready (after physics
    when it runs), over the processed frames after the calibration warm-up (the first `warmup_frames`, which wait
    for it; a stream that ends within it has no latency to report: NaN). Dropped frames (drop policy) are in the
    result as invalid frames with reason DROPPED_REASON."""

    observations: Observations
    motion: KinematicMotion
    contacts: np.ndarray  # (T, 4) causal network flags
    stationary: np.ndarray  # (T,)
    physics: PhysicsMotion | None
    wall_seconds: float
    frames_per_second: float  # processed (not dropped) frames per second of wall time
    latency_median_ms: float
    latency_p95_ms: float
    warmup_frames: int
    detect_ms_per_frame: float  # per detected frame
    fit_ms_per_frame: float  # per frame of the grid, dropped ones included
    contacts_physics_ms_per_frame: float  # per frame of the grid
    drop_stale_frames: bool
    frames_arrived: int
    frames_dropped_before_detection: int
    frames_dropped_before_fit: int  # detected, but a newer detection was waiting when the fit got to it

    @property
    def frames_dropped(self) -> int:
        return self.frames_dropped_before_detection + self.frames_dropped_before_fit

    @property
    def frames_processed(self) -> int:
        return self.frames_arrived - self.frames_dropped


def _open_source(source) -> tuple[Iterator[tuple[int, np.ndarray]], float, tuple[int, int], Callable[[], None], bool]:
    """A camera index or a video path -> (frames, fps, (width, height), close, whether it is a camera)."""
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
            while True:
                yield index, frame
                ok, frame = capture.read()
                if not ok:
                    return
                index += 1
        return camera_frames(), fps, (first.shape[1], first.shape[0]), capture.release, True
    from .io.video import iter_frames

    reader = iter_frames(source)
    return iter(reader), reader.info.fps, (reader.info.width, reader.info.height), lambda: None, False


def stream_capture(source, settings: Settings, *, realtime: bool = False, max_frames: int | None = None,
                   on_pose: Callable[[int, np.ndarray, dict], None] | None = None,
                   drop_stale_frames: bool = True) -> LiveReport:
    """Capture from a camera index or video file frame by frame: detection, causal fit, causal contacts and,
    with settings.physics.method == "physcap", the physics tracker.

    realtime: feed a video file at its own frame rate, as a camera would (a camera always is).
    drop_stale_frames: the drop policy of the module docstring; off, every frame is processed and frames the
        pipeline cannot keep up with wait, which shows as latency (a camera's wait in memory, about 1 MB a frame at
        640x480). A file fed with realtime=False is never dropped.
    on_pose: called in the calling thread with (frame index, final qpos, details) as soon as each processed
        frame's pose is ready (not for dropped frames); details holds the frame's contacts (4,), stationary flag,
        latency_s (from its arrival) and, with physics, grf (4, 3) and residual (6,). The time it takes delays the
        frames after it, as a slower fit would.
    """
    frames, fps, image_size, close, camera = _open_source(source)
    filmed = settings.camera.fps or fps  # the motion's rate; frames still arrive and are paced at the source's
    scheduled = realtime and not camera  # a file played as a camera: frames arrive at start + index / fps
    paced = realtime or camera  # frames arrive whether or not the pipeline is ready for them
    stop = threading.Event()
    # Only a camera's frames must be taken as they come (or the driver discards them); a file's wait to be decoded.
    # Frames are dropped from the end of the warm-up on: the warm-up holds every frame up to its last detected one
    # and fits them all when it ends, so frames dropped before would only make that longer.
    frame_handoff = _Handoff(keep_newest=False, capacity=None if camera else FILE_READ_AHEAD)
    detection_handoff = _Handoff(keep_newest=False)
    reader = _SourceThread(frames, fps, close, scheduled, max_frames, frame_handoff, stop)
    detector = _DetectionThread(frame_handoff, detection_handoff, fps, image_size, settings, stop)
    loop = _FitLoop(OnlineFitter(settings, filmed, image_size), _AfterFit(settings, filmed),
                    _FallingBehind(fps, paced and drop_stale_frames) if paced else None, on_pose,
                    (frame_handoff, detection_handoff), paced and drop_stale_frames)
    detector.start()
    try:
        detector.ready.wait()
        started = time.perf_counter()
        reader.start()
        item = detection_handoff.take()
        while item is not None:
            index, arrival, kp, wl, reason, repeated = item
            gap = index - len(loop.reasons)
            for skipped in range(len(loop.reasons), index):  # frames a stage skipped, kept on the grid
                loop.skip(skipped)
            # A detection that came while those were predicted is taken instead while the gaps shrink; when
            # predicting a gap takes longer than the gap lasted, the next would only grow, and this one is fitted.
            if (newer := detection_handoff.waiting_index()) is not None and newer - index < gap:
                item = detection_handoff.take_newer()
                continue
            # as the observations file keeps them (stages.as_stored)
            loop.add(index, stored_precision(kp), stored_precision(wl), reason, arrival, repeated)
            item = detection_handoff.take()
        detector.join()
        reader.join()
        loop.finish()
        wall = time.perf_counter() - started
    finally:
        stop.set()
        if reader.ident is None:  # never started, so it will not close the source
            close()
    return _live_report(str(source), loop, detector, filmed, image_size, wall, paced and drop_stale_frames,
                        frame_handoff.dropped, detection_handoff.dropped)


class _FitLoop:
    """stream_capture's calling thread: each detection (or frame a stage skipped) into the causal fit, and each
    pose that becomes ready through contacts and physics (`after`) to on_pose; the frames' inputs as they came."""

    def __init__(self, fitter: OnlineFitter, after: _AfterFit, warning: _FallingBehind | None,
                 on_pose: Callable[[int, np.ndarray, dict], None] | None, handoffs: tuple[_Handoff, _Handoff],
                 drop_stale_frames: bool):
        self.fitter, self.after, self.warning, self.on_pose = fitter, after, warning, on_pose
        self.handoffs, self.drop_stale_frames = handoffs, drop_stale_frames  # the handoffs drop from the warm-up's end
        self.keypoints: list[np.ndarray] = []
        self.world: list[np.ndarray] = []
        self.reasons: list[str] = []
        self.repeated: list[bool] = []  # frames showing the last new picture again (detect/repeats.py)
        self.arrivals: dict[int, float] = {}  # perf_counter of each processed frame's arrival
        self.fit_seconds = 0.0
        self.dropped = 0  # frames so far that a stage skipped

    def deliver(self, results: list[tuple[int, np.ndarray]], fitted_straight_away: bool) -> None:
        for index, q in results:
            final, details = self.after.push(index, q, self.fitter.body, self.fitter.floor, self.keypoints,
                                             self.reasons)
            if index in self.arrivals:
                self.after.latency[index] = details["latency_s"] = time.perf_counter() - self.arrivals[index]
                if self.warning and fitted_straight_away:
                    self.warning.check(index, details["latency_s"], len(self.reasons), self.dropped)
                if self.on_pose:
                    self.on_pose(index, final, details)

    def add(self, index: int, kp: np.ndarray, wl: np.ndarray, reason: str, arrival: float | None,
            repeated: bool = False) -> None:
        self.keypoints.append(kp)
        self.world.append(wl)
        self.reasons.append(reason)
        self.repeated.append(repeated)
        if arrival is None:
            self.dropped += 1
        else:
            self.arrivals[index] = arrival
        calibrated = self.fitter.body is not None  # else the frame may be held by the warm-up
        t0 = time.perf_counter()
        results = self.fitter.push(kp, wl, reason == "") if arrival is not None else self.fitter.skip()
        self.fit_seconds += time.perf_counter() - t0
        if not calibrated and self.fitter.body is not None:
            for handoff in self.handoffs:
                handoff.keep_newest = self.drop_stale_frames
        self.deliver(results, calibrated)

    def skip(self, index: int) -> None:
        """A frame a stage skipped, kept on the grid: unseen, its pose predicted."""
        nothing = np.zeros((NUM_LANDMARKS, 3))
        self.add(index, nothing, nothing, DROPPED_REASON, None)

    def finish(self) -> None:
        """End of stream: what the warm-up still holds fitted and delivered."""
        t0 = time.perf_counter()
        results = self.fitter.finish()
        self.fit_seconds += time.perf_counter() - t0
        self.deliver(results, False)


def _live_report(source: str, loop: _FitLoop, detector: _DetectionThread, fps: float, image_size: tuple[int, int],
                 wall: float, drop_stale_frames: bool, dropped_before_detection: int,
                 dropped_before_fit: int) -> LiveReport:
    """The motion, contacts, physics and figures of a finished stream (see LiveReport)."""
    fitter, after = loop.fitter, loop.after
    if fitter.body is None or fitter.calibration is None or fitter.floor is None:  # the warm-up never ended
        raise InputError(f"{source}: no person was found in any frame.")
    T = len(loop.reasons)
    obs = _observations(loop.keypoints, loop.world, loop.reasons, loop.repeated, fps, image_size, source,
                        detector.seconds / max(detector.detected, 1))
    q = np.stack([after.qpos[i] for i in range(T)])
    motion = KinematicMotion(fitter.body, fitter.calibration, fitter.camera, fitter.floor, q,
                             reprojection_errors(fitter.body, fitter.camera, q, obs), obs.valid.copy(),
                             loop.fit_seconds, True, fitter.foot_swaps(T))
    physics = after.physics_motion(T)
    if physics is not None:  # both on the floor the physics refined, which becomes z = 0
        motion, physics = onto_refined_floor(motion, physics)
    calibrated = np.cumsum(obs.valid) >= fitter.warmup  # else the stream ended within the warm-up: all waited
    warmup = int(np.argmax(calibrated)) + 1 if calibrated.any() else T
    steady = np.array([after.latency[i] for i in range(warmup, T) if i in after.latency]) * 1000
    contacts, stationary = after.contact_flags(T)
    median, p95 = (float(np.median(steady)), float(np.percentile(steady, 95))) if len(steady) else (np.nan, np.nan)
    return LiveReport(obs, motion, contacts, stationary, physics, wall, len(loop.arrivals) / wall, median, p95,
                      warmup, detector.seconds / max(detector.detected, 1) * 1000, loop.fit_seconds / max(T, 1) * 1000,
                      after.seconds / max(T, 1) * 1000, drop_stale_frames, T, dropped_before_detection,
                      dropped_before_fit)


def _observations(keypoints: list[np.ndarray], world: list[np.ndarray], reasons: list[str], repeated: list[bool],
                  fps: float, image_size: tuple[int, int], source: str, seconds_per_frame: float) -> Observations:
    """The frames' detections gathered into Observations ("" reasons mark valid frames)."""
    why = np.array(reasons, dtype=object)
    empty = np.zeros((0, NUM_LANDMARKS, 3))
    return Observations(np.stack(keypoints) if keypoints else empty, np.stack(world) if world else empty, fps,
                        image_size, valid=why == "", invalid_reason=why, repeated=np.array(repeated, bool),
                        source=source, seconds_per_frame=seconds_per_frame)


class _Handoff:
    """Items passed from one stage's thread to the next. keep_newest: an item put while an older one still waits
    replaces it (counted in `dropped`); otherwise every item is kept, in order, and with a capacity the putting
    stage waits while that many are waiting."""

    def __init__(self, keep_newest: bool, capacity: int | None = None):
        self.keep_newest, self.capacity = keep_newest, capacity
        self.dropped = 0
        self._items: deque = deque()
        self._ended = False
        self._changed = threading.Condition()

    def put(self, item, stop: threading.Event) -> None:
        with self._changed:
            while self.capacity is not None and len(self._items) >= self.capacity and not stop.is_set():
                self._changed.wait(0.1)
            if self.keep_newest:
                self.dropped += len(self._items)
                self._items.clear()
            self._items.append(item)
            self._changed.notify_all()

    def end(self) -> None:
        """No more items will come: `take` returns None once the waiting ones are taken."""
        with self._changed:
            self._ended = True
            self._changed.notify_all()

    def waiting_index(self) -> int | None:
        """With keep_newest, the index (first element) of the newest item waiting; else, or with none, None."""
        with self._changed:
            return self._items[-1][0] if self.keep_newest and self._items else None

    def take_newer(self):
        """The newest item waiting (keep_newest), instead of the one taken last; both that and any older waiting
        ones are counted as dropped."""
        with self._changed:
            self.dropped += len(self._items)
            item = self._items.pop()
            self._items.clear()
            return item

    def take(self):
        """The oldest waiting item (with keep_newest the newest), after waiting for one; None at the end."""
        with self._changed:
            while not self._items and not self._ended:
                self._changed.wait()
            if self.keep_newest and len(self._items) > 1:  # those waiting from before keep_newest was set
                self.dropped += len(self._items) - 1
                self._items = deque([self._items[-1]])
            item = self._items.popleft() if self._items else None
            self._changed.notify_all()
            return item


class _SourceThread(threading.Thread):
    """Reads the source's frames into a _Handoff as (index, frame, arrival time): for a file played as a camera
    (scheduled) its time start + index / fps, when the frame is due whether or not it was decoded by then; otherwise
    when it was read. An exception in it is raised again by `join`."""

    def __init__(self, frames, fps: float, close: Callable[[], None], scheduled: bool, max_frames: int | None,
                 handoff: _Handoff, stop: threading.Event):
        super().__init__(name="physmocap-source", daemon=True)
        self.frames, self.fps, self.close, self.scheduled = frames, fps, close, scheduled
        self.max_frames, self.handoff, self.stop = max_frames, handoff, stop
        self.failure: BaseException | None = None

    def run(self) -> None:
        start = time.perf_counter()
        try:
            for index, frame in self.frames:
                if self.stop.is_set() or (self.max_frames is not None and index >= self.max_frames):
                    break
                if self.scheduled:
                    arrival = start + index / self.fps
                    if self.stop.wait(max(0.0, arrival - time.perf_counter())):
                        break  # stopped while waiting for the frame's time
                else:
                    arrival = time.perf_counter()
                self.handoff.put((index, frame, arrival), self.stop)
        except BaseException as exc:  # handed to the fitting thread, which raises it
            self.failure = exc
        finally:
            self.close()
            self.handoff.end()

    def join(self, timeout: float | None = None) -> None:
        super().join(timeout)
        if self.failure is not None:
            raise self.failure


class _DetectionThread(threading.Thread):
    """Runs the detector on the frames it takes, handing (index, arrival, keypoints, landmarks, invalid reason) to
    the fitting thread; `ready` is set once the detector is loaded (the source starts then). An exception in it is
    raised again by `join`."""

    def __init__(self, frames: _Handoff, detections: _Handoff, fps: float, image_size: tuple[int, int],
                 settings: Settings, stop: threading.Event):
        super().__init__(name="physmocap-detect", daemon=True)
        self.frames, self.detections, self.fps, self.image_size = frames, detections, fps, image_size
        self.settings, self.stop = settings, stop
        self.ready = threading.Event()
        self.detected = 0
        self.seconds = 0.0  # spent detecting
        self.failure: BaseException | None = None

    def run(self) -> None:
        from .detect.mediapipe_pose import PersonFollower
        from .detect.repeats import RepeatMarker

        follower = None
        repeats = RepeatMarker(self.image_size)
        try:
            follower = PersonFollower(self.image_size, self.fps, person_box=self.settings.detect.person_box,
                                      max_width=self.settings.detect.max_width)
            self.ready.set()
            while not self.stop.is_set() and (item := self.frames.take()) is not None:
                index, frame, arrival = item
                kp, wl, reason = follower.detect(index, frame)
                repeated = repeats.repeated(frame, kp, reason)
                self.detections.put((index, arrival, kp, wl, reason, repeated), self.stop)
                self.detected += 1
        except BaseException as exc:  # handed to the fitting thread, which raises it
            self.failure = exc
        finally:
            if follower is not None:
                follower.close()
                self.seconds = follower.seconds
            self.stop.set()  # the source stops too (it has ended already unless this thread failed)
            self.ready.set()
            self.detections.end()

    def join(self, timeout: float | None = None) -> None:
        super().join(timeout)
        if self.failure is not None:
            raise self.failure


class _FallingBehind:
    """The warning that the pipeline falls behind its source: one line when frames are dropped or a pose comes
    more than LAG_WARNING_SECONDS after its frame arrived, repeated at most every WARNING_INTERVAL_SECONDS.
    Counted from the first frame fitted straight away after the calibration warm-up: the warm-up's frames all wait
    for it, and frames dropped while the pipeline catches up with it are no sign of a slow pipeline."""

    def __init__(self, fps: float, dropping: bool):
        self.fps, self.dropping = fps, dropping
        self.last_warning: float | None = None
        self.first_steady: tuple[int, int] | None = None  # (its index, frames dropped before it)

    def check(self, index: int, latency: float, arrived: int, dropped: int) -> None:
        """After frame `index`'s pose, `arrived` frames having arrived and `dropped` been dropped so far."""
        if self.first_steady is None:
            self.first_steady = index, dropped
            return
        dropped -= self.first_steady[1]
        if latency <= LAG_WARNING_SECONDS and not dropped:
            return
        now = time.perf_counter()
        if self.last_warning is not None and now - self.last_warning < WARNING_INTERVAL_SECONDS:
            return
        self.last_warning = now
        if self.dropping:
            log.warning("live: the pipeline falls behind the %.0f fps source: %d of the %d frames since the warm-up "
                        "dropped so far to keep the latency bounded (now %.0f ms)", self.fps, dropped,
                        arrived - self.first_steady[0], latency * 1000)
        else:
            log.warning("live: the pipeline falls behind the %.0f fps source: frame %d posed %.1f s after it "
                        "arrived; every frame is kept, so the lag grows while the pipeline is slower than the source",
                        self.fps, index, latency)


class _AfterFit:
    """What follows the fit, one frame at a time: the causal contact network, foot-lock (contacts.footlock, as
    the offline pipeline) and, with physcap, the physics tracker; it keeps every frame's output for the report."""

    def __init__(self, settings: Settings, fps: float):
        self.settings, self.fps = settings, fps
        self.weights = load_weights("causal")
        self.physics_on = settings.physics.method == "physcap"
        self.stream: PhysicsStream | None = None
        self.qpos: dict[int, np.ndarray] = {}
        self.latency: dict[int, float] = {}  # seconds from arrival to the final pose, processed frames only
        self.contacts: dict[int, np.ndarray] = {}  # (4,) bool after foot-lock
        self.stationary: dict[int, bool] = {}
        self.physics_frames: dict[int, tuple] = {}
        self.seen: dict[int, bool] = {}  # whether each frame showed the person
        self.seconds = 0.0

    def push(self, index: int, q: np.ndarray, body, floor, keypoints: list, reasons: list) -> tuple[np.ndarray, dict]:
        """Frame `index`'s fitted pose q (nq,) on the warm-up's floor -> its final pose and the details `on_pose`
        receives."""
        started = time.perf_counter()
        self.qpos[index] = q
        first = causal_window_start(index)
        valid = np.array([r == "" for r in reasons[first:index + 1]])
        if valid[-1]:
            window = np.array(keypoints[first:index + 1])
            _, flags = network_probabilities(window, valid, self.fps, self.weights, "causal")
        else:  # what the network gives an unseen frame, without running it (a dropped frame must cost little)
            flags = np.zeros((1, NUM_OUTPUTS), bool)
        # the stationary flag of the causal 2D root-speed heuristic, over the frames it reads (clamped at 0, as the
        # whole-clip computation of pipeline.contacts_stage is)
        past = np.clip(np.arange(index - CAUSAL_SIZE_WINDOW.length + 1, index + 1), 0, None)
        stationary = bool(velocity_2d(np.array([keypoints[i] for i in past]),
                                      np.array([reasons[i] == "" for i in past]), self.fps, causal=True)[1][-1])
        contacts = lock_feet(flags[-1:, :4], body, q[None], self.settings.physics)[0]
        self.contacts[index], self.stationary[index], self.seen[index] = contacts, stationary, bool(valid[-1])
        details: dict[str, Any] = dict(contacts=contacts, stationary=stationary)
        final = q
        if self.physics_on:
            if self.stream is None:
                self.stream = PhysicsStream(body, self.settings.physics, self.fps, self.settings.camera.floor is None,
                                            floor_trusted=floor.trusted)
            elif valid[-1] and len(valid) > 1 and not valid[-2]:
                self.stream.resume(q)  # the person seen again after frames without one, as run_physcap does
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
        seen = np.array([self.seen[i] for i in range(T)], bool)
        # as run_physcap writes them: at the frames' instants (on_pose had each interval's as it came)
        grf, residual, contacts = written_forces(
            np.stack([f[1].contact_forces for f in frames]), np.stack([f[1].residual for f in frames]),
            np.stack([f[1].active for f in frames]), seen & np.array([f[1].tracked for f in frames], bool), ~seen,
            [f[1].shares for f in frames], self.stream.tracker.substeps if self.stream is not None else 1)
        return PhysicsMotion(
            qpos=np.stack([f[0] for f in frames]), grf=grf, residual=residual, contacts=contacts,
            corrected=np.array([f[2] for f in frames]), qp_failures=np.array([f[1].qp_failures for f in frames]),
            seconds=self.seconds, floor_plane=None if self.stream is None else self.stream.floor_plane,
            unexplained=np.array([f[1].unexplained_flag for f in frames], bool))
