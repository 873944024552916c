"""The shared real videos used to measure MediaPipe's noise and to evaluate contacts on hand-labelled frames.

Development helpers: the product never needs these videos. Detections are cached as observations files, because
MediaPipe takes 25-40 ms a frame here. The hand labels live in benchmarks/labels/contacts_real.toml.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..motion import Observations
from .labels import CONTACT_SITES


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
    RealVideo("sports2d_walk", "sports2d_demo.mp4", person_box=(900.0, 500.0, 1170.0, 960.0)),
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


@dataclass(frozen=True)
class RealLabels:
    """Hand labels of one video (see benchmarks/labels/contacts_real.md).

    frames: (N,) labelled frame indices, sorted.
    contacts: (N, 4) int8, l heel, l toe, r heel, r toe: 1 contact, 0 no contact, -1 not judged.
    stationary: (N,) int8: 1 stationary, 0 moving, -1 not judged.
    """

    frames: np.ndarray
    contacts: np.ndarray
    stationary: np.ndarray


def parse_frames(spec: str) -> np.ndarray:
    """Frame indices of a space-separated list of "a", "a-b" (inclusive) and "a-b:step" items, sorted, unique."""
    frames: set[int] = set()
    for item in spec.split():
        span, _, step = item.partition(":")
        first, _, last = span.partition("-")
        frames.update(range(int(first), int(last or first) + 1, int(step or 1)))
    return np.array(sorted(frames), dtype=int)


def load_real_labels(path: str | os.PathLike) -> dict[str, RealLabels]:
    """Read the hand-label file (benchmarks/labels/contacts_real.toml): video name -> RealLabels."""
    with open(path, "rb") as file:
        table = tomllib.load(file)
    labels = {}
    for name, entry in table.items():
        frames = np.setdiff1d(parse_frames(entry["frames"]), parse_frames(entry.get("exclude", "")))
        contacts = np.ones((len(frames), len(CONTACT_SITES)), dtype=np.int8)
        for column, site in enumerate(CONTACT_SITES):
            contacts[np.isin(frames, parse_frames(entry.get("no_contact", {}).get(site, ""))), column] = 0
            contacts[np.isin(frames, parse_frames(entry.get("unknown", {}).get(site, ""))), column] = -1
        stationary = np.full(len(frames), -1, dtype=np.int8)
        stationary[np.isin(frames, parse_frames(entry.get("stationary", {}).get("yes", "")))] = 1
        stationary[np.isin(frames, parse_frames(entry.get("stationary", {}).get("no", "")))] = 0
        labels[name] = RealLabels(frames, contacts, stationary)
    return labels
