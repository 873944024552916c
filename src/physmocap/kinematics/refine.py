"""The kinematic optimisation before the trajectory optimisation (Rempe et al. 2020, 3.3 and B.3-B.4), on the
project's one kinematic fitter with its optional contact terms switched on:

0. contacts whose point slides along the floor in the kinematic stage's motion become no contact (ours);
1. the offline fit with contact velocity, joint velocity and joint-angle velocity terms (no floor term), from
   the kinematic stage's motion;
2. a robust (Huber) plane fit to the heel and toe positions labelled in contact; contacts farther than
   `floor_outlier_distance` from it become no contact; the world is moved onto the plane (z = 0); runs of
   frames labelled all in the air while the body does not fall get their points near the floor back in
   contact, and points resting on the floor are labelled in contact (ours);
3. the fit again with the floor term, which puts the feet in contact on the floor.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from typing import TYPE_CHECKING

import numpy as np

from ..body import kinematics as kin
from ..body.model import CONTACT_POINTS
from ..body.rotations import unwrap_rotation_vectors
from ..body.support import STEP_HEIGHT
from ..camera import WORLD_UP, Camera, Floor, tangent_basis
from ..config import FitSettings, TrajoptSettings
from ..detect.foot_swaps import find_foot_swaps, undo_foot_swaps
from ..motion import Observations, long_runs, valid_runs
from .fit import KinematicFitter
from .floor import move_world_to_floor
from .stage import KinematicMotion, hold_outside_valid, reprojection_errors
from .targets import landmark_depth_scale, make_targets, raw_depth, smooth_depth

if TYPE_CHECKING:
    from ..stages import ProgressFactory

log = logging.getLogger("physmocap")

MIN_FLOOR_POINTS = 8  # fewer contact points than this leave the floor as it was
SINK_PERCENTILE, SINK_DEPTH = 5.0, 0.03  # a refitted floor with 5% of all foot points 3 cm below it is rejected
HUBER_SCALE = 0.02  # m: contact points farther from the plane than this pull linearly (Huber)
# m: a joint step this much longer than the fit's (and twice it) is a joint turned through a half turn, not motion
# (validation and test: at most 0.03 m; the flips 0.28 and 0.71 m; docs/decisions/b4-rotation-wrap.md)
FLIP_STEP = 0.1
# s: the stretch solved again on either side of a flip, and the part of it blended into the first solution at each
# end (docs/decisions/b4-rotation-wrap.md)
FLIP_WINDOW, FLIP_BLEND = 1.0, 0.25


def tilt_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (3,) orthogonal to the unit vector `up` (camera frame) and to each other: `roll`, the
    camera's x axis made orthogonal to up (tilting the normal along it rolls the floor about the viewing
    direction), and `pitch` = up x roll (tilting along it turns the floor towards or away from the camera)."""
    roll = np.array([1.0, 0.0, 0.0]) - up[0] * up
    if np.linalg.norm(roll) < 0.1:  # up along the camera's x axis (a camera on its side)
        return tangent_basis(up)
    roll /= np.linalg.norm(roll)
    return roll, np.cross(up, roll)


