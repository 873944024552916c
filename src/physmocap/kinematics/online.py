"""Causal kinematic fit of a stream of detections: constant cost per frame, for live capture; and many such
streams side by side, the offline fit's starting point."""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel, build_body_model
from ..camera import Camera, Floor, world_from_floor
from ..config import Settings
from ..detect.foot_swaps import CausalFootSwaps, find_foot_swaps, swap_feet, undo_foot_swaps
from ..errors import ReconstructionError
from ..landmarks import NUM_LANDMARKS
from ..motion import Observations
from .calibration import Calibration, calibrate, resolve_height
from .fit import STATED_FPS, FitTargets, KinematicFitter, initial_qpos
from .floor import estimate_floor, move_world_to_floor, seen_sole_points
from .targets import make_targets, raw_depth, refine_lengths, smooth_depth

FIRST_FRAME_ITERATIONS = 60  # the first frame starts from a generic pose and needs more steps
WARMUP_SECONDS = 3.0  # held back to calibrate and find the floor when body.calibration_frames is 0 (all: offline
# only). On the synthetic set (8 clips, online fit) 1 s -> 3 s took the root-relative error from 56.6 to 52.5 mm and,
# through a better floor, PhysCap's from 71.5 to 60.6 mm, its MPE from 45 to 34 mm and penetration from 5.7% to 1.4%
# The offline fit's causal start raises a frame's damping tenfold after a rejected step, not fourfold: a quarter of
# the frames needed three or more rejections from the online fit's small initial damping. Synthetic set (8 clips x
# 2 seeds, 2 steps per frame): batched evaluations 318 -> 218 on sports2d, root-relative 32.1 -> 31.9 mm, global
# root 47.5 -> 45.5 mm. The online fit keeps 4 (10 cost it 50.3 -> 51.1 mm root-relative).
START_DAMPING_INCREASE = 10.0
DEPTH_WINDOW = 9  # frames in the causal running median of the person's distance


@dataclass
class CausalPast:
    """The past of K causal fits run side by side: the last (up to two) fitted poses, oldest first, each
    (K, nq), and per temporal signal their values (K, h, n). Empty: the next frame is a cold start."""

    poses: list[np.ndarray]
    signals: list[np.ndarray]

    @staticmethod
    def of(fitter: KinematicFitter, poses: list[np.ndarray]) -> CausalPast:
        """The past made of fitted poses (each (K, nq)), e.g. after the world has moved."""
        values = [fitter.signal_values(q) for q in poses]
        return CausalPast(list(poses), [np.stack(v, axis=1) for v in zip(*values, strict=True)])

    def rows(self, rows: np.ndarray) -> CausalPast:
        return CausalPast([q[rows] for q in self.poses], [v[rows] for v in self.signals])


def predicted_pose(fitter: KinematicFitter, past: CausalPast) -> np.ndarray:
    """(K, nq) the next poses by constant velocity from the last two (the last one when there is only one);
    MuJoCo's per-pose functions, as K is small."""
    q = past.poses[-1]
    if len(past.poses) == 2:
        velocity = np.empty((len(q), fitter.body.nv))
        for k in range(len(q)):
            mujoco.mj_differentiatePos(fitter.model, velocity[k], 1.0, past.poses[0][k], q[k])
        q = fitter.integrate(q, velocity)
    return q


def causal_step(fitter: KinematicFitter, targets: FitTargets, past: CausalPast, iterations: int,
                damping_increase: float = 4.0, prediction: np.ndarray | None = None) -> tuple[np.ndarray, CausalPast]:
    """Fit the next frame of each of K causal streams (targets of K frames) from its past only: warm-started
    by constant velocity from the last two poses (`prediction` if already made), or from a generic pose without a
    past (damping_increase: see KinematicFitter.fit_frames). Returns the poses (K, nq) and the past that includes
    them."""
    if not past.poses:
        K = len(targets.depth)
        q0 = np.concatenate([initial_qpos(fitter.body, fitter.camera, targets, k) for k in range(K)])
        result = fitter.fit_frames(q0, targets, None, FIRST_FRAME_ITERATIONS, damping_increase=damping_increase)
    else:
        start = predicted_pose(fitter, past) if prediction is None else prediction
        result = fitter.fit_frames(start, targets, past.signals, iterations, damping_increase=damping_increase,
                                   last=past.poses[-1])
    if result.signals is None:
        raise RuntimeError("fit_frames returned no temporal signals")
    signals = [v[:, None] for v in result.signals]
    if past.signals:
        signals = [np.concatenate([h[:, -1:], v], axis=1) for h, v in zip(past.signals, signals, strict=True)]
    return result.qpos, CausalPast(past.poses[-1:] + [result.qpos], signals)


