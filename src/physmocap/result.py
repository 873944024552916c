"""The `result.npz` contract (DESIGN.md "The result file"): assembling, saving and loading it."""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .body import kinematics as kin
from .body.model import (
    CONTACT_POINTS,
    JOINT_NAMES,
    LANDMARK_POINTS,
    BodyModel,
    SkeletonLengths,
    build_body_model,
    template_lengths,
)
from .body.rotations import is_rotation
from .dynamics.stage import PhysicsMotion
from .errors import InputError
from .io.atomic import read_npz, save_npz
from .io.finite import finite_result
from .kinematics.stage import KinematicMotion, reprojection_errors
from .landmarks import NUM_LANDMARKS
from .motion import Observations

if TYPE_CHECKING:
    from .trajopt.stage import TrajoptMotion

RESULT_POINTS: tuple[str, ...] = JOINT_NAMES + LANDMARK_POINTS

REQUIRED_KEYS = (
    "fps", "joint_names", "joints_world", "joints_world_kinematic", "qpos", "contacts", "stationary", "grf",
    "residual_root_force", "camera_K", "camera_R", "camera_t", "floor", "keypoints_2d", "valid", "body_mass",
    "body_height", "stage_seconds", "settings",
)


def person_height_pixels(motion: KinematicMotion) -> np.ndarray:
    """(T,) the person's standing height as it would appear in the image at their distance, pixels."""
    pelvis_depth = motion.camera.to_camera(motion.qpos[:, 0:3])[:, 2]
    return motion.camera.focal * motion.body.height / np.maximum(pelvis_depth, 1e-6)


def build_result(obs: Observations, motion: KinematicMotion, stage_seconds: dict[str, float],
                 settings: dict, contacts: np.ndarray, stationary: np.ndarray,
                 physics: PhysicsMotion | TrajoptMotion | None = None, predicted: np.ndarray | None = None,
                 physics_method: str = "physcap") -> dict[str, np.ndarray]:
    """All arrays of result.npz. `contacts`: the flags after foot-lock; `predicted`: the contact network's
    (default: the same). Without physics the final motion is the kinematic one and the force keys are zeros;
    with physics, `contacts` become the flags the physics used. Per-run numbers and texts are 0-d arrays, as
    load_result reads them back."""
    body, T = motion.body, len(motion.qpos)
    unexplained = None if physics is None else physics.unexplained
    points = body.point_index(RESULT_POINTS)
    kinematic = kin.forward_kinematics(body, motion.qpos).points[:, points]
    final = kinematic if physics is None else kin.forward_kinematics(body, physics.qpos).points[:, points]
    final_reprojection = (motion.reprojection_error if physics is None
                          else reprojection_errors(body, motion.camera, physics.qpos, obs))
    return dict(
        fps=np.array(obs.fps, dtype=np.float64),
        joint_names=np.array(RESULT_POINTS),
        joints_world=final,
        joints_world_kinematic=kinematic,
        qpos=motion.qpos if physics is None else physics.qpos,
        qpos_kinematic=motion.qpos,
        contact_names=np.array(CONTACT_POINTS),
        contacts=contacts if physics is None else physics.contacts,
        contacts_predicted=contacts if predicted is None else predicted,
        stationary=stationary,
        grf=np.zeros((T, 4, 3)) if physics is None else physics.grf,
        residual_root_force=np.zeros((T, 6)) if physics is None else physics.residual,
        physics=np.array("none" if physics is None else physics_method),
        physics_fallback=np.zeros(T, bool) if physics is None else physics.qp_failures > 0,
        # frames the physics' contact model could not explain (hands or a raised floor carrying the body, the body
        # resting on a knee, an elbow or the seat, a force over PhysicsSettings.max_force, a failed solver; for
        # trajopt an input COM below the floor): the final
        # motion there is the kinematic one (PhysCap blends in and out over PhysicsSettings.unexplained_blend_offline,
        # online over unexplained_blend)
        physics_unexplained=np.zeros(T, bool) if unexplained is None else np.asarray(unexplained, bool),
        balance_corrected=np.zeros(T, bool) if physics is None else physics.corrected,
        camera_K=motion.camera.K,
        camera_R=motion.camera.R,
        camera_t=motion.camera.t,
        image_size=np.array(obs.image_size),
        floor=motion.floor.plane,
        # False: the floor is level with the posture, not the feet
        floor_trusted=np.array(motion.floor.trusted, dtype=bool),
        floor_confidence=np.array(json.dumps(motion.floor.confidence())),
        body_height_source=np.array(motion.calibration.height_source),  # "given" (default 1.70 m too) or "estimated"
        keypoints_2d=obs.keypoints_2d,
        # frames showing the picture of the frame before again (detect/repeats.py); offline, their detections are
        # interpolated between the new pictures around them
        repeated_picture=np.asarray(obs.repeated, bool),
        valid=motion.valid,
        invalid_reason=np.asarray(obs.invalid_reason, dtype=str),
        reprojection_error=motion.reprojection_error,
        reprojection_error_final=final_reprojection,
        physics_deviation=np.linalg.norm(final - kinematic, axis=-1).mean(axis=1),
        person_height_px=person_height_pixels(motion),
        body_mass=np.array(body.mass, dtype=np.float64),
        body_height=np.array(body.height, dtype=np.float64),
        body_lengths=np.array(json.dumps(body.lengths.__dict__)),
        stage_seconds=np.array(json.dumps(stage_seconds)),
        settings=np.array(json.dumps(settings)),
    )


