"""The floor under the fitted person: a plane through the feet pulled towards the person's own vertical posture,
with its confidence, and the motion re-expressed in the world whose z = 0 plane it is."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from ..body import kinematics as kin
from ..body.model import CONTACT_POINTS, BodyModel
from ..body.rotations import unit_vectors
from ..camera import Camera, Floor, angle_degrees, fit_floor, robust_offset, world_from_floor
from ..landmarks import LANDMARK_INDEX
from .fit import MARKERS

log = logging.getLogger("physmocap")

# The floor (estimate_floor; chosen on the validation clips of benchmarks/bench_floor_height.py, see
# docs/decisions/floor-posture-prior.md).
FLOOR_PRIOR_WEIGHT = 0.02  # fit_floor's pull towards the posture vertical (0.05 before the posture prior)
FEET_ONLY_PRIOR_WEIGHT = 0.002  # the same for the plane of the feet alone, against which the posture is checked
FLOOR_AGREEMENT = 10.0  # degrees: the feet's plane may lean this far from the posture before it is not trusted
FLOOR_BOOTSTRAP_DRAWS = 16
FLOOR_OUTLIER_DISTANCE = 0.10  # m: foot points farther from the floor are its outliers


def move_world_to_floor(qpos: np.ndarray, camera: Camera, floor: Floor, anchor_frame: int):
    """Re-express a motion in the world whose z = 0 plane is `floor` (camera frame), origin on the floor
    below the pelvis of `anchor_frame`. Returns (qpos, camera) in the new world."""
    R_new, t_new = world_from_floor(floor, camera.to_camera(qpos[anchor_frame, :3]))
    # old world -> camera -> new world
    qpos = kin.rigid_transform_qpos(qpos, R_new.T @ camera.R, R_new.T @ (camera.t - t_new))
    return qpos, camera.with_extrinsics(R_new, t_new)

def posture_vertical(body: BodyModel, qpos: np.ndarray, camera: Camera, valid: np.ndarray,
                     support: np.ndarray | None = None) -> np.ndarray:
    """(3,) the person's own vertical in the camera frame: per frame the unit axis from the support to the
    centre of mass, its median over the valid frames. The support is the middle of the sole points flagged in
    `support` (T, 4) on the frames that have any (`lowest_points`), else of all four. A body cannot keep its
    centre of mass away from above its support for long (it would fall), so over a clip this axis leans as
    little as the posture does, whichever way the person turns; the middle of all four leans with a runner,
    whose swinging foot trails behind (docs/decisions/refine-short-runs.md)."""
    pose = kin.forward_kinematics(body, qpos)
    com = camera.to_camera(kin.center_of_mass(body, pose))
    soles = camera.to_camera(pose.points[:, body.point_index(CONTACT_POINTS)])
    if support is None:
        support = np.ones(soles.shape[:2], bool)
    frames = valid & support.any(axis=1)
    middle = (soles * support[..., None]).sum(axis=1)[frames] / support.sum(axis=1)[frames, None]
    return unit_vectors(np.median(unit_vectors(com[frames] - middle), axis=0))


def lowest_points(soles: np.ndarray, up: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T, 4) per valid frame the sole points of soles (T, 4, 3) within 3 cm of the lowest along `up`."""
    height = soles @ up
    return (height <= height.min(axis=1, keepdims=True) + 0.03) & valid[:, None]


def seen_sole_points(keypoints_2d: np.ndarray, image_size: tuple[int, int], min_confidence: float) -> np.ndarray:
    """(T, 4) whether each sole point (CONTACT_POINTS) was seen: its keypoint in keypoints_2d (T, 33, 3: x, y px,
    confidence), or its ankle's where the detector gives it no confident one (COCO's 17 joints have no heel or
    toe), lies inside the picture of image_size (width, height) px with at least min_confidence. MediaPipe also
    places feet beyond the picture's edge, with confidences up to 0.9; the fit follows them, but where they are
    placed shows nothing of the floor."""
    landmark_of = {point: LANDMARK_INDEX[landmark] for landmark, point in MARKERS}
    points = keypoints_2d[:, [landmark_of[name] for name in CONTACT_POINTS]]
    ankles = keypoints_2d[:, [LANDMARK_INDEX[f"{name.split('_')[0]}_ankle"] for name in CONTACT_POINTS]]
    points = np.where((points[..., 2] >= min_confidence)[..., None], points, ankles)
    width, height = image_size
    inside = (points[..., 0] >= 0) & (points[..., 0] < width) & (points[..., 1] >= 0) & (points[..., 1] < height)
    return inside & (points[..., 2] >= min_confidence)


def floor_points(soles: np.ndarray, up: np.ndarray, fps: float, valid: np.ndarray,
                 seen: np.ndarray | None = None) -> np.ndarray:
    """(T, 4) the sole points of soles (T, 4, 3) that show the floor below `up`: the lowest (`lowest_points`)
    that were seen (`seen` (T, 4), None: all) while slower than the clip's median sole speed; the lowest seen
    alone where fewer than 8 are slow. A lowest point not seen is no evidence, and the other foot is not
    taken in its place: it may be the lifted one. Nor is a lone valid frame, between frames without a person:
    nothing measures its speed (on one video such a detection, 12 m behind the person, leant the floor 41
    degrees)."""
    lowest = lowest_points(soles, up, valid) & (True if seen is None else seen)
    neighbour = np.zeros_like(valid)
    neighbour[1:] |= valid[:-1]
    neighbour[:-1] |= valid[1:]
    speed = np.zeros(soles.shape[:2])
    speed[1:] = np.linalg.norm(np.diff(soles, axis=0), axis=2) * fps
    slow = (speed <= np.percentile(speed[valid], 50)) & neighbour[:, None]
    return lowest & slow if (lowest & slow).sum() >= 8 else lowest


