"""Detection of a long video by two MediaPipe graphs at once, each on its own part, so that two cores are busy.

One MediaPipe graph keeps about 1.15 cores busy; its calculators run in MediaPipe's own threads, and the Python
thread that feeds it waits without the GIL, so two graphs in two threads keep two cores busy
(docs/decisions/detect-two-graphs.md). The calling thread's follower detects frames [0, split); a second
follower, in a thread, starts fresh (on the whole frame, or the person_box region) at `split - overlap` and
detects to the end. The junction check then compares the two on the overlap's last frames, after the second
graph has settled: where both follow someone, their torso centres and sizes must agree. If they do, the second
graph's frames from `split` on are kept; if they do not (another person, a lost track), the calling thread's
follower continues over the second part as a sequential run would, and one log line says so. Either way the
person followed is the one a sequential run follows.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from ..cores import may_use_two_cores
from ..io.video import VideoInfo, iter_frames
from .mediapipe_pose import PREFETCH_FRAMES, Box, Detections, PersonFollower, torso_centre_and_size

logger = logging.getLogger(__name__)

MIN_FRAMES = 300
"""Frames a video needs for two graphs: the second graph takes 0.2-0.5 s to load and detects the overlap a
second time (about 0.7 CPU s at 30 fps); half of 300 frames saves some 4 s."""
OVERLAP_SECONDS = 1.0
"""Seconds of video the second graph detects before the split: its first half settles MediaPipe's tracking and
smoothing, its second half is compared with the first graph's."""
MIN_OVERLAP = 10
"""Frames of overlap at least, whatever the frame rate."""
CENTRE_TOLERANCE = 0.25
"""Torso sizes by which the two graphs' torso centres may differ on a compared frame (the same person: at most
0.04 on the validation clips, docs/decisions/detect-two-graphs.md; another person: a torso size or more)."""
SIZE_TOLERANCE = 1.25
"""Factor by which the two graphs' torso sizes may differ on a compared frame (the same person: at most 1.08)."""
MIN_COMPARED = 3
"""Overlap frames on which both graphs must follow someone for the junction check to trust the splice."""


@dataclass(frozen=True)
class Plan:
    """Frames [0, split) go to the first graph, [overlap_start, end) to the second; the overlap's frames from
    compare_from to split are compared. announced: the frames the video announces."""

    announced: int
    split: int
    overlap_start: int
    compare_from: int


def graphs_to_run(requested: int | None) -> int:
    """MediaPipe graphs detection runs at once in this process: `requested` (1 or 2); None chooses 2 where this
    process may use two cores (`cores.may_use_two_cores`: not in a pool or batch worker)."""
    if requested is not None:
        return requested
    return 2 if may_use_two_cores() else 1