def save_result(path: str | os.PathLike, result: dict[str, np.ndarray]) -> None:
    """Write result.npz atomically with every number finite: per-frame motion arrays as io.finite blanks them
    (the frames named in a warning); the reprojection errors 0 where they could not be measured (no confident
    keypoint, e.g. a frame without a person), which `reprojection_measured` marks; unseen keypoints (non-finite)
    as (0, 0) with confidence 0."""
    out = finite_result(result, str(path))
    if "reprojection_error" in out:
        measured = np.isfinite(np.asarray(out["reprojection_error"], dtype=float))
        if "reprojection_error_final" in out:
            measured &= np.isfinite(np.asarray(out["reprojection_error_final"], dtype=float))
            out["reprojection_error_final"] = np.where(measured, out["reprojection_error_final"], 0.0)
        out["reprojection_error"] = np.where(measured, out["reprojection_error"], 0.0)
        out["reprojection_measured"] = measured
    if "keypoints_2d" in out:
        keypoints = np.array(out["keypoints_2d"], dtype=float)
        unseen = ~np.isfinite(keypoints).all(axis=-1)
        keypoints[unseen] = 0.0
        out["keypoints_2d"] = keypoints
    save_npz(path, **out)


# The numeric arrays a reader relies on, by shape: T frames, J points (joint_names), Q = the body's qpos width;
# () a scalar. Optional keys are checked where present.
RESULT_SHAPES: dict[str, tuple] = {
    "fps": (), "body_mass": (), "body_height": (), "joints_world": ("T", "J", 3),
    "joints_world_kinematic": ("T", "J", 3), "qpos": ("T", "Q"), "qpos_kinematic": ("T", "Q"),
    "contacts": ("T", 4), "contacts_predicted": ("T", 4),
    "stationary": ("T",), "grf": ("T", 4, 3), "residual_root_force": ("T", 6), "camera_K": (3, 3),
    "camera_R": (3, 3), "camera_t": (3,), "floor": (4,), "keypoints_2d": ("T", NUM_LANDMARKS, 3), "valid": ("T",),
    "physics_unexplained": ("T",), "physics_fallback": ("T",), "physics_deviation": ("T",),
    "balance_corrected": ("T",), "repeated_picture": ("T",), "reprojection_error": ("T",),
    "reprojection_error_final": ("T",), "reprojection_measured": ("T",), "person_height_px": ("T",),
}
POSITIVE_SCALARS = ("fps", "body_mass", "body_height")
UNIT_TOLERANCE = 1e-3  # of qpos's quaternions, camera_R, the floor's normal, body_height; a capture's are within 1e-12


