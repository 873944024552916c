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
from ..body.model import CONTACT_POINTS, BodyModel, SkeletonLengths, build_body_model
from ..camera import Camera, Floor, angle_degrees, fit_floor, robust_offset, world_from_floor
from ..config import FitSettings, Settings
from ..detect.foot_swaps import find_foot_swaps, undo_foot_swaps
from ..errors import ReconstructionError
from ..motion import Observations
from .calibration import Calibration, calibrate, plausible_length, resolve_height
from .filters import one_euro_qpos
from .fit import MARKER_LANDMARKS, MARKERS, FitTargets, KinematicFitter

if TYPE_CHECKING:
    from ..stages import ProgressFactory

log = logging.getLogger("physmocap")

# The floor (estimate_floor; chosen on the validation clips of benchmarks/bench_floor_height.py, see
# docs/decisions/floor-posture-prior.md).
FLOOR_PRIOR_WEIGHT = 0.02  # fit_floor's pull towards the posture vertical (0.05 before the posture prior)
FEET_ONLY_PRIOR_WEIGHT = 0.002  # the same for the plane of the feet alone, against which the posture is checked
FLOOR_AGREEMENT = 10.0  # degrees: the feet's plane may lean this far from the posture before it is not trusted
FLOOR_BOOTSTRAP_DRAWS = 16
FLOOR_OUTLIER_DISTANCE = 0.10  # m: foot points farther from the floor are its outliers

# Lengths the offline fit measures again against its first fit (refine_lengths), in the order they are solved for.
REFINED_LENGTHS = ("thigh", "shank", "upper_arm", "forearm", "heel_back", "toe_front", "ankle_height")

# The markers on the hand itself (pinky and index knuckles): they only turn the hand (FitSettings.hand_weight).
HAND_MARKERS = np.array([a in {f"{side}_{part}" for side in ("left", "right") for part in ("pinky", "index")}
                         for a, _ in MARKERS])


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
        return dict(qpos=self.qpos, lengths=np.str_(json.dumps(self.body.lengths.__dict__)),
                    mass=np.float64(self.body.mass), camera_K=self.camera.K, camera_R=self.camera.R,
                    camera_t=self.camera.t, image_size=np.array(self.camera.image_size), floor=self.floor.plane,
                    floor_inliers=np.float64(self.floor.inlier_fraction),
                    reprojection_error=np.full(T, np.nan) if self.reprojection_error is None
                    else self.reprojection_error, valid=self.valid, seconds=np.float64(self.seconds),
                    online=np.bool_(self.online), landmark_scale=np.float64(self.calibration.landmark_scale),
                    frames_used=np.int64(self.calibration.frames_used),
                    replaced=np.array(self.calibration.replaced, dtype=str),
                    foot_swaps=np.zeros(T, bool) if self.foot_swaps is None else np.asarray(self.foot_swaps, bool),
                    height=np.float64(self.calibration.height),
                    detector_height=np.float64(self.calibration.detector_height),
                    height_source=np.str_(self.calibration.height_source),
                    floor_tilt_spread=np.float64(self.floor.tilt_spread),
                    floor_prior_disagreement=np.float64(self.floor.prior_disagreement),
                    floor_trusted=np.bool_(self.floor.trusted), floor_source=np.str_(self.floor.source))

    @classmethod
    def from_arrays(cls, arrays) -> "KinematicMotion":
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


