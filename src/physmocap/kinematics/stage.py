"""The kinematics stage: calibrate the skeleton, fit it to the observations over time, find the floor and
express the motion in the world frame (Z up, floor z = 0)."""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel, SkeletonLengths, build_body_model
from ..camera import Camera, Floor
from ..config import Settings
from ..detect.foot_swaps import find_foot_swaps, undo_foot_swaps
from ..errors import ReconstructionError
from ..motion import Observations
from .calibration import Calibration, calibrate, resolve_height
from .filters import one_euro_qpos
from .fit import MARKER_LANDMARKS, MARKERS, KinematicFitter
from .floor import estimate_floor, move_world_to_floor, seen_sole_points
from .online import OnlineFitter, fit_streams
from .targets import landmark_depth_scale, make_targets, raw_depth, refine_lengths, smooth_depth

if TYPE_CHECKING:
    from ..stages import ProgressFactory

log = logging.getLogger("physmocap")

@dataclass
class KinematicMotion:
    """Result of the kinematics stage.

    qpos: (T, nq) world frame; camera: intrinsics and world -> camera extrinsics; floor: in the camera frame;
    reprojection_error: (T,) median pixel distance of the fitted markers to confident keypoints (nan if none);
    valid: (T,) frames with observations; seconds: time spent fitting; foot_swaps: (T,) frames whose feet the fit
    took the other way round from the detector (offline: decided over the whole clip; online: per frame from the
    past, see OnlineFitter).
    """

    body: BodyModel
    calibration: Calibration
    camera: Camera
    floor: Floor
    qpos: np.ndarray
    reprojection_error: np.ndarray
    valid: np.ndarray
    seconds: float
    online: bool
    foot_swaps: np.ndarray | None = None

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Every field as named arrays (the skeleton's lengths as JSON text), for an .npz file; `from_arrays`
        rebuilds the motion exactly."""
        import json

        T = len(self.qpos)
        calibration, floor = self.calibration, self.floor
        numbers = dict(mass=self.body.mass, floor_inliers=floor.inlier_fraction, seconds=self.seconds,
                       landmark_scale=calibration.landmark_scale, height=calibration.height,
                       detector_height=calibration.detector_height, floor_tilt_spread=floor.tilt_spread,
                       floor_prior_disagreement=floor.prior_disagreement)
        return dict(qpos=self.qpos, lengths=np.array(json.dumps(self.body.lengths.__dict__)),
                    camera_K=self.camera.K, camera_R=self.camera.R, camera_t=self.camera.t,
                    image_size=np.array(self.camera.image_size), floor=floor.plane,
                    reprojection_error=np.full(T, np.nan) if self.reprojection_error is None
                    else self.reprojection_error, valid=self.valid, online=np.array(self.online, dtype=bool),
                    frames_used=np.array(calibration.frames_used, dtype=np.int64),
                    replaced=np.array(calibration.replaced, dtype=str),
                    foot_swaps=np.zeros(T, bool) if self.foot_swaps is None else np.asarray(self.foot_swaps, bool),
                    height_source=np.array(calibration.height_source),
                    floor_trusted=np.array(floor.trusted, dtype=bool), floor_source=np.array(floor.source),
                    **{name: np.array(value, dtype=np.float64) for name, value in numbers.items()})

    @classmethod
    def from_arrays(cls, arrays) -> KinematicMotion:
        """The motion `to_arrays` gave (a KeyError names a missing array)."""
        import json

        lengths = SkeletonLengths(**json.loads(str(arrays["lengths"])))
        size = arrays["image_size"]
        camera = Camera(arrays["camera_K"], arrays["camera_R"], arrays["camera_t"], (int(size[0]), int(size[1])))
        plane = np.asarray(arrays["floor"], float)  # as stored: renormalising would change its last bits
        calibration = Calibration(lengths, float(arrays["landmark_scale"]), int(arrays["frames_used"]),
                                  tuple(str(x) for x in arrays["replaced"]), float(arrays["height"]),
                                  float(arrays["detector_height"]), str(arrays["height_source"]))
        floor = Floor(plane[:3], float(plane[3]), float(arrays["floor_inliers"]), float(arrays["floor_tilt_spread"]),
                      float(arrays["floor_prior_disagreement"]), bool(arrays["floor_trusted"]),
                      str(arrays["floor_source"]))
        return cls(build_body_model(lengths, float(arrays["mass"])), calibration, camera, floor, arrays["qpos"],
                   arrays["reprojection_error"], arrays["valid"], float(arrays["seconds"]), bool(arrays["online"]),
                   arrays["foot_swaps"])


def fit_motion(obs: Observations, settings: Settings, progress: ProgressFactory | None = None) -> KinematicMotion:
    """Calibrate, fit, find the floor and express everything in the world frame.

    Online: frame by frame through OnlineFitter, exactly as a live stream is fitted (progress: "fit", frames).
    Offline: causal fits of short runs of frames, all side by side ("fit start", frames), start a joint
    optimisation over the whole clip ("fit clip", frame passes: see KinematicFitter.fit_offline), after which the
    floor is found from all frames.
    """
    start = time.perf_counter()
    if not obs.valid.any():
        raise ReconstructionError(f"{obs.source}: no frame shows a person to fit.")
    motion = (_fit_online if settings.online else _fit_offline)(obs, settings, progress)
    qpos = motion.qpos
    if settings.fit.one_euro:
        qpos = one_euro_qpos(motion.body, qpos, obs.fps, settings.fit.one_euro_min_cutoff, settings.fit.one_euro_beta)
    error = reprojection_errors(motion.body, motion.camera, qpos, obs)
    return dataclasses.replace(motion, qpos=qpos, reprojection_error=error, seconds=time.perf_counter() - start)


def _fit_online(obs: Observations, settings: Settings, progress: ProgressFactory | None) -> KinematicMotion:
    bar = progress("fit", obs.num_frames) if progress else None
    online = OnlineFitter(settings, obs.fps, obs.image_size, obs.camera_K)
    qpos: np.ndarray | None = None

    def store(results):
        nonlocal qpos
        for index, q in results:
            if qpos is None:
                qpos = np.zeros((obs.num_frames, len(q)))
            qpos[index] = q

    for t in range(obs.num_frames):
        store(online.push(obs.keypoints_2d[t], obs.landmarks_3d[t], bool(obs.valid[t])))
        if bar:
            bar(t + 1, obs.num_frames)
    store(online.finish())
    if online.body is None or online.calibration is None or online.floor is None or qpos is None:
        raise ReconstructionError(f"{obs.source}: no frame shows a person to fit.")
    unmeasured = np.full(obs.num_frames, np.nan)  # fit_motion measures the reprojection errors
    return KinematicMotion(online.body, online.calibration, online.camera, online.floor, qpos, unmeasured,
                           obs.valid.copy(), 0.0, True, online.foot_swaps(obs.num_frames))


def _fit_offline(obs: Observations, settings: Settings, progress: ProgressFactory | None) -> KinematicMotion:
    s = settings
    swaps = find_foot_swaps(obs) if s.fit.undo_foot_swaps else np.zeros(obs.num_frames, dtype=bool)
    obs = undo_foot_swaps(obs, swaps)
    camera = Camera.from_settings(obs.image_size, s.camera.focal, s.camera.fov,
                                  None if (s.camera.focal or s.camera.fov) else obs.camera_K)
    height, source = resolve_height(obs, s.body.height, s.body.estimate_height)
    calibration = dataclasses.replace(calibrate(obs, height, frames=s.body.calibration_frames), height_source=source)
    body = build_body_model(calibration.lengths, s.body.mass)
    depth = raw_depth(obs.keypoints_2d, obs.landmarks_3d, obs.valid, camera.focal, calibration, s.fit.min_confidence)
    if not np.isfinite(depth).any():
        raise ReconstructionError(f"{obs.source}: no frame shows enough of the person with enough confidence to "
                                  "place them in depth.")
    depth = smooth_depth(depth)
    targets = make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, depth, camera, calibration, s.fit)
    fitter = KinematicFitter(body, camera, s.fit, obs.fps)
    qpos = fit_streams(fitter, targets, obs.valid, s.fit.offline_chunk, s.fit.offline_start_iterations,
                       progress("fit start", int(obs.valid.sum())) if progress else None)
    if s.fit.rescale_landmark_depth:
        scale = landmark_depth_scale(body, camera, qpos, obs, targets, calibration)
        obs = dataclasses.replace(obs, landmarks_3d=obs.landmarks_3d * np.stack(
            [np.ones_like(scale), np.ones_like(scale), 1.0 / scale], axis=1)[:, None])
        targets = make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, depth, camera, calibration, s.fit)
    if s.fit.refine_lengths:
        calibration = refine_lengths(body, camera, qpos, targets, calibration, calibration.height)
        body = build_body_model(calibration.lengths, s.body.mass)
        fitter = KinematicFitter(body, camera, s.fit, obs.fps)
    bar = progress("fit clip", fitter.planned_passes(len(qpos)), "frame passes") if progress else None
    qpos = hold_outside_valid(fitter.fit_offline(qpos, targets, bar).qpos, obs.valid)
    floor = (Floor.from_plane(s.camera.floor) if s.camera.floor is not None
             else estimate_floor(body, qpos, camera, obs.fps, obs.valid,
                                 seen_sole_points(obs.keypoints_2d, obs.image_size, s.fit.min_confidence)))
    qpos, camera = move_world_to_floor(qpos, camera, floor, int(np.argmax(obs.valid)))
    unmeasured = np.full(obs.num_frames, np.nan)  # fit_motion measures the reprojection errors
    return KinematicMotion(body, calibration, camera, floor, qpos, unmeasured, obs.valid.copy(), 0.0, False, swaps)


def hold_outside_valid(qpos: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """qpos (T, nq) with the frames before the first valid frame holding its pose and those after the last
    holding that one: a whole-clip fit has no data there and its smoothness terms extrapolate the motion (on
    sports2d the feet ended 0.9 m under the floor three frames before the person appeared)."""
    frames = np.flatnonzero(valid)
    if len(frames):
        qpos = qpos.copy()
        qpos[:frames[0]] = qpos[frames[0]]
        qpos[frames[-1] + 1:] = qpos[frames[-1]]
    return qpos


def reprojection_errors(body: BodyModel, camera: Camera, qpos: np.ndarray, obs: Observations,
                        min_confidence: float = 0.5) -> np.ndarray:
    """(T,) median pixel distance between projected markers and confident keypoints per frame."""
    pts = kin.forward_kinematics(body, qpos).points[:, body.point_index([b for _, b in MARKERS])]
    kp = obs.keypoints_2d[:, MARKER_LANDMARKS]
    dist = np.linalg.norm(camera.project(pts) - kp[..., :2], axis=-1)
    dist[kp[..., 2] < min_confidence] = np.nan
    dist[~obs.valid] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames without confident keypoints give nan
        return np.nanmedian(dist, axis=1)
