"""Containers that flow between the stages. Plain data with shapes in their docstrings; no algorithms.

T is the number of frames, K = 33 MediaPipe landmarks, J the number of named points of the body model.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .errors import InputError
from .io.atomic import read_npz, save_npz
from .landmarks import NUM_LANDMARKS


def _numbers(path: Path, key: str, value) -> np.ndarray:
    """value as a float64 array, or InputError naming the file and the key (a file written by other code may hold
    text or objects there)."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {key} must hold numbers, got {np.asarray(value).dtype} values.") from None


def valid_runs(valid: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every run of valid frames."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], valid.astype(int), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def long_runs(flags: np.ndarray, min_frames: int) -> np.ndarray:
    """(T,) bool: flags (T,) without the runs of True shorter than min_frames."""
    out = np.zeros(len(flags), bool)
    for start, stop in valid_runs(np.asarray(flags, bool)):
        out[start:stop] = stop - start >= min_frames
    return out


def frame_ranges(frames) -> list[str]:
    """Sorted frame indices as ranges: [3, 4, 5, 9] -> ['3-5', '9']."""
    frames = [int(f) for f in frames]
    out, start = [], None
    for i, f in enumerate(frames):
        start = f if start is None else start
        if i + 1 == len(frames) or frames[i + 1] != f + 1:
            out.append(str(start) if start == f else f"{start}-{f}")
            start = None
    return out

@dataclass
class Observations:
    """What a detector saw, independent of the detector.

    keypoints_2d: (T, K, 3) x, y in pixels of the native image, confidence in 0..1 (0 where not seen).
    landmarks_3d: (T, K, 3) metres, relative to the midpoint of the hips, axes aligned with the camera
        (x right, y down, z away from the camera).
    fps: frames per second of the source.
    image_size: (width, height) in pixels.
    camera_K: (3, 3) intrinsics if the source knows them, else None.
    valid: (T,) False where no person was found or the track seems to have jumped to someone else; left out
        (empty): every frame is valid.
    invalid_reason: (T,) short text per frame, "" where valid; left out (empty): "invalid" where not valid.
    repeated: (T,) True where the frame shows the picture of the frame before it again (detect/repeats.py): its
        detection is no new observation; left out (empty): no frame is.
    source: where the observations came from (a path or a detector name).
    """

    keypoints_2d: np.ndarray
    landmarks_3d: np.ndarray
    fps: float
    image_size: tuple[int, int]
    camera_K: np.ndarray | None = None
    valid: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    invalid_reason: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=object))
    repeated: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    source: str = ""
    seconds_per_frame: float = field(default=0.0, compare=False)

    def __post_init__(self) -> None:
        self.keypoints_2d = np.asarray(self.keypoints_2d, dtype=np.float64)
        self.landmarks_3d = np.asarray(self.landmarks_3d, dtype=np.float64)
        T = len(self.keypoints_2d)
        self.valid = np.asarray(self.valid, dtype=bool)
        if len(self.valid) == 0:
            self.valid = np.ones(T, dtype=bool)
        self.invalid_reason = np.asarray(self.invalid_reason, dtype=object)
        if len(self.invalid_reason) == 0:
            self.invalid_reason = np.where(self.valid, "", "invalid").astype(object)
        self.repeated = np.asarray(self.repeated, dtype=bool)
        if len(self.repeated) == 0:
            self.repeated = np.zeros(T, dtype=bool)
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))
        self.fps = float(self.fps)

    @property
    def num_frames(self) -> int:
        return len(self.keypoints_2d)

    def select(self, frames) -> Observations:
        """These observations on `frames` only (a slice or an index array): every per-frame array taken alike."""
        return replace(self, keypoints_2d=self.keypoints_2d[frames], landmarks_3d=self.landmarks_3d[frames],
                       valid=self.valid[frames], invalid_reason=self.invalid_reason[frames],
                       repeated=self.repeated[frames])

    def save(self, path: str | os.PathLike) -> None:
        arrays = dict(
            keypoints_2d=self.keypoints_2d.astype(np.float32),
            landmarks_3d=self.landmarks_3d.astype(np.float32),
            fps=np.float64(self.fps),
            image_size=np.asarray(self.image_size, dtype=np.int64),
            valid=self.valid,
            invalid_reason=self.invalid_reason.astype(str),
            repeated=self.repeated,
            source=np.str_(self.source),
            seconds_per_frame=np.float64(self.seconds_per_frame),
        )
        if self.camera_K is not None:
            arrays["camera_K"] = np.asarray(self.camera_K, dtype=np.float64)
        save_npz(path, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Observations:
        """Read and check an observations file; any problem raises InputError naming the file."""
        path = Path(path)
        contents = read_npz(path, "observations")
        for key in ("keypoints_2d", "landmarks_3d", "fps", "image_size"):
            if key not in contents:
                raise InputError(f"{path}: observations file has no '{key}' array.")
        k2, k3 = (_numbers(path, key, contents[key]) for key in ("keypoints_2d", "landmarks_3d"))
        if k2.ndim != 3 or k2.shape[1:] != (NUM_LANDMARKS, 3):
            raise InputError(f"{path}: keypoints_2d has shape {k2.shape}, expected (T, {NUM_LANDMARKS}, 3).")
        if k3.shape != k2.shape:
            raise InputError(f"{path}: landmarks_3d has shape {k3.shape}, expected {k2.shape} like keypoints_2d.")
        if len(k2) == 0:
            raise InputError(f"{path}: observations file holds no frames.")
        fps_values = _numbers(path, "fps", contents["fps"]).reshape(-1)
        fps = float(fps_values[0]) if fps_values.size else float("nan")
        if not np.isfinite(fps) or fps <= 0:
            raise InputError(f"{path}: fps is {fps}, expected a positive number.")
        size = _numbers(path, "image_size", contents["image_size"]).reshape(-1)
        if size.shape != (2,) or not np.all(np.isfinite(size) & (size > 0)):
            raise InputError(f"{path}: image_size is {size.tolist()}, expected (width, height) in pixels.")
        K = None if contents.get("camera_K") is None else _numbers(path, "camera_K", contents["camera_K"])
        if K is not None and (K.shape != (3, 3) or not np.isfinite(K).all()):
            raise InputError(f"{path}: camera_K is {K.tolist()}, expected a finite (3, 3) matrix.")
        valid = contents.get("valid")
        if valid is not None and valid.shape != (len(k2),):
            raise InputError(f"{path}: valid has shape {valid.shape}, expected ({len(k2)},).")
        # Non-finite values mark missing detections: make them explicit zero-confidence points.
        k2 = np.array(k2, dtype=np.float64)
        k3 = np.array(k3, dtype=np.float64)
        missing = ~np.isfinite(k2).all(axis=2) | ~np.isfinite(k3).all(axis=2)
        k2[missing] = 0.0
        k3[missing] = 0.0
        seen = k2[:, :, 2].max(axis=1) > 0
        valid = seen if valid is None else np.asarray(valid, dtype=bool) & seen  # a frame with nothing seen has no pose
        reason = contents.get("invalid_reason")
        repeated = contents.get("repeated")
        if repeated is not None and repeated.shape != (len(k2),):
            raise InputError(f"{path}: repeated has shape {repeated.shape}, expected one flag for each of the "
                             f"{len(k2)} frames.")
        spf = _numbers(path, "seconds_per_frame", contents.get("seconds_per_frame", 0.0)).reshape(-1)
        if not np.all(np.isfinite(spf) & (spf >= 0)):
            raise InputError(f"{path}: seconds_per_frame is {spf.tolist()}, expected a number of seconds >= 0.")
        return cls(
            keypoints_2d=k2,
            landmarks_3d=k3,
            fps=fps,
            image_size=(int(size[0]), int(size[1])),
            camera_K=K,
            valid=np.asarray(valid, dtype=bool),
            invalid_reason=np.zeros(0, dtype=object) if reason is None else reason.astype(object),
            repeated=np.zeros(0, dtype=bool) if repeated is None else np.asarray(repeated, dtype=bool),
            source=str(contents.get("source", path)),
            seconds_per_frame=float(next(iter(spf), 0.0)),
        )