def make_targets(keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: np.ndarray, depth: np.ndarray,
                 camera: Camera, calibration: Calibration, fit: FitSettings) -> FitTargets:
    """Per-frame observations (T, 33, 3) -> what the fit pulls towards, in the camera's world frame. Landmarks
    the detector did not see (confidence 0, or not finite) weigh nothing in either term."""
    kp = keypoints_2d[:, MARKER_LANDMARKS]
    landmarks = landmarks_3d[:, MARKER_LANDMARKS]
    seen = (kp[..., 2] > 0) & np.isfinite(kp).all(axis=2) & np.isfinite(landmarks).all(axis=2) & valid[:, None]
    conf = np.where(seen & (kp[..., 2] >= fit.min_confidence), kp[..., 2], 0.0)
    kp = np.where(seen[..., None], kp, 0.0)
    targets_3d = (np.where(seen[..., None], landmarks, 0.0) * calibration.landmark_scale) @ camera.R  # camera -> world
    # A seen but doubtful landmark keeps some 3D weight: the 3D term holds the pose where the 2D term lets go.
    weight_3d = np.sqrt(fit.weight_3d) * seen * np.sqrt(np.clip(kp[..., 2], 0.3, 1.0))
    marker = np.where(HAND_MARKERS, np.sqrt(fit.hand_weight), 1.0)
    return FitTargets(kp[..., :2], np.sqrt(fit.weight_2d * conf) * marker, targets_3d, weight_3d * marker, depth)


def raw_depth(keypoints_2d: np.ndarray, landmarks_3d: np.ndarray, valid: np.ndarray, focal: float,
              calibration: Calibration, min_confidence: float) -> np.ndarray:
    """(T,) the person's distance by similar triangles: the spread of the metric skeleton across the image
    plane against its spread in pixels; nan where a frame shows too little."""
    kp = keypoints_2d[:, MARKER_LANDMARKS]
    conf = np.where(kp[..., 2] >= min_confidence, kp[..., 2], 0.0) * valid[:, None]
    rel = landmarks_3d[:, MARKER_LANDMARKS, :2] * calibration.landmark_scale
    spread_3d = np.sqrt(np.sum(conf * np.sum((rel - _weighted_mean(rel, conf)) ** 2, -1), 1))
    spread_2d = np.sqrt(np.sum(conf * np.sum((kp[..., :2] - _weighted_mean(kp[..., :2], conf)) ** 2, -1), 1))
    with np.errstate(all="ignore"):
        return np.where(valid & (spread_2d > 1e-6), focal * spread_3d / spread_2d, np.nan)


