"""The kinematics stage: calibrate the skeleton, fit it to the observations over time, find the floor and
express the motion in the world frame (Z up, floor z = 0)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..body import kinematics as kin
from ..body.model import CONTACT_POINTS, BodyModel, build_body_model
from ..body.rotations import matrix_to_quat, quat_multiply
from ..camera import PROVISIONAL_R, Camera, Floor, fit_floor, world_from_floor
from ..config import Settings
from ..errors import ReconstructionError
from ..motion import Observations
from .calibration import Calibration, calibrate
from .filters import one_euro_qpos
from .fit import MARKER_LANDMARKS, FitTargets, KinematicFitter, initial_qpos

FIRST_FRAME_ITERATIONS = 60  # the first frame starts from a generic pose and needs more steps


@dataclass
class KinematicMotion:
    """Result of the kinematics stage.

    qpos: (T, nq) world frame; camera: intrinsics and world -> camera extrinsics; floor: in the camera frame;
    reprojection_error: (T,) median pixel distance of the fitted markers to confident keypoints (nan if none);
    valid: (T,) frames with observations; seconds: time spent fitting.
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


def make_targets(obs: Observations, camera: Camera, calibration: Calibration, settings: Settings) -> FitTargets:
    """Observations -> what the fit pulls towards, in the camera's world frame."""
    fit = settings.fit
    kp = obs.keypoints_2d[:, MARKER_LANDMARKS]
    conf = np.where(kp[..., 2] >= fit.min_confidence, kp[..., 2], 0.0) * obs.valid[:, None]
    rel_cam = obs.landmarks_3d[:, MARKER_LANDMARKS] * calibration.landmark_scale
    targets_3d = rel_cam @ camera.R  # camera -> world axes (R is world -> camera)
    weight_3d = np.sqrt(fit.weight_3d) * obs.valid[:, None] * np.sqrt(np.clip(kp[..., 2], 0.3, 1.0))
    # Distance by similar triangles: spread of the metric skeleton across the image plane against its
    # spread in pixels. Smoothed over time; frames without a person take their neighbours' values.
    spread_3d = np.sqrt(np.sum(conf * np.sum((rel_cam[..., :2] - _wmean(rel_cam[..., :2], conf)) ** 2, -1), 1))
    spread_2d = np.sqrt(np.sum(conf * np.sum((kp[..., :2] - _wmean(kp[..., :2], conf)) ** 2, -1), 1))
    good = obs.valid & (spread_2d > 1e-6)
    if not good.any():
        raise ReconstructionError(f"{obs.source}: no frame has enough keypoints to place the person.")
    depth = np.full(obs.num_frames, np.nan)
    depth[good] = camera.focal * spread_3d[good] / spread_2d[good]
    depth = np.interp(np.arange(len(depth)), np.flatnonzero(good), depth[good])
    depth = _running_median(depth, 9)
    return FitTargets(kp[..., :2], np.sqrt(fit.weight_2d * conf), targets_3d, weight_3d, depth)