def fit_contact_floor(points: np.ndarray, up_prior: np.ndarray, outlier_distance: float, roll_prior: float,
                      pitch_prior: float, iterations: int = 10) -> tuple[Floor, np.ndarray]:
    """Robust plane through the heel and toe positions labelled in contact (Rempe B.4): Huber weights by
    iteratively reweighted least squares on the points only, the tilt from `up_prior` penalised quadratically
    (a person standing still touches the floor along a line, which leaves the tilt to the prior), with weights
    `roll_prior` and `pitch_prior` (relative to one point at 1 m, per point) along the two axes of `tilt_axes`.
    points: (N, 3) camera frame; returns the floor (camera frame) and the (N,) inliers within outlier_distance.

    (camera.fit_floor passes its prior through the Huber loss too, where it pulls only linearly: measured, a
    wrongly labelled lifted foot tilted its plane by 30 degrees.)"""
    up = up_prior / np.linalg.norm(up_prior)
    a, b = tilt_axes(up)
    tilt, d = np.zeros(2), -float(np.median(points @ up))
    weights = np.ones(len(points))
    prior = np.sqrt(np.array([roll_prior, pitch_prior]) * len(points))
    for _ in range(iterations):
        n = up + tilt[0] * a + tilt[1] * b
        scale = np.linalg.norm(n)
        dist = (points @ n) / scale + d
        weights = np.minimum(1.0, HUBER_SCALE / np.maximum(np.abs(dist), 1e-12))
        # Linearised in (tilt, d): d dist / d tilt_k = (p . e_k) / |n| (the normalisation is second order).
        w = np.sqrt(weights)
        A = np.concatenate([np.stack([w * (points @ a), w * (points @ b), w], axis=1),
                            np.array([[prior[0], 0.0, 0.0], [0.0, prior[1], 0.0]])])
        rhs = np.concatenate([-w * dist, -prior * tilt])
        step = np.linalg.lstsq(A, rhs, rcond=None)[0]
        tilt, d = tilt + step[:2], d + step[2]
        if np.abs(step).max() < 1e-7:
            break
    n = up + tilt[0] * a + tilt[1] * b
    scale = np.linalg.norm(n)
    dist = np.abs(points @ (n / scale) + d)
    inliers = dist < outlier_distance
    return Floor(n / scale, float(d), float(inliers.mean())), inliers


@dataclasses.dataclass
class RefinedKinematics:
    """motion: the refined kinematic motion (world frame moved onto the refitted floor); contacts: (T, 4) the
    contact flags after relabelling; relabelled: (T, 4) flags removed (sliding points and the floor's outliers);
    added: (T, 4) flags added (see `false_flights` and `resting_points`); seconds."""

    motion: KinematicMotion
    contacts: np.ndarray
    relabelled: np.ndarray
    added: np.ndarray
    seconds: float


def false_flights(body, qpos: np.ndarray, fps: float, contacts: np.ndarray, valid: np.ndarray,
                  near_floor: float, outliers: np.ndarray | None = None, gravity: float = 9.81) -> np.ndarray:
    """(T, 4) contact flags to add where the labels have every point in the air but the kinematic COM does not
    fall freely: the parabola fitted to the COM height over such a run and its take-off and landing frames
    curves down by less than half of gravity (ours: a contact network's false flight makes the optimiser launch
    the body on a ballistic arc it never flew; the measure of contacts.flights.flight_support, whose curvature
    over all the frames reads a short run's flight where the velocities at its two ends, smoothed by the fit,
    did not: docs/decisions/refine-short-runs.md). Runs of fewer than 3 frames with their neighbours are left
    alone. The points within `near_floor` of the floor (z = 0) in those frames are marked in contact (but not
    points deeper than STEP_HEIGHT under it: lower ground, where a stair climber's feet stood); farther points are
    the floor's outliers, as for the labelled contacts (measured: a lowest point 13 cm up marked in contact put a
    jump's flight on the floor), except the labelled ones within STEP_HEIGHT of the floor that the floor dropped
    as its `outliers` (T, 4): where dropping them made the flight, the labels and the centre of mass agree that the
    body stands and only the fitted feet's height does not, which the next fit mends (a 12 fps video's last 5
    frames, the feet planted in the picture and fitted 7-10 cm up, were otherwise handed back kinematic and
    flagged). Labels farther up stand on something else: given back, a walk over a 0.3 m box was pulled down onto
    the floor, and the physics explained it."""
    pose = kin.forward_kinematics(body, qpos)
    com_height = kin.center_of_mass(body, pose)[:, 2]
    heights = pose.points[:, body.point_index(CONTACT_POINTS), 2]
    added = np.zeros_like(contacts, dtype=bool)
    airborne = ~contacts.any(axis=1) & valid
    T = len(qpos)
    for a, b in valid_runs(airborne):
        lo, hi = max(a - 1, 0), min(b + 1, T)
        if hi - lo < 3:
            continue
        fall = -2.0 * np.polyfit(np.arange(hi - lo) / fps, com_height[lo:hi], 2)[0] / gravity
        if fall < 0.5:
            added[a:b] = (heights[a:b] < near_floor) & (heights[a:b] > -STEP_HEIGHT)
            if outliers is not None:
                added[a:b] |= outliers[a:b] & (np.abs(heights[a:b]) < STEP_HEIGHT)
    return added


