"""Checks that settings and observations make sense together, before any fitting: a floor whose normal points
away from the person's up direction or lies far from their feet, keypoints far outside the image, a camera
matrix that cannot be one, offline physics asked of a single frame. A problem that would give garbage is refused
(SettingsError, InputError: one sentence); one the fit survives is returned as a warning sentence."""

from __future__ import annotations

import numpy as np

from .camera import Camera
from .config import Settings
from .errors import InputError, ReconstructionError, SettingsError
from .landmarks import LANDMARK_INDEX
from .motion import Observations

FLOOR_MAX_TILT_DEGREES = 60.0  # the floor's normal against the person's median up direction; 90: a vertical plane
FLOOR_MAX_DISTANCE = 1.5  # m: the median feet's distance from a given floor (a depth guess, accurate to ~0.3 m)
FAR_OUTSIDE = 1.0  # image sizes beyond the image's edge at which a keypoint is surely not in native pixels

_SHOULDERS = [LANDMARK_INDEX["left_shoulder"], LANDMARK_INDEX["right_shoulder"]]
_HIPS = [LANDMARK_INDEX["left_hip"], LANDMARK_INDEX["right_hip"]]
_ANKLES = [LANDMARK_INDEX["left_ankle"], LANDMARK_INDEX["right_ankle"]]


def check_observations(obs: Observations, settings: Settings, source: str) -> list[str]:
    """Refuse observations and settings that cannot give a sensible result; return warnings (sentences)."""
    if settings.refines_before_physics and obs.num_frames == 1:
        # the whole-clip refinement differentiates the motion; online physics tracks a single frame
        raise ReconstructionError(f"{source}: a single frame has no motion for physics to follow "
                                  "(capture it with --physics none).")
    camera = _camera(obs, settings, source)
    warnings = _check_keypoints(obs, source)
    if settings.camera.floor is not None:
        _check_floor(np.asarray(settings.camera.floor, float), obs, camera)
    return warnings


def _camera(obs: Observations, settings: Settings, source: str) -> Camera:
    if obs.camera_K is not None and not settings.camera.focal and not settings.camera.fov:
        K = obs.camera_K
        if not (np.isfinite(K).all() and K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1])):
            raise InputError(f"{source}: camera_K is not a camera matrix (positive focal lengths on the diagonal, "
                             f"last row 0 0 1): {np.round(K, 3).tolist()}.")
    return Camera.from_settings(obs.image_size, settings.camera.focal, settings.camera.fov,
                                None if (settings.camera.focal or settings.camera.fov) else obs.camera_K)


def _check_keypoints(obs: Observations, source: str) -> list[str]:
    """Refuse keypoints mostly far outside the image (another unit or image size); warn about a few."""
    size = np.asarray(obs.image_size, float)
    xy, confident = obs.keypoints_2d[..., :2], obs.keypoints_2d[..., 2] > 0
    far = confident & ((xy < -FAR_OUTSIDE * size) | (xy > (1 + FAR_OUTSIDE) * size)).any(axis=-1)
    if not far.any():
        return []
    if far.sum() > 0.5 * confident.sum():
        raise InputError(f"{source}: {100 * far.sum() / confident.sum():.0f}% of the seen keypoints lie more than "
                         f"an image size outside the {obs.image_size[0]}x{obs.image_size[1]} image (are they pixels "
                         "of the native image, and is image_size right?).")
    frames = np.flatnonzero(far.any(axis=1))
    return [f"{int(far.sum())} keypoints on {len(frames)} frames (first: {frames[0]}) lie more than an image size "
            "outside the image; the fit's robust weights discount them."]


def _person_up(obs: Observations) -> np.ndarray | None:
    """Unit vector from the hips to the shoulders in camera axes, the median over frames that see all four."""
    seen = obs.valid & (obs.keypoints_2d[:, _SHOULDERS + _HIPS, 2] > 0).all(axis=1)
    if not seen.any():
        return None
    up = np.median(obs.landmarks_3d[seen][:, _SHOULDERS].mean(axis=1) - obs.landmarks_3d[seen][:, _HIPS].mean(axis=1),
                   axis=0)
    norm = np.linalg.norm(up)
    return up / norm if norm > 1e-6 else None


def _feet_in_camera(obs: Observations, camera: Camera) -> np.ndarray | None:
    """(N, 3) rough ankle midpoints in the camera frame, metres: the depth from the ratio of the trunk-and-leg
    length in the 3D landmarks to its length in pixels (a pinhole guess, good to ~20%)."""
    ids = _SHOULDERS + _HIPS + _ANKLES
    seen = obs.valid & (obs.keypoints_2d[:, ids, 2] > 0).all(axis=1)
    if not seen.any():
        return None
    k2, k3 = obs.keypoints_2d[seen, :, :2], obs.landmarks_3d[seen]

    def chain(points):
        shoulders, hips, ankles = (points[:, group].mean(axis=1) for group in (_SHOULDERS, _HIPS, _ANKLES))
        return np.linalg.norm(shoulders - hips, axis=-1) + np.linalg.norm(hips - ankles, axis=-1), ankles

    metres, _ = chain(k3)
    pixels, ankles_px = chain(k2)
    usable = (pixels > 1.0) & (metres > 0.1)
    if not usable.any():
        return None
    depth = camera.focal * metres[usable] / pixels[usable]
    rays = np.c_[ankles_px[usable], np.ones(usable.sum())] @ np.linalg.inv(camera.K).T
    return rays * depth[:, None]


def _check_floor(plane: np.ndarray, obs: Observations, camera: Camera) -> None:
    norm = np.linalg.norm(plane[:3])
    normal, offset = plane[:3] / norm, plane[3] / norm
    given = ",".join(f"{x:g}" for x in plane)
    up = _person_up(obs)
    if up is not None:
        tilt = float(np.degrees(np.arccos(np.clip(normal @ up, -1.0, 1.0))))
        if tilt > 90.0:
            flipped = ",".join(f"{0.0 - x:g}" for x in plane)
            raise SettingsError(f"--floor {given}: its normal points {tilt:.0f} degrees away from the person's up "
                                f"direction, so the world would be upside down (the same plane with its normal up "
                                f"is {flipped}).")
        if tilt > FLOOR_MAX_TILT_DEGREES:
            raise SettingsError(f"--floor {given}: the plane is tilted {tilt:.0f} degrees from the person's up "
                                "direction (a wall rather than a floor?).")
    feet = _feet_in_camera(obs, camera)
    if feet is not None:
        distance = float(np.median(feet @ normal + offset))
        if abs(distance) > FLOOR_MAX_DISTANCE:
            raise SettingsError(f"--floor {given}: the person's feet are about {abs(distance):.1f} m "
                                f"{'above' if distance > 0 else 'below'} this plane (more than "
                                f"{FLOOR_MAX_DISTANCE:g} m): its offset or the camera's focal length is wrong.")
