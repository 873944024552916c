"""Causal kinematic fit of a stream of detections: constant cost per frame, for live capture."""

from __future__ import annotations

from collections import deque

import numpy as np

from ..body import kinematics as kin
from ..body.model import build_body_model
from ..camera import Camera, Floor, world_from_floor
from ..config import Settings
from ..motion import Observations
from .calibration import calibrate
from .fit import KinematicFitter, initial_qpos
from .stage import estimate_floor, make_targets, move_world_to_floor, raw_depth

FIRST_FRAME_ITERATIONS = 60  # the first frame starts from a generic pose and needs more steps
DEPTH_WINDOW = 9  # frames in the causal running median of the person's distance


class OnlineFitter:
    """Fits pushed frames one at a time, each from the past only.

    The first `body.calibration_frames` frames that show a person are held back: they calibrate the bone
    lengths, are fitted, and place the floor (unless it is given). From then on every pushed frame is fitted at
    once, warm-started from the previous two frames with constant velocity. After warm-up, `body`, `camera`,
    `floor` and `calibration` are fixed.
    """

    def __init__(self, settings: Settings, fps: float, image_size: tuple[int, int],
                 camera_K: np.ndarray | None = None):
        self.settings, self.fps, self.image_size = settings, fps, image_size
        cam = settings.camera
        self.camera = Camera.from_settings(image_size, cam.focal, cam.fov,
                                           None if (cam.focal or cam.fov) else camera_K)
        self.warmup = settings.body.calibration_frames or 30
        self.body = self.calibration = self.floor = self.fitter = None
        self._pending: list[tuple[np.ndarray, np.ndarray, bool]] = []
        self._frames = 0
        self._depths: deque[float] = deque(maxlen=DEPTH_WINDOW)
        self._recent: deque[np.ndarray] = deque(maxlen=2)
        self._history: list[deque] = []

    def push(self, keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: bool) -> list[tuple[int, np.ndarray]]:
        """Add one frame (33, 3) + (33, 3); returns the (frame index, qpos) pairs that became ready."""
        index = self._frames
        self._frames += 1
        if self.body is None:
            self._pending.append((keypoints_2d, landmarks_3d, valid))
            if sum(v for _, _, v in self._pending) >= self.warmup:
                return self._start()
            return []
        return [(index, self._fit(keypoints_2d, landmarks_3d, valid))]

    def finish(self) -> list[tuple[int, np.ndarray]]:
        """End of stream: fits what the warm-up still holds (a clip shorter than the warm-up)."""
        if self.body is None and any(v for _, _, v in self._pending):
            return self._start()
        return []

    def _start(self) -> list[tuple[int, np.ndarray]]:
        k2 = np.stack([p[0] for p in self._pending])
        k3 = np.stack([p[1] for p in self._pending])
        valid = np.array([p[2] for p in self._pending])
        first_index = self._frames - len(self._pending)
        self._pending = []
        s = self.settings
        self.calibration = calibrate(Observations(k2, k3, self.fps, self.image_size, valid=valid), s.body.height,
                                     frames=0)
        self.body = build_body_model(self.calibration.lengths, s.body.mass)
        first = int(np.argmax(valid))
        depth = raw_depth(k2, k3, valid, self.camera.focal, self.calibration, s.fit.min_confidence)
        self._depths.append(float(depth[first]))
        if s.camera.floor is not None:  # the world is known: fit in it directly
            self.floor = Floor.from_plane(s.camera.floor)
            targets = make_targets(k2[first:first + 1], k3[first:first + 1], valid[first:first + 1],
                                   depth[first:first + 1], self.camera, self.calibration, s.fit)
            pelvis = initial_qpos(self.body, self.camera, targets, 0)[0, :3]
            self.camera = self.camera.with_extrinsics(*world_from_floor(self.floor, self.camera.to_camera(pelvis)))
        self.fitter = KinematicFitter(self.body, self.camera, s.fit, self.fps)
        qpos = np.array([self._fit(k2[t], k3[t], valid[t]) for t in range(first, len(valid))])
        qpos = np.concatenate([np.repeat(qpos[:1], first, axis=0), qpos])  # hold the first pose before it
        if s.camera.floor is None:
            self.floor = estimate_floor(self.body, qpos, self.camera, self.fps, valid)
            qpos, self.camera = move_world_to_floor(qpos, self.camera, self.floor, first)
            self.fitter = KinematicFitter(self.body, self.camera, s.fit, self.fps)
            self._recent = deque(qpos[-2:], maxlen=2)
            self._history = [deque(v, maxlen=2) for v in self.fitter.signal_values(qpos[-2:])]
        return list(zip(range(first_index, first_index + len(qpos)), qpos))

    def _fit(self, keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: bool) -> np.ndarray:
        s, body = self.settings, self.body
        k2, k3, v = keypoints_2d[None], landmarks_3d[None], np.array([valid])
        depth = raw_depth(k2, k3, v, self.camera.focal, self.calibration, s.fit.min_confidence)[0]
        if np.isfinite(depth):
            self._depths.append(float(depth))
        targets = make_targets(k2, k3, v, np.array([np.median(self._depths)]), self.camera, self.calibration,
                               s.fit)
        if not self._recent:
            q0, steps = initial_qpos(body, self.camera, targets, 0), FIRST_FRAME_ITERATIONS
        else:
            q0, steps = self._recent[-1][None], s.fit.online_iterations
            if len(self._recent) == 2:
                q0 = kin.integrate(body, q0, kin.difference(body, self._recent[0][None], q0))
        past = [np.array(h) if h else None for h in self._history] if self._history else [None, None]
        q = self.fitter.fit_frame(q0, targets, past, steps).qpos[0]
        values = self.fitter.signal_values(q[None])
        if not self._history:
            self._history = [deque(maxlen=2) for _ in values]
        for h, value in zip(self._history, values):
            h.append(value[0])
        self._recent.append(q)
        return q