def floor_tilt_spread(points: np.ndarray, frames: np.ndarray, up: np.ndarray, fitted: np.ndarray,
                      fps: float, draws: int = FLOOR_BOOTSTRAP_DRAWS, seed: int = 0) -> float:
    """Degrees, RMS angle to `fitted` of the normals that estimate_floor's fit finds on resamplings of the foot
    points (points (N, 3), camera frame; frames (N,) the frame of each) by blocks of one second (a still foot
    gives many nearly equal points, which are one piece of evidence, not many); 90 with under two blocks."""
    block = np.asarray(frames) // max(1, int(round(fps)))
    blocks = np.unique(block)
    if len(blocks) < 2:
        return 90.0
    rng = np.random.default_rng(seed)
    angles = []
    for _ in range(draws):
        sample = np.concatenate([points[block == b] for b in rng.choice(blocks, len(blocks))])
        angles.append(angle_degrees(fit_floor(sample, up, prior_weight=FLOOR_PRIOR_WEIGHT)[0].normal, fitted))
    return float(np.sqrt(np.mean(np.square(angles))))

def estimate_floor(body: BodyModel, qpos: np.ndarray, camera: Camera, fps: float, valid: np.ndarray,
                   seen: np.ndarray | None = None) -> Floor:
    """Floor from the feet and the person's posture, in the camera frame, when no contact labels exist yet.

    A robust (Huber) plane through the lowest sole point of each frame while it is slow and seen (`seen` (T, 4)
    from `seen_sole_points`; None: all are), its tilt pulled towards the person's own vertical
    (`posture_vertical`) with FLOOR_PRIOR_WEIGHT. Its confidence: the share of those points within
    FLOOR_OUTLIER_DISTANCE of it, the spread of its normal under a bootstrap over seconds (`floor_tilt_spread`),
    and the angle between the vertical and the plane the feet alone give (nearly free of the prior). Beyond
    FLOOR_AGREEMENT degrees the feet say something no posture explains (points taken from a lifted foot, a wrong
    depth) and the floor is not trusted: it is then level with the posture, through the same points, a warning
    is logged and Floor.trusted says so. Where no lowest sole point was ever seen, the fitted feet are all there
    is: the floor is fitted to them as if seen, and not trusted either (source "unseen feet")."""
    soles = camera.to_camera(kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)])
    # The support is the lowest points along the feet's own plane: the posture's first guess leans with a
    # runner, and the lowest points along it are then the trailing foot's.
    first = posture_vertical(body, qpos, camera, valid)
    first_points = floor_points(soles, first, fps, valid, seen)
    if seen is not None and not first_points.any():
        return _floor_of_unseen_feet(body, qpos, camera, fps, valid)
    feet_first, _ = fit_floor(soles[first_points], first, prior_weight=FEET_ONLY_PRIOR_WEIGHT)
    up = posture_vertical(body, qpos, camera, valid, lowest_points(soles, feet_first.normal, valid))
    chosen = floor_points(soles, up, fps, valid, seen)
    if seen is not None and not chosen.any():  # the seen points lie lowest along the first vertical only
        return _floor_of_unseen_feet(body, qpos, camera, fps, valid)
    points, frames = soles[chosen], np.nonzero(chosen)[0]
    floor, _ = fit_floor(points, up, prior_weight=FLOOR_PRIOR_WEIGHT)
    feet_only, _ = fit_floor(points, up, prior_weight=FEET_ONLY_PRIOR_WEIGHT)
    disagreement = angle_degrees(feet_only.normal, up)
    spread = floor_tilt_spread(points, frames, up, floor.normal, fps)
    if disagreement <= FLOOR_AGREEMENT:
        normal, offset, source, trusted = floor.normal, floor.offset, "feet and posture", True
    else:
        normal, offset, source, trusted = up, robust_offset(points, up), "posture", False
        log.warning("The floor through the feet is tilted %.0f degrees from the person's posture (more than %.0f): "
                    "it cannot be trusted, and the floor is taken level with the posture instead; give it with "
                    "--floor if it is known.", disagreement, FLOOR_AGREEMENT)
    inliers = float(np.mean(np.abs(points @ normal + offset) < FLOOR_OUTLIER_DISTANCE))
    return Floor(normal, offset, inliers, spread, disagreement, trusted, source)


def _floor_of_unseen_feet(body: BodyModel, qpos: np.ndarray, camera: Camera, fps: float, valid: np.ndarray) -> Floor:
    """estimate_floor's floor through the fitted feet as if they were seen, not trusted; a warning says why."""
    log.warning("The feet are outside the picture on every frame: the floor is fitted to where the fit placed them "
                "and cannot be trusted; give it with --floor if it is known.")
    return dataclasses.replace(estimate_floor(body, qpos, camera, fps, valid), trusted=False, source="unseen feet")