def _wmean(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return (np.sum(x * w[..., None], axis=1) / np.maximum(w.sum(axis=1), 1e-9)[:, None])[:, None]


def _running_median(x: np.ndarray, width: int) -> np.ndarray:
    pad = width // 2
    padded = np.pad(x, pad, mode="edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1)


def fit_online(fitter: KinematicFitter, targets: FitTargets, valid: np.ndarray, iterations: int,
               progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Causal fit, frame by frame, warm-started from the previous frame with constant velocity."""
    body = fitter.body
    T = len(targets.depth)
    qpos = np.empty((T, body.nq))
    history: list[list[np.ndarray]] = [[], []]
    first = int(np.argmax(valid))
    for t in range(T):
        frame = targets.frames(slice(t, t + 1))
        if t <= first:
            q0 = initial_qpos(body, fitter.camera, targets, first)
            steps = FIRST_FRAME_ITERATIONS
        else:
            q0 = qpos[t - 1:t]
            if t >= 2:
                q0 = kin.integrate(body, q0, kin.difference(body, qpos[t - 2:t - 1], qpos[t - 1:t]))
            steps = iterations
        past = [np.array(h[-2:]) if h else None for h in history]
        qpos[t] = fitter.fit_frame(q0, frame, past, steps).qpos[0]
        for h, values in zip(history, fitter.signal_values(qpos[t:t + 1])):
            h.append(values[0])
            del h[:-2]
        if progress:
            progress(t + 1, T)
    return qpos


def rigid_transform_qpos(qpos: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Move whole poses by x -> R x + t (the root's position and orientation; joints are relative)."""
    out = qpos.copy()
    out[:, 0:3] = qpos[:, 0:3] @ R.T + t
    out[:, 3:7] = quat_multiply(matrix_to_quat(R)[None], qpos[:, 3:7])
    return out


def estimate_floor(body: BodyModel, qpos_camera_world: np.ndarray, camera: Camera, fps: float,
                   valid: np.ndarray) -> Floor:
    """Floor from the feet, in the camera frame, when no contact labels exist yet: the lowest sole point of
    each frame while it is slow, fitted robustly (Huber), regularised towards the body's mean vertical axis."""
    pose = kin.forward_kinematics(body, qpos_camera_world)
    pts = camera.to_camera(pose.points)
    soles = pts[:, body.point_index(CONTACT_POINTS)]  # (T, 4, 3)
    names = body.point_names
    body_up = (pts[:, names.index("neck")] - 0.5 * (pts[:, names.index("left_ankle")]
                                                     + pts[:, names.index("right_ankle")]))
    up = np.median(body_up[valid], axis=0)
    up /= np.linalg.norm(up)
    height = soles @ up
    lowest = height <= height.min(axis=1, keepdims=True) + 0.03
    speed = np.zeros(soles.shape[:2])
    speed[1:] = np.linalg.norm(np.diff(soles, axis=0), axis=2) * fps
    slow = speed <= np.nanpercentile(speed[valid], 50)
    chosen = lowest & slow & valid[:, None]
    if chosen.sum() < 8:
        chosen = lowest & valid[:, None]
    floor, inliers = fit_floor(soles[chosen], up)
    return floor


def fit_motion(obs: Observations, settings: Settings,
               progress: Callable[[int, int], None] | None = None) -> KinematicMotion:
    """Calibrate, fit (online or offline), find the floor, and express everything in the world frame."""
    start = time.perf_counter()
    calibration = calibrate(obs, settings.body.height, settings.body.calibration_frames)
    body = build_body_model(calibration.lengths, settings.body.mass)
    cam_settings = settings.camera
    camera = Camera.from_settings(obs.image_size, cam_settings.focal, cam_settings.fov,
                                  None if (cam_settings.focal or cam_settings.fov) else obs.camera_K)
    given_floor = None if cam_settings.floor is None else Floor.from_plane(cam_settings.floor)
    if given_floor is not None:  # fit directly in the final world
        first = int(np.argmax(obs.valid))
        guess = initial_qpos(body, camera, make_targets(obs, camera, calibration, settings), first)
        camera = camera.with_extrinsics(*world_from_floor(given_floor, camera.to_camera(guess[0, :3])))
    targets = make_targets(obs, camera, calibration, settings)
    fitter = KinematicFitter(body, camera, settings.fit, obs.fps)
    qpos = fit_online(fitter, targets, obs.valid, settings.fit.online_iterations, progress)
    if not settings.online:
        qpos = fitter.fit_offline(qpos, targets).qpos
    if settings.fit.one_euro:
        qpos = one_euro_qpos(body, qpos, obs.fps, settings.fit.one_euro_min_cutoff, settings.fit.one_euro_beta)
    if given_floor is None:
        floor = estimate_floor(body, qpos, camera, obs.fps, obs.valid)
        first = int(np.argmax(obs.valid))
        R_new, t_new = world_from_floor(floor, camera.to_camera(qpos[first, :3]))
        # world_old -> camera -> world_new
        to_new_R = R_new.T @ camera.R
        to_new_t = R_new.T @ (camera.t - t_new)
        qpos = rigid_transform_qpos(qpos, to_new_R, to_new_t)
        camera = camera.with_extrinsics(R_new, t_new)
    else:
        floor = given_floor
    error = reprojection_errors(body, camera, qpos, obs)
    return KinematicMotion(body, calibration, camera, floor, qpos, error, obs.valid.copy(),
                           time.perf_counter() - start, settings.online)


def reprojection_errors(body: BodyModel, camera: Camera, qpos: np.ndarray, obs: Observations,
                        min_confidence: float = 0.5) -> np.ndarray:
    """(T,) median pixel distance between projected markers and confident keypoints per frame."""
    from .fit import MARKERS

    pts = kin.forward_kinematics(body, qpos).points[:, body.point_index([b for _, b in MARKERS])]
    kp = obs.keypoints_2d[:, MARKER_LANDMARKS]
    dist = np.linalg.norm(camera.project(pts) - kp[..., :2], axis=-1)
    dist[kp[..., 2] < min_confidence] = np.nan
    dist[~obs.valid] = np.nan
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmedian(dist, axis=1)