def floor_motion(body, qpos: np.ndarray, fps: float, interval: float) -> tuple[np.ndarray, np.ndarray]:
    """(T, 4) heights above the floor (z = 0) and (T, 4) speeds along it (m/s, over `interval` s centred on each
    frame) of the heel and toe points of the motion qpos (world on its floor, z up)."""
    points = kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)]
    half = max(1, int(round(0.5 * interval * fps)))
    frames = np.arange(len(points))
    behind, ahead = np.maximum(frames - half, 0), np.minimum(frames + half, len(points) - 1)
    step = points[ahead, :, :2] - points[behind, :, :2]
    return points[..., 2], np.linalg.norm(step, axis=-1) * fps / np.maximum(ahead - behind, 1)[:, None]


def slipping_contacts(body, qpos: np.ndarray, fps: float, contacts: np.ndarray,
                      settings: TrajoptSettings) -> np.ndarray:
    """(T, 4) contact flags whose point slides along the floor faster than `contact_slip_speed` in the kinematic
    motion qpos: a contact holds its point still (Rempe 3.2 labels under 0.6 m/s, physmocap's under 1.0), so such
    a flag is wrong, e.g. a hop labelled as standing, which no-slip would pin to the floor (ours)."""
    _, speed = floor_motion(body, qpos, fps, settings.contact_slip_interval)
    return contacts & (speed > settings.contact_slip_speed)


def resting_points(body, qpos: np.ndarray, fps: float, contacts: np.ndarray, valid: np.ndarray,
                   settings: TrajoptSettings) -> np.ndarray:
    """(T, 4) flags to add for points labelled in the air that rest on the floor in the kinematic motion qpos
    (world on its floor): below `rest_height` (a point under the floor is not in the air either, unless deeper than
    STEP_HEIGHT: lower ground) and slower than
    `rest_speed`, for at least
    `min_phase_seconds` (ours: a missed contact leaves the body on fewer supports than it stands on, and the
    optimiser moves it far from the observations to balance it there)."""
    height, speed = floor_motion(body, qpos, fps, settings.contact_slip_interval)
    resting = ((height < settings.rest_height) & (height > -STEP_HEIGHT) & (speed < settings.rest_speed)
               & valid[:, None])
    min_frames = max(1, math.ceil(settings.min_phase_seconds * fps - 1e-9))
    resting = np.stack([long_runs(resting[:, i], min_frames) for i in range(4)], axis=1)
    return resting & ~contacts


def added_contacts(body, qpos: np.ndarray, fps: float, contacts: np.ndarray, valid: np.ndarray,
                   settings: TrajoptSettings, outliers: np.ndarray | None = None) -> np.ndarray:
    """(T, 4) flags B.4 adds to the contacts (T, 4) kept on its floor, for the motion qpos (T, nq) on that floor
    (z = 0) at `fps`: the points of false flights (`false_flights`, with the labelled `outliers` (T, 4) that the
    floor dropped) that do not slide faster than settings.contact_slip_speed, which drops such a label, and, with
    settings.rest_height, the points resting on the floor (`resting_points`). Only on valid (T,) frames whose
    centre of mass lies above the floor: a body under it stands on another level (the ground beside the box the
    floor was found on), and contacts added there pulled it up to the floor, 80 px out of the picture
    (docs/decisions/refine-short-runs.md)."""
    on_this_floor = np.asarray(valid, bool) & (kin.center_of_mass(body, kin.forward_kinematics(body, qpos))[:, 2] > 0.0)
    added = false_flights(body, qpos, fps, contacts, on_this_floor, settings.floor_outlier_distance, outliers)
    if settings.contact_slip_speed > 0 and added.any():  # a run's low swinging foot (refine-short-runs.md)
        added &= ~slipping_contacts(body, qpos, fps, added, settings)
    if added.any():
        log.info("trajopt: %d frame(s) labelled all in the air while the body does not fall: contacts added.",
                 int(added.any(axis=1).sum()))
    if settings.rest_height > 0:
        added |= resting_points(body, qpos, fps, contacts | added, on_this_floor, settings)
    return added