def _checked_lengths(path: Path, text: np.ndarray) -> SkeletonLengths:
    """body_lengths: a JSON object of every SkeletonLengths field, in finite metres (export rebuilds the body)."""
    fields = set(SkeletonLengths.__dataclass_fields__)
    try:
        lengths = json.loads(str(text))
    except ValueError:
        lengths = None
    if not (isinstance(lengths, dict) and set(lengths) == fields
            and all(isinstance(v, (int, float)) and np.isfinite(v) for v in lengths.values())):
        raise InputError(f"{path}: body_lengths must be a JSON object of the skeleton's {len(fields)} lengths in "
                         "metres, as a capture writes it.")
    return SkeletonLengths(**lengths)


@functools.cache
def _template_body() -> BodyModel:
    """The qpos layout of every result: each body has the template's joints (its lengths move no coordinate)."""
    return build_body_model(template_lengths())


def load_result(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a result file; InputError naming the file if it is missing, unreadable, incomplete, or holds an array
    of another shape or type than RESULT_SHAPES, or a value that is not finite (every writer writes finite ones)."""
    path = Path(path)
    result = read_npz(path, "result")
    missing = [k for k in REQUIRED_KEYS if k not in result]
    if missing:
        raise InputError(f"{path}: result file lacks {', '.join(missing)}.")
    names = result["joint_names"]
    sizes = {"T": len(np.atleast_1d(result["joints_world"])), "J": len(np.atleast_1d(names)),
             "Q": _template_body().nq}
    if names.ndim != 1 or names.dtype.kind not in "US":
        raise InputError(f"{path}: joint_names must be a list of names, got {names.dtype} values of shape "
                         f"{names.shape}.")
    for key, pattern in RESULT_SHAPES.items():
        if key not in result:
            continue
        value = result[key]
        expected = tuple(sizes.get(dim, dim) for dim in pattern)
        if value.dtype.kind not in "biuf" or value.shape != expected:
            shown = ", ".join(str(d) for d in pattern) + ("," if len(pattern) == 1 else "")
            dims = ", ".join(f"{d} = {sizes[d]}" for d in pattern if isinstance(d, str))
            raise InputError(f"{path}: {key} is {value.dtype} of shape {value.shape}, expected numbers of shape "
                             f"({shown})" + (f" with {dims}." if dims else "."))
        if not np.isfinite(value).all():
            raise InputError(f"{path}: {key} holds values that are not finite.")
    bad = [key for key in POSITIVE_SCALARS if not float(result[key]) > 0]
    if bad or sizes["T"] == 0:
        raise InputError(f"{path}: " + (f"{', '.join(bad)} must be positive." if bad else "result holds no frames."))
    _check_geometry(path, result)
    return result


def _check_geometry(path: Path, result: dict[str, np.ndarray]) -> None:
    """What a capture writes beyond shapes: unit quaternions in qpos, a rotation in camera_R, a unit floor normal,
    and body_lengths (JSON) whose standing height is body_height."""
    for key in ("qpos", "qpos_kinematic"):
        if key in result:
            quaternions = result[key][:, _template_body().quaternion_addresses[:, None] + np.arange(4)]
            norms = np.linalg.norm(quaternions, axis=-1)
            if np.any(np.abs(norms - 1.0) > UNIT_TOLERANCE):
                raise InputError(f"{path}: {key} holds rotations that are not unit quaternions.")
    R = result["camera_R"]
    if not is_rotation(R, UNIT_TOLERANCE):
        raise InputError(f"{path}: camera_R is not a rotation.")
    if abs(np.linalg.norm(result["floor"][:3]) - 1.0) > UNIT_TOLERANCE:
        raise InputError(f"{path}: floor's normal (its first three numbers) is not a unit vector.")
    if "body_lengths" in result:
        height = _checked_lengths(path, result["body_lengths"]).standing_height
        if abs(height - float(result["body_height"])) > UNIT_TOLERANCE * height:
            raise InputError(f"{path}: body_height {float(result['body_height']):g} m is not the standing height of "
                             f"body_lengths ({height:g} m).")