def two_part_plan(info: VideoInfo, graphs: int | None) -> Plan | None:
    """How to split the video `info` describes between two graphs, or None to detect it with one."""
    frames = info.frame_count
    if graphs_to_run(graphs) < 2 or frames < MIN_FRAMES:
        return None
    overlap = max(MIN_OVERLAP, round(OVERLAP_SECONDS * info.fps))
    split = (frames + overlap) // 2  # both graphs detect about as many frames
    return Plan(frames, split, split - overlap, split - overlap // 2)


class _SharedProgress:
    """One progress report over both graphs: the first graph's frames, and the second's from the split on. The
    last frame is reported only once the junction is decided, and frames detected again after a failed junction
    check add to the total, so the count never runs backwards or finishes early."""

    def __init__(self, progress: Callable[[int, int], None] | None, announced: int, split: int) -> None:
        self.progress, self.announced, self.split = progress, announced, split
        self.first_done = self.second_done = self.redone = 0
        self._lock = threading.Lock()

    def first_frame(self, index: int) -> None:
        with self._lock:
            self.first_done = index + 1
            self._report(final=False)

    def second_frame(self, index: int) -> None:
        with self._lock:
            self.second_done = max(0, index + 1 - self.split)
            self._report(final=False)

    def redo_second_part(self) -> None:
        """The first graph detects the second part again: its frames from the split on count as more work."""
        with self._lock:
            self.redone = self.second_done

    def finish(self) -> None:
        with self._lock:
            self._report(final=True)

    def _report(self, final: bool) -> None:
        if self.progress is None:
            return
        done = self.first_done + self.redone + (0 if self.redone else self.second_done)
        total = max(self.announced + self.redone, done)
        self.progress(done if final else min(done, total - 1), total)


def junction_mismatch(first: Detections, second: Detections, plan: Plan) -> str:
    """Why the two graphs may not be spliced at plan.split ("" when they follow the same person): on the frames
    from plan.compare_from to the split where both follow someone, torso centres and sizes must agree."""
    compared = 0
    for frame in range(plan.compare_from, min(plan.split, first.end, second.end)):
        reasons = first.reasons[frame - first.first], second.reasons[frame - second.first]
        if reasons != ("", ""):
            continue
        centre_a, size_a = torso_centre_and_size(first.keypoints.block[frame - first.first, :, :2])
        centre_b, size_b = torso_centre_and_size(second.keypoints.block[frame - second.first, :, :2])
        step = float(np.linalg.norm(centre_b - centre_a)) / max(size_a, 1e-6)
        ratio = max(size_a, size_b) / max(min(size_a, size_b), 1e-6)
        if step > CENTRE_TOLERANCE or ratio > SIZE_TOLERANCE:
            return (f"at frame {frame} their torso centres are {step:.2f} torso sizes apart and their sizes differ "
                    f"by a factor {ratio:.2f}")
        compared += 1
    if compared < MIN_COMPARED:
        return (f"both followed someone on only {compared} of the overlap's frames "
                f"{plan.compare_from}-{plan.split - 1}")
    return ""


def detect_in_two_parts(path: str | os.PathLike, plan: Plan, follower: PersonFollower,
                        frames: Iterator[tuple[int, np.ndarray]], person_box: Box | None, max_width: int | None,
                        progress: Callable[[int, int], None] | None) -> tuple[Detections, float]:
    """The detections of the whole video and the wall seconds they took (both graphs at once): `follower` on
    `frames` (the sequential reader, from frame 0) up to the split, a second follower in a thread from
    plan.overlap_start on, spliced or redone as the module says. Ctrl-C or an error in either stops both."""
    started = time.perf_counter()
    report = _SharedProgress(progress, plan.announced, plan.split)
    first, second = Detections(0), Detections(plan.overlap_start)
    stop, failed = threading.Event(), threading.Event()
    failure: list[BaseException] = []

    def detect_second_part() -> None:
        try:
            second_follower = PersonFollower(follower.image_size, follower.fps, person_box=person_box,
                                             max_width=max_width)
            try:
                second_frames = iter(iter_frames(path, prefetch=PREFETCH_FRAMES, start_frame=plan.overlap_start))
                try:
                    second.detect(second_follower, second_frames, report.second_frame, stop=stop)
                finally:
                    second_frames.close()
            finally:
                second_follower.close()
        except BaseException as error:  # handed to the calling thread, which stops and raises it
            failure.append(error)
            failed.set()

    thread = threading.Thread(target=detect_second_part, name="physmocap-detect-second", daemon=True)
    thread.start()
    try:
        first.detect(follower, frames, report.first_frame, stop_before=plan.split, stop=failed)
        thread.join()
    finally:
        stop.set()
        thread.join()
    if failure:
        raise failure[0]
    if first.end < plan.split:  # the video stopped decoding before the split: the second part holds no frame
        report.finish()
        return first, time.perf_counter() - started
    mismatch = junction_mismatch(first, second, plan)
    if mismatch:
        logger.info("%s: the second detection graph, started at frame %d, may follow another person than the "
                    "first (%s): the first graph detects frames %d on as well.", path, plan.overlap_start,
                    mismatch, plan.split)
        report.redo_second_part()
        first.detect(follower, frames, report.first_frame)
        whole = first
    else:
        whole = first.spliced(second, plan.split)
    report.finish()
    return whole, time.perf_counter() - started