def contact_fit_settings(fit: FitSettings, settings: TrajoptSettings, floor: bool) -> FitSettings:
    """The fit's settings with Rempe's optional terms at their trajopt weights (the floor term only if `floor`)."""
    return dataclasses.replace(fit, weight_contact_velocity=settings.kinematic_contact_velocity,
                               weight_velocity=settings.kinematic_velocity,
                               weight_angle_velocity=settings.kinematic_angle_velocity,
                               weight_com_acceleration=settings.kinematic_com_acceleration,
                               weight_floor=settings.kinematic_floor if floor else 0.0)


def fitted_observations(obs: Observations, motion: KinematicMotion, fit: FitSettings) -> Observations:
    """The observations as the offline kinematic stage corrected them before its fit: the detector's foot swaps
    undone (motion.foot_swaps, found again when a cached motion lacks them) and, with rescale_landmark_depth,
    its 3D landmarks' depth stretch undone against the fitted motion. Refitting the raw observations would bring
    both errors back (measured: 82 -> 138 mm global error on a synthetic walk)."""
    swaps = motion.foot_swaps
    if swaps is None:
        swaps = find_foot_swaps(obs) if fit.undo_foot_swaps else np.zeros(obs.num_frames, bool)
    obs = undo_foot_swaps(obs, swaps)
    if fit.rescale_landmark_depth:
        depth = smooth_depth(raw_depth(obs.keypoints_2d, obs.landmarks_3d, obs.valid, motion.camera.focal,
                                       motion.calibration, fit.min_confidence))
        targets = make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, depth, motion.camera,
                               motion.calibration, fit)
        scale = landmark_depth_scale(motion.body, motion.camera, motion.qpos, obs, targets, motion.calibration)
        obs = dataclasses.replace(obs, landmarks_3d=obs.landmarks_3d * np.stack(
            [np.ones_like(scale), np.ones_like(scale), 1.0 / scale], axis=1)[:, None])
    return obs


def _contact_floor(soles: np.ndarray, contacts: np.ndarray, valid: np.ndarray, camera: Camera, floor: Floor,
                   keep_floor: bool, settings: TrajoptSettings) -> tuple[Floor, np.ndarray]:
    """B.4's second step: the floor through the contact points `soles` (T, 4, 3, camera frame) unless
    keep_floor (or too few contacts, or it would sink the feet, deeper than `floor` does: then `floor`), and the
    contacts (T, 4) kept as its inliers. A kinematic floor that was not trusted (its feet's plane leant from the
    person's posture, kinematics.floor) is kept as well: the contacts are the same feet, and refitted through them
    the floor leant again, by 22 degrees on one video, while reporting itself trusted. The refitted floor keeps the
    kinematic one's confidence, source "contacts"."""
    kept = contacts.copy()
    if contacts.sum() >= MIN_FLOOR_POINTS:
        if not keep_floor and floor.trusted:
            fitted, _ = fit_contact_floor(soles[contacts], camera.R[:, 2], settings.floor_outlier_distance,
                                          settings.floor_roll_prior, settings.floor_pitch_prior)
            # A floor that many feet would sink through is made of wrong labels (feet labelled in contact in
            # the air): keep the kinematic stage's floor, fitted to the lowest slow foot points, instead, unless
            # the feet sink deeper through that one (a tilted kinematic floor; docs/decisions/refine-short-runs.md).
            sunk, kinematic_sunk = (np.percentile(f.height(soles[valid].reshape(-1, 3)), SINK_PERCENTILE)
                                    for f in (fitted, floor))
            if sunk > -SINK_DEPTH or sunk > kinematic_sunk:
                floor = dataclasses.replace(floor, normal=fitted.normal, offset=fitted.offset,
                                            inlier_fraction=fitted.inlier_fraction, source="contacts")
            else:
                log.info("trajopt: the floor through the labelled contacts lies above %.0f%% of the foot points "
                         "(by %.0f cm, the kinematic floor by %.0f); the kinematic floor is kept.", SINK_PERCENTILE,
                         -100 * sunk, -100 * kinematic_sunk)
        inliers = np.abs(floor.height(soles[contacts])) < settings.floor_outlier_distance
        kept[contacts] = inliers
    return floor, kept