def steps_per_frame(iterations: int, fps: float) -> int:
    """Levenberg-Marquardt steps per frame for `iterations` stated at 30 fps: below 30 fps as many more as the
    frames are fewer (the same per second of video, to the nearest step), since each frame's pose lies further
    from its prediction; above, the same. With 2 at 10 fps the offline fit's start turned pelvises half round on
    frames of the synthetic set, and the whole-clip fit kept them (docs/decisions/fit-steps-frame-rate.md)."""
    return max(iterations, math.floor(iterations * STATED_FPS / fps + 0.5))


def fit_streams(fitter: KinematicFitter, targets: FitTargets, valid: np.ndarray, chunk: int, iterations: int,
                progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """The offline fit's starting point: the causal fit run over runs of at most `chunk` valid frames, all runs
    side by side (one batched step per frame of the longest), at a fraction of one stream's cost. A run also
    starts after every gap of invalid frames, which are interpolated between their fitted neighbours, not
    extrapolated. valid: (T,) bool, at least one frame; returns qpos (T, nq). iterations: Levenberg-Marquardt
    steps per frame at 30 fps (`steps_per_frame`)."""
    iterations = steps_per_frame(iterations, fitter.fps)
    frames = np.flatnonzero(valid)
    gap_ends = np.flatnonzero(np.diff(frames, prepend=-2) > 1)  # positions in `frames` where a run begins
    run_ends = np.append(gap_ends[1:], len(frames))
    starts = np.concatenate([np.arange(a, b, chunk) for a, b in zip(gap_ends, run_ends, strict=True)])
    ends = np.append(starts[1:], len(frames))
    fitted = np.zeros((len(frames), fitter.body.nq))
    past, rows = CausalPast([], []), np.arange(len(starts))
    steps = int((ends - starts).max())
    for i in range(steps):
        running = starts[rows] + i < ends[rows]  # runs end, none begins
        rows, past = rows[running], past.rows(running)
        index = starts[rows] + i
        fitted[index], past = causal_step(fitter, targets.frames(frames[index]), past, iterations,
                                          START_DAMPING_INCREASE)
        if progress:  # frames fitted so far, over all runs
            progress(int(np.minimum(ends - starts, i + 1).sum()), len(frames))
    return _fill_gaps(fitter.body, frames, fitted, len(valid))


def _fill_gaps(body, frames: np.ndarray, qpos: np.ndarray, T: int) -> np.ndarray:
    """Poses at `frames` (sorted) -> (T, nq): frames between two of them interpolated on the manifold, frames
    before the first and after the last holding the nearest."""
    t = np.arange(T)
    before = np.maximum(np.searchsorted(frames, t, side="right") - 1, 0)
    after = np.minimum(before + 1, len(frames) - 1)
    span = frames[after] - frames[before]
    weight = np.where(span > 0, np.clip(t - frames[before], 0, None) / np.maximum(span, 1), 0.0)
    return kin.integrate(body, qpos[before], weight[:, None] * kin.difference(body, qpos[before], qpos[after]))


class OnlineFitter:
    """Fits pushed frames one at a time, each from the past only.

    The first `body.calibration_frames` (WARMUP_SECONDS' worth if 0) frames that show a person are held back: they
    calibrate the bone lengths, are fitted (twice with fit.refine_lengths: the lengths are measured again along the
    first fit, as offline), and place the floor (unless it is given); their foot swaps are found as offline. From
    then on every pushed frame is fitted at once, warm-started from the previous two frames with constant velocity,
    its feet read as detected or swapped by the clip's model of foot swaps decoded over the past (CausalFootSwaps).
    After warm-up, `body`, `camera`, `floor` and `calibration` are fixed. `foot_swap_frames` lists the frames (stream
    indices) whose feet were fitted the other way round from the detector's labels.
    """

    def __init__(self, settings: Settings, fps: float, image_size: tuple[int, int],
                 camera_K: np.ndarray | None = None):
        self.settings, self.fps, self.image_size = settings, fps, image_size
        cam = settings.camera
        self.camera = Camera.from_settings(image_size, cam.focal, cam.fov,
                                           None if (cam.focal or cam.fov) else camera_K)
        self.warmup = settings.body.calibration_frames or max(1, round(WARMUP_SECONDS * fps))
        self.body: BodyModel | None = None  # these four: None until the warm-up ends
        self.calibration: Calibration | None = None
        self.floor: Floor | None = None
        self.fitter: KinematicFitter | None = None
        self._pending: list[tuple[np.ndarray, np.ndarray, bool]] = []
        self._frames = 0
        self._depths: deque[float] = deque(maxlen=DEPTH_WINDOW)
        self._past = CausalPast([], [])
        self._foot_swaps = CausalFootSwaps(image_size[1])
        self.foot_swap_frames: list[int] = []

    def push(self, keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: bool) -> list[tuple[int, np.ndarray]]:
        """Add one frame (33, 3) + (33, 3); returns the (frame index, qpos) pairs that became ready."""
        index = self._frames
        self._frames += 1
        if self.body is None:
            self._pending.append((keypoints_2d, landmarks_3d, valid))
            if sum(v for _, _, v in self._pending) >= self.warmup:
                return self._start()
            return []
        swapped = self._foot_swaps.update(keypoints_2d, landmarks_3d, valid) and self.settings.fit.undo_foot_swaps
        if swapped:
            self.foot_swap_frames.append(index)
            keypoints_2d, landmarks_3d = swap_feet(keypoints_2d[None])[0], swap_feet(landmarks_3d[None])[0]
        return [(index, self._fit(keypoints_2d, landmarks_3d, valid))]

    def foot_swaps(self, frames: int) -> np.ndarray:
        """(frames,) bool: the stream's frames whose feet were read swapped (foot_swap_frames)."""
        swaps = np.zeros(frames, dtype=bool)
        swaps[self.foot_swap_frames] = True
        return swaps

    def skip(self) -> list[tuple[int, np.ndarray]]:
        """A frame that is not fitted (live capture dropped it): during the warm-up it is held as unseen; after,
        its pose is the constant-velocity prediction the fit of an unseen frame starts from, at a fraction of the
        fit's cost, and the past moves on by it."""
        if self.fitter is None:
            return self.push(np.zeros((NUM_LANDMARKS, 3)), np.zeros((NUM_LANDMARKS, 3)), False)
        index, self._frames = self._frames, self._frames + 1
        self._foot_swaps.skip()
        q = predicted_pose(self.fitter, self._past)
        self._past = CausalPast.of(self.fitter, self._past.poses[-1:] + [q])
        return [(index, q[0])]

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
        held = Observations(k2, k3, self.fps, self.image_size, valid=valid)
        for t in range(len(valid)):  # the causal reading's past: its sequence costs end where the clip's decision does
            self._foot_swaps.update(k2[t], k3[t], bool(valid[t]))
        swaps = find_foot_swaps(held) if s.fit.undo_foot_swaps else np.zeros(len(valid), dtype=bool)
        held = undo_foot_swaps(held, swaps)  # the warm-up is held back: its swaps are found as offline
        k2, k3 = held.keypoints_2d, held.landmarks_3d
        height, source = resolve_height(held, s.body.height, s.body.estimate_height)
        self.calibration = dataclasses.replace(calibrate(held, height, frames=0), height_source=source)
        self.body = build_body_model(self.calibration.lengths, s.body.mass)
        first = int(np.argmax(valid))
        depth = raw_depth(k2, k3, valid, self.camera.focal, self.calibration, s.fit.min_confidence)
        if not np.isfinite(depth).any():  # as offline (stage._fit_offline): nothing to place in depth
            raise ReconstructionError("no frame of the warm-up shows enough of the person with enough confidence to "
                                      "place them in depth.")
        if s.camera.floor is not None:  # the world is known: fit in it directly
            self.floor = Floor.from_plane(s.camera.floor)
            targets = make_targets(k2[first:first + 1], k3[first:first + 1], valid[first:first + 1],
                                   depth[first:first + 1], self.camera, self.calibration, s.fit)
            pelvis = initial_qpos(self.body, self.camera, targets, 0)[0, :3]
            self.camera = self.camera.with_extrinsics(*world_from_floor(self.floor, self.camera.to_camera(pelvis)))
        self.fitter = KinematicFitter(self.body, self.camera, s.fit, self.fps, causal=True)
        fitted = self._fit_held(k2, k3, valid, depth, first)
        if s.fit.refine_lengths:  # as offline, from the held frames' fit; they are fitted again with the result
            targets = make_targets(k2, k3, valid, smooth_depth(depth), self.camera, self.calibration, s.fit)
            poses = np.array(fitted)
            self.calibration = refine_lengths(self.body, self.camera, np.concatenate(
                [np.repeat(poses[:1], first, axis=0), poses]), targets, self.calibration, self.calibration.height)
            self.body = build_body_model(self.calibration.lengths, s.body.mass)
            self.fitter = KinematicFitter(self.body, self.camera, s.fit, self.fps, causal=True)
            fitted = self._fit_held(k2, k3, valid, depth, first)
        qpos = np.array(fitted)
        self.foot_swap_frames += [first_index + t for t in np.flatnonzero(swaps)]
        qpos = np.concatenate([np.repeat(qpos[:1], first, axis=0), qpos])  # hold the first pose before it
        if s.camera.floor is None:
            self.floor = estimate_floor(self.body, qpos, self.camera, self.fps, valid,
                                        seen_sole_points(k2, self.image_size, s.fit.min_confidence))
            qpos, self.camera = move_world_to_floor(qpos, self.camera, self.floor, first)
            self.fitter = KinematicFitter(self.body, self.camera, s.fit, self.fps, causal=True)
            self._past = CausalPast.of(self.fitter, [q[None] for q in qpos[-2:]])
        return list(enumerate(qpos, start=first_index))

    def _fit_held(self, k2: np.ndarray, k3: np.ndarray, valid: np.ndarray, depth: np.ndarray,
                  first: int) -> list[np.ndarray]:
        """The held warm-up frames (their foot swaps already undone) from `first` on, fitted causally from a cold
        start: per frame its qpos. A run of frames after a gap without a person starts cold again, as offline
        (`fit_streams`): the past of a lone detection before the gap would otherwise carry its depth into the
        person who then walks in."""
        fitted = []
        for t in range(first, len(valid)):
            if t == first or (valid[t] and not valid[t - 1] and np.isfinite(depth[t])):
                self._past = CausalPast([], [])
                self._depths.clear()
                # the start's depth, or the next the held frames measure (_start made sure there is one, and
                # raw_depth measures none before the first valid frame)
                self._depths.append(float(depth[t:][np.isfinite(depth[t:])][0]))
            fitted.append(self._fit(k2[t], k3[t], valid[t]))
        return fitted

    def _fit(self, keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: bool) -> np.ndarray:
        """One frame (its feet read as they are to be fitted) fitted from the past: its pose (nq,)."""
        s, calibration, fitter = self.settings, self.calibration, self.fitter
        if calibration is None or fitter is None:
            raise RuntimeError("OnlineFitter._fit ran before the warm-up calibrated the body.")  # a bug
        k2, k3, v = keypoints_2d[None], landmarks_3d[None], np.array([valid])
        depth = raw_depth(k2, k3, v, self.camera.focal, calibration, s.fit.min_confidence)[0]
        if np.isfinite(depth):
            self._depths.append(float(depth))
        depth = np.array([np.median(self._depths)])
        q = predicted_pose(fitter, self._past) if self._past.poses else None
        targets = make_targets(k2, k3, v, depth, self.camera, calibration, s.fit)
        q, self._past = causal_step(fitter, targets, self._past, steps_per_frame(s.fit.online_iterations, self.fps),
                                    prediction=q)
        return q[0]
