"""The shared real videos used to measure MediaPipe's noise and to evaluate contacts on hand-labelled frames.

Development helpers: the product never needs these videos. Detections are cached as observations files, because
MediaPipe takes 25-40 ms a frame here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from ..motion import Observations


@dataclass(frozen=True)
class RealVideo:
    """One video and the person to follow in it.

    name: short name, used for cache files and label rows.
    relative_path: path under the shared videos folder.
    person_box: (x0, y0, x1, y1) native pixels around the person to follow where they first appear; None for the
        person MediaPipe finds first.
    """

    name: str
    relative_path: str
    person_box: tuple[float, float, float, float] | None = None


REAL_VIDEOS: tuple[RealVideo, ...] = (
    RealVideo("taiji", "hybrik_taiji.mp4"),
    RealVideo("basketball", "mmhuman3d_single_person_demo.mp4"),
    RealVideo("sports2d_box", "sports2d_demo.mp4"),
    RealVideo("pose2sim_cam01", "pose2sim_demo_singleperson/cam01.mp4"),
    RealVideo("pose2sim_cam02", "pose2sim_demo_singleperson/cam02.mp4"),
    RealVideo("pose2sim_cam03", "pose2sim_demo_singleperson/cam03.mp4"),
    RealVideo("pose2sim_cam04", "pose2sim_demo_singleperson/cam04.mp4"),
)
DETECTOR_MAX_WIDTH = 640  # px: the pipeline's default (config.DetectSettings.max_width)


def cached_detection(video: RealVideo, videos_dir: str | os.PathLike, cache_dir: str | os.PathLike) -> Observations:
    """MediaPipe observations of `video`, from `cache_dir`/<name>.npz, detecting and caching them if missing."""
    from ..detect.mediapipe_pose import detect_video

    cache = Path(cache_dir) / f"{video.name}.npz"
    if cache.is_file():
        return Observations.load(cache)
    observations = detect_video(
        Path(videos_dir) / video.relative_path, person_box=video.person_box, max_width=DETECTOR_MAX_WIDTH
    )
    cache.parent.mkdir(parents=True, exist_ok=True)
    observations.save(cache)
    return observations