def flipped_points(body, fitted: np.ndarray, refined: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T - 1, P) bool: per step between two valid frames (valid (T,)), the body's points that the refined poses
    (T, nq) move at least twice as far as the fitted poses (T, nq) move any point, and FLIP_STEP farther: where the
    refinement turned a joint through a half turn, its wrapped joint-angle velocity term counting a small turn as
    nearly 2 pi."""
    def steps(qpos):
        points = kin.forward_kinematics(body, qpos).points
        return np.linalg.norm(np.diff(points, axis=0), axis=-1)  # (T - 1, P)

    before, after = steps(fitted).max(axis=1, keepdims=True), steps(refined)
    valid = np.asarray(valid, bool)
    return (valid[1:] & valid[:-1])[:, None] & (after > 2.0 * before) & (after > before + FLIP_STEP)


def flipped_steps(body, fitted: np.ndarray, refined: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T - 1,) bool: the steps in which the refinement flipped some point (`flipped_points`)."""
    return flipped_points(body, fitted, refined, valid).any(axis=1)


def wrapping_joints(body, qpos: np.ndarray) -> np.ndarray:
    """(T - 1, J) bool: per step of the poses (T, nq), the ball joints (kin.tables(body).ball_bodies) whose rotation
    vector from rest, as the fit's joint-angle velocity term reads it (KinematicFitter._angle_signal), passes to
    another branch of the log (a turn through a half turn): there the wrapped term counts a step of up to 2 pi
    where the rotation's own is smaller."""
    rotvec = kin.ball_rotation_vectors(body, qpos)  # (T, J, 3)

    def steps(vectors: np.ndarray) -> np.ndarray:
        return np.linalg.norm(np.diff(vectors, axis=0), axis=-1)

    return steps(rotvec) > steps(unwrap_rotation_vectors(rotvec)) + 1e-6


def wrapped_flips(body, fitted: np.ndarray, refined: np.ndarray, flips: np.ndarray) -> np.ndarray:
    """(T - 1,) bool: the steps with a flipped point (flips, (T - 1, P) from `flipped_points`) moved by a ball joint
    that passes a half turn within a step of it, in the fitted or the refined poses (T, nq): the flips the wrapped
    joint-angle velocity term made, which solving again with the angles unwrapped can remove."""
    tab = kin.tables(body)
    wrapping = wrapping_joints(body, fitted) | wrapping_joints(body, refined)  # (T - 1, J)
    near = wrapping.copy()
    near[1:] |= wrapping[:-1]
    near[:-1] |= wrapping[1:]
    moves = body.ancestors[tab.point_body][:, tab.ball_bodies].astype(float)  # (P, J): the joint moves the point
    return ((flips.astype(float) @ moves) * near).any(axis=1)


def flip_windows(flips: np.ndarray, fps: float) -> list[tuple[int, int]]:
    """[(first, end)] frame ranges: FLIP_WINDOW seconds on either side of each flipped step (flips, (T - 1,) bool),
    overlapping ranges merged, within the clip."""
    reach, end = int(round(FLIP_WINDOW * fps)), len(flips) + 1
    windows: list[tuple[int, int]] = []
    for step in np.flatnonzero(flips).tolist():
        first, last = max(0, step - reach), min(end, step + 2 + reach)
        if windows and first <= windows[-1][1]:
            windows[-1] = (windows[-1][0], max(windows[-1][1], last))
        else:
            windows.append((first, last))
    return windows


