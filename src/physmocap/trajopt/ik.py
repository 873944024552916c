"""Full-body motion from the optimised reduced motion (Rempe et al. 2020, C.4), by the kinematic fitter used as IK.

The upper body (and the pelvis) keeps its offsets from the COM of the input motion, added to the optimised COM
(turned by the change of orientation when `rotate_upper_body`); heels and toes go to their optimised positions;
knees and ankles follow from the IK, pulled to their input offsets too (`ik_leg_weight`, ours) so that they do
not swivel away. The fitter (kinematics.fit.KinematicFitter) runs with only its 3D term (pelvis-relative
targets), the pose prior and joint limits, and the joint-angle velocity term: the root starts at its target and
no term moves its translation, so the pelvis lands where the COM puts it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel
from ..body.rotations import matrix_to_quat, quat_multiply
from ..camera import Camera
from ..config import FitSettings, TrajoptSettings
from ..kinematics.fit import MARKERS, FitTargets, KinematicFitter
from .reduced import ReducedMotion, euler_to_matrix

# Knee and ankle markers (their weight is ik_leg_weight: the legs bend as the contact points require, the pull to
# where the input's knees and ankles sit relative to the COM settles the knees' swivel) and the markers sent to
# the optimised contact points.
FREE_MARKERS = ("left_knee", "right_knee", "left_ankle", "right_ankle")
FOOT_MARKERS = {"left_heel": 0, "left_toe": 1, "right_heel": 2, "right_toe": 3}  # model point -> CONTACT index


@dataclasses.dataclass
class IkTargets:
    """World targets of the IK: markers (T, M, 3) in MARKERS order, their weights (T, M), and the root pose
    to start from: qpos (T, nq)."""

    markers: np.ndarray
    weights: np.ndarray
    qpos: np.ndarray


def ik_targets(body: BodyModel, qpos_in: np.ndarray, reduced: ReducedMotion, com: np.ndarray, euler: np.ndarray,
               feet: np.ndarray, settings: TrajoptSettings, fitted_euler: np.ndarray | None = None) -> IkTargets:
    """Targets for frames (T) from the input motion qpos_in (T, nq), its reduced form, and the optimised COM
    (T, 3), orientation (T, 3) and contact points (T, 4, 3). The upper body turns by the optimised orientation's
    change from fitted_euler (T, 3), the fit stage's orientation (None: the input's): the root's own frame-to-frame
    noise, which the fit smooths away and the joints do not share, must not turn the whole upper body (120 fps:
    docs/decisions/trajopt-frame-rate.md)."""
    names = [b for _, b in MARKERS]
    points = kin.forward_kinematics(body, qpos_in).points
    markers_in = points[:, body.point_index(names)]
    turn = np.repeat(np.eye(3)[None], len(com), axis=0)
    if settings.rotate_upper_body:
        reference = reduced.rotation if fitted_euler is None else euler_to_matrix(fitted_euler)
        turn = euler_to_matrix(euler) @ reference.transpose(0, 2, 1)  # R(theta*) R(theta_fit)^T
    offsets = markers_in - reduced.com[:, None]
    markers = com[:, None] + np.einsum("tij,tmj->tmi", turn, offsets)
    weights = np.ones((len(com), len(names)))
    for name in FREE_MARKERS:
        weights[:, names.index(name)] = np.sqrt(settings.ik_leg_weight)
    for name, k in FOOT_MARKERS.items():
        markers[:, names.index(name)] = feet[:, k]
        weights[:, names.index(name)] = np.sqrt(settings.ik_feet_weight)
    # The root starts in place: pelvis at its target, orientation turned likewise.
    qpos = qpos_in.copy()
    pelvis_in = points[:, body.point_index(["pelvis"])[0]]
    qpos[:, 0:3] = com + np.einsum("tij,tj->ti", turn, pelvis_in - reduced.com)
    qpos[:, 3:7] = quat_multiply(matrix_to_quat(turn), qpos_in[:, 3:7])
    return IkTargets(markers, weights, qpos)


def solve_ik(body: BodyModel, targets: IkTargets, fps: float, settings: TrajoptSettings) -> np.ndarray:
    """qpos (T, nq) reaching the targets, by the kinematic fitter with its 3D term only."""
    fit = FitSettings(weight_2d=0.0, weight_3d=1.0, weight_smooth=0.0, weight_depth=0.0, robust_2d=0.0,
                      robust_3d=0.0, offline_iterations=settings.ik_iterations,
                      weight_angle_velocity=settings.kinematic_angle_velocity)
    camera = Camera.from_settings((1000, 1000))  # unused: no reprojection or depth term
    fitter = KinematicFitter(body, camera, fit, fps)
    T, M = targets.markers.shape[:2]
    pelvis = targets.qpos[:, 0:3]  # the root's position is the pelvis point (its joint centre)
    fit_targets = FitTargets(np.zeros((T, M, 2)), np.zeros((T, M)), targets.markers - pelvis[:, None],
                             targets.weights, np.ones(T))
    return fitter.fit_offline(targets.qpos, fit_targets).qpos