def _weighted_mean(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    return (np.sum(x * w[..., None], axis=1) / np.maximum(w.sum(axis=1), 1e-9)[:, None])[:, None]


def landmark_depth_scale(body: BodyModel, camera: Camera, qpos: np.ndarray, obs: Observations,
                         targets: FitTargets, calibration: Calibration, width: int = 5) -> np.ndarray:
    """(T,) per frame, how much the detector stretched its 3D landmarks along the camera axis against the
    fitted skeleton (MediaPipe's depth is the least certain: about 0.66 of the truth on average and +-18% from
    frame to frame): weighted least squares of the detector's hip-relative depths onto the fitted ones, pulled
    towards the clip's own value where a frame shows little depth, then a centred running median of `width`.
    The fitted depths come from the bone lengths and the 2D keypoints as much as from those landmarks."""
    pts = kin.forward_kinematics(body, qpos).points
    relative = (pts[:, body.point_index([b for _, b in MARKERS])] - pts[:, body.point_index(["pelvis"])]) @ camera.R.T
    fitted = relative[..., 2]
    seen = obs.landmarks_3d[:, MARKER_LANDMARKS, 2] * calibration.landmark_scale
    w = targets.weight_3d**2
    clip_scale = np.sum(w * fitted * seen) / max(np.sum(w * seen**2), 1e-12)
    prior = 0.05**2 * np.mean(np.sum(w, axis=1))  # as much as a frame whose landmarks are all 5 cm deep
    per_frame = (np.sum(w * fitted * seen, axis=1) + prior * clip_scale) / (np.sum(w * seen**2, axis=1) + prior)
    return 1.0 / np.clip(smooth_depth(per_frame, width), 0.4, 2.5)


def refine_lengths(body: BodyModel, camera: Camera, qpos: np.ndarray, targets: FitTargets,
                   calibration: Calibration, height: float) -> Calibration:
    """The limbs' and feet's lengths (REFINED_LENGTHS) measured again against a fitted motion, the skeleton then
    scaled to `height` again.

    Each observed offset between two landmarks (hip to knee, ankle to heel, ...) is, in the model, a sum of
    lengths along axes the fit has found (the thigh's direction; the foot's forward and down axes): linear in the
    lengths once the axes are held. They are solved for by weighted least squares over all frames and both
    sides, with the data terms' own residuals (the 3D landmarks' offsets; the keypoints' offsets through the
    projection's derivative at the segment, in metres at the person) and weights (the product of the two ends').
    The calibration's median distance between two noisy landmarks is too long by about the noise variance across
    the segment over its length (synthetic set, MediaPipe's measured noise: upper arm +8 mm, forearm +7 mm; the
    ankle's height above the sole by 27%, so the calibration takes that from the template); along an axis that
    the fit took from all the data, noise across the segment does not count. Implausible results keep the
    calibration's value."""
    points = kin.forward_kinematics(body, qpos).points
    marker = {b: i for i, (_, b) in enumerate(MARKERS)}
    index = {name: k for k, name in enumerate(REFINED_LENGTHS)}
    n = len(REFINED_LENGTHS)
    normal, rhs = np.zeros((n, n)), np.zeros(n)
    metres_per_pixel = (targets.depth / camera.focal)[:, None, None]
    for side in ("left", "right"):
        def point(name):
            return points[:, body.point_index([f"{side}_{name}"])[0]]

        forward = _unit(point("toe") - point("heel"))
        heel = point("heel") - point("ankle")
        down = _unit(heel - np.einsum("ti,ti->t", heel, forward)[:, None] * forward)
        offsets = [(first, second, [(name, _unit(point(second) - point(first)))]) for name, first, second in (
            ("thigh", "hip", "knee"), ("shank", "knee", "ankle"), ("upper_arm", "shoulder", "elbow"),
            ("forearm", "elbow", "wrist"))]
        offsets += [("ankle", "heel", [("heel_back", -forward), ("ankle_height", down)]),
                    ("ankle", "toe", [("toe_front", forward), ("ankle_height", down)])]
        for first, second, terms in offsets:
            a, b = marker[f"{side}_{first}"], marker[f"{side}_{second}"]
            cols = [index[name] for name, _ in terms]
            axes = np.stack([axis for _, axis in terms], axis=1)  # (T, k, 3)
            seen = targets.targets_3d[:, b] - targets.targets_3d[:, a]
            # Each axis in the image: pixels per metre at the segment's middle, times metres per pixel.
            jac = camera.projection_jacobian(0.5 * (point(first) + point(second)))  # (T, 2, 3)
            pixels = np.einsum("tij,tkj->tki", jac, axes) * metres_per_pixel
            rows = [(targets.weight_3d[:, a] * targets.weight_3d[:, b], axes, seen),
                    (targets.weight_2d[:, a] * targets.weight_2d[:, b], pixels,
                     (targets.keypoints[:, b] - targets.keypoints[:, a]) * metres_per_pixel[:, 0])]
            for weight, model, observed in rows:
                normal[np.ix_(cols, cols)] += np.einsum("t,tki,tli->kl", weight, model, model)
                rhs[cols] += np.einsum("t,tki,ti->k", weight, model, observed)
    values, replaced = dict(calibration.lengths.__dict__), set(calibration.replaced)
    try:
        solved = np.linalg.solve(normal, rhs)
    except np.linalg.LinAlgError:
        return calibration
    for name, value in zip(REFINED_LENGTHS, solved):
        if plausible_length(name, value / height):
            values[name] = float(value)
            replaced.discard(name)
    lengths = SkeletonLengths(**values)
    return dataclasses.replace(calibration, lengths=lengths.scaled(height / lengths.standing_height),
                               replaced=tuple(n for n in calibration.replaced if n in replaced))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def smooth_depth(depth: np.ndarray, width: int = 9) -> np.ndarray:
    """Centred running median; gaps take their neighbours' values. ReconstructionError without a finite value."""
    good = np.isfinite(depth)
    if not good.any():
        raise ReconstructionError("no frame shows enough of the person with enough confidence to place them in "
                                  "depth.")
    filled = np.interp(np.arange(len(depth)), np.flatnonzero(good), depth[good])
    pad = width // 2
    padded = np.pad(filled, pad, mode="edge")
    return np.median(np.lib.stride_tricks.sliding_window_view(padded, width), axis=1)


def move_world_to_floor(qpos: np.ndarray, camera: Camera, floor: Floor, anchor_frame: int):
    """Re-express a motion in the world whose z = 0 plane is `floor` (camera frame), origin on the floor
    below the pelvis of `anchor_frame`. Returns (qpos, camera) in the new world."""
    R_new, t_new = world_from_floor(floor, camera.to_camera(qpos[anchor_frame, :3]))
    # old world -> camera -> new world
    qpos = kin.rigid_transform_qpos(qpos, R_new.T @ camera.R, R_new.T @ (camera.t - t_new))
    return qpos, camera.with_extrinsics(R_new, t_new)


def posture_vertical(body: BodyModel, qpos: np.ndarray, camera: Camera, valid: np.ndarray) -> np.ndarray:
    """(3,) the person's own vertical in the camera frame: per frame the unit axis from the middle of the four
    sole points to the centre of mass, its median over the valid frames. A body cannot keep its centre of mass
    away from above its support for long (it would fall), so over a clip this axis leans as little as the
    posture does, whichever way the person turns."""
    pose = kin.forward_kinematics(body, qpos)
    com = camera.to_camera(kin.center_of_mass(body, pose))
    soles = camera.to_camera(pose.points[:, body.point_index(CONTACT_POINTS)])
    return _unit(np.median(_unit(com - soles.mean(axis=1))[valid], axis=0))


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


def estimate_floor(body: BodyModel, qpos: np.ndarray, camera: Camera, fps: float, valid: np.ndarray) -> Floor:
    """Floor from the feet and the person's posture, in the camera frame, when no contact labels exist yet.

    A robust (Huber) plane through the lowest sole point of each frame while it is slow, its tilt pulled
    towards the person's own vertical (`posture_vertical`) with FLOOR_PRIOR_WEIGHT. Its confidence: the share of
    those points within FLOOR_OUTLIER_DISTANCE of it, the spread of its normal under a bootstrap over seconds
    (`floor_tilt_spread`), and the angle between the vertical and the plane the feet alone give (nearly free of
    the prior). Beyond FLOOR_AGREEMENT degrees the feet say something no posture explains (points taken from a
    lifted foot, a wrong depth) and the floor is not trusted: it is then level with the posture, through the
    same points, a warning is logged and Floor.trusted says so."""
    pts = camera.to_camera(kin.forward_kinematics(body, qpos).points)
    up = posture_vertical(body, qpos, camera, valid)
    soles = pts[:, body.point_index(CONTACT_POINTS)]  # (T, 4, 3)
    height = soles @ up
    lowest = height <= height.min(axis=1, keepdims=True) + 0.03
    speed = np.zeros(soles.shape[:2])
    speed[1:] = np.linalg.norm(np.diff(soles, axis=0), axis=2) * fps
    slow = speed <= np.percentile(speed[valid], 50)
    chosen = lowest & slow & valid[:, None]
    if chosen.sum() < 8:
        chosen = lowest & valid[:, None]
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
    from .online import OnlineFitter

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
    swaps = np.zeros(obs.num_frames, dtype=bool)
    swaps[online.foot_swap_frames] = True
    return KinematicMotion(online.body, online.calibration, online.camera, online.floor, qpos, None,
                           obs.valid.copy(), 0.0, True, swaps)


def _fit_offline(obs: Observations, settings: Settings, progress: ProgressFactory | None) -> KinematicMotion:
    from .online import fit_streams

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
             else estimate_floor(body, qpos, camera, obs.fps, obs.valid))
    qpos, camera = move_world_to_floor(qpos, camera, floor, int(np.argmax(obs.valid)))
    return KinematicMotion(body, calibration, camera, floor, qpos, None, obs.valid.copy(), 0.0, False, swaps)


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