def blend_window(body, qpos: np.ndarray, solved: np.ndarray, first: int, end: int, frames: int) -> np.ndarray:
    """qpos (T, nq) with frames first .. end - 1 replaced by `solved` (end - first, nq), blended on the manifold
    from qpos over `frames` frames at each end of the window that is not the clip's."""
    share = np.ones(end - first)
    ramp = np.arange(1, frames + 1) / (frames + 1)
    if first > 0:
        share[:frames] = np.minimum(share[:frames], ramp[:end - first])
    if end < len(qpos):
        share[-frames:] = np.minimum(share[-frames:], ramp[::-1][-(end - first):])
    out = qpos.copy()
    window = qpos[first:end]
    out[first:end] = kin.integrate(body, window, share[:, None] * kin.difference(body, window, solved))
    return out


def _solve_flips_again(body, motion: KinematicMotion, camera: Camera, on_floor, fit: FitSettings, fps: float,
                       qpos: np.ndarray, points: np.ndarray, flips: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """B.4's last fit (fit: its settings; on_floor: its targets) solved again with the joint angles unwrapped over
    each flip's window (`flip_windows`), from the fitted poses (motion, moved into the floor's world: camera), and
    blended into the first solution (qpos (T, nq)). A window is kept where it flips nothing but what the first
    solution flipped without a half turn (points, flips: `flipped_points`, `wrapped_flips`). The floor stays the
    first solution's, and so do the frames outside the windows."""
    fitted = kin.rigid_transform_qpos(motion.qpos, camera.R.T @ motion.camera.R,
                                      camera.R.T @ (motion.camera.t - camera.t))
    fitter = KinematicFitter(body, camera, fit, fps, unwrap_angles=True)
    allowed = points.any(axis=1) & ~flips  # flips the first solution has without a half turn
    blend = max(1, int(round(FLIP_BLEND * fps)))
    windows = flip_windows(flips, fps)
    repaired, failed = qpos, 0
    for first, end in windows:
        window = slice(first, end)
        solved = fitter.fit_offline(fitted[window], on_floor.frames(window)).qpos
        candidate = hold_outside_valid(blend_window(body, repaired, solved, first, end, blend), valid)
        if (flipped_steps(body, motion.qpos[window], candidate[window], valid[window])
                & ~allowed[first:end - 1]).any():
            failed += 1
        else:
            repaired = candidate
    frames = ", ".join(str(int(t)) for t in np.flatnonzero(flips)[:5])
    if failed:
        log.warning("trajopt: the refinement turned a joint through a half turn in one frame (after frames %s); "
                    "solved again there with the joint angles unwrapped, %d of %d stretches still flip and are "
                    "kept as first solved.", frames, failed, len(windows))
    else:
        log.info("trajopt: the refinement turned a joint through a half turn in one frame (after frames %s): "
                 "solved again there with the joint angles unwrapped.", frames)
    return repaired


def refine_kinematics(obs: Observations, motion: KinematicMotion, contacts: np.ndarray, fit: FitSettings,
                      settings: TrajoptSettings, keep_floor: bool = False,
                      progress: ProgressFactory | None = None) -> RefinedKinematics:
    """Rempe's three-stage kinematic optimisation (B.4) from an offline kinematic motion.

    obs: the detector's observations; motion: the kinematic stage's result (offline fit, world on its floor);
    contacts: (T, 4) bool flags (l heel, l toe, r heel, r toe) from the contact stage; fit: the fit's settings;
    settings: the trajopt settings (weights of the optional terms, outlier distance); keep_floor: keep
    motion.floor (e.g. a floor given by the user) instead of refitting it, still relabelling the contacts far
    from it. progress: a display for each of the two fits, "refine 1/2" and "refine 2/2", counted in frame passes
    (see KinematicFitter.fit_offline). Where the result flips a point in one frame (`flipped_points`) through a
    joint whose angles, or the fit's, pass a half turn there (`wrapped_flips`), the last fit is solved again with
    the joint angles unwrapped over FLIP_WINDOW seconds on either side, kept where it flips no more
    (`_solve_flips_again`). A flip elsewhere is not the wrapped angles' doing, and solving again unwrapped cannot
    remove it (docs/decisions/b4-rotation-wrap.md).
    """
    start = time.perf_counter()
    body, camera, fps = motion.body, motion.camera, obs.fps
    raw = obs
    obs = fitted_observations(obs, motion, fit)
    labelled = np.asarray(contacts, bool) & obs.valid[:, None]
    contacts = labelled
    if settings.contact_slip_speed > 0:
        contacts = labelled & ~slipping_contacts(body, motion.qpos, fps, labelled, settings)
    depth = smooth_depth(raw_depth(obs.keypoints_2d, obs.landmarks_3d, obs.valid, camera.focal, motion.calibration,
                                   fit.min_confidence))

    def targets_in(cam, flags, floor):  # the world is the floor's (z up) in both fits
        t = make_targets(obs.keypoints_2d, obs.landmarks_3d, obs.valid, depth, cam, motion.calibration, fit)
        return dataclasses.replace(t, contacts=flags.astype(float), floor=floor).with_free_fall(WORLD_UP, fps)

    def bar(fitter, name):
        return progress(name, fitter.planned_passes(obs.num_frames), "frame passes") if progress else None

    # 1. Contacts still, no floor.
    fitter = KinematicFitter(body, camera, contact_fit_settings(fit, settings, False), fps)
    qpos = fitter.fit_offline(motion.qpos, targets_in(camera, contacts, None), bar(fitter, "refine 1/2")).qpos
    # 2. The floor through the contact points (camera frame), outliers relabelled.
    soles = camera.to_camera(kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)])
    floor, kept = _contact_floor(soles, contacts, obs.valid, camera, motion.floor, keep_floor, settings)
    anchor = int(np.argmax(obs.valid))
    qpos, camera = move_world_to_floor(qpos, camera, floor, anchor)
    # Labels the floor dropped come back in false flights only on a trusted floor: on one levelled with the posture
    # against its feet, the feet's heights do not tell a wrong label (they pulled Pose2Sim cam03 15 mm off).
    given = added_contacts(body, qpos, fps, kept, obs.valid, settings, contacts & ~kept if floor.trusted else None)
    kept |= given
    removed, added = labelled & ~kept, given & ~labelled  # a dropped label given back is neither
    # 3. Again, with the feet in contact on the floor (z = 0 in the new world).
    on_floor_settings = contact_fit_settings(fit, settings, True)
    fitter = KinematicFitter(body, camera, on_floor_settings, fps)
    on_floor = targets_in(camera, kept, np.array([0.0, 0.0, 1.0, 0.0]))
    qpos = hold_outside_valid(fitter.fit_offline(qpos, on_floor, bar(fitter, "refine 2/2")).qpos, obs.valid)
    points = flipped_points(body, motion.qpos, qpos, obs.valid)
    if points.any():
        flips = wrapped_flips(body, motion.qpos, qpos, points)
        if flips.any():
            qpos = _solve_flips_again(body, motion, camera, on_floor, on_floor_settings, fps, qpos, points, flips,
                                      obs.valid)
        else:
            log.info("trajopt: the refinement moves a joint far in one frame (after frames %s), not through a half "
                     "turn: kept.", ", ".join(str(int(t)) for t in np.flatnonzero(points.any(axis=1))[:5]))
    seconds = time.perf_counter() - start
    refined = dataclasses.replace(motion, camera=camera, floor=floor, qpos=qpos,
                                  reprojection_error=reprojection_errors(body, camera, qpos, raw),
                                  valid=motion.valid.copy(), seconds=motion.seconds + seconds)
    return RefinedKinematics(refined, kept, removed, added, seconds)
