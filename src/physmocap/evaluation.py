"""Scoring a run: the metrics that need no ground truth (those of the run report) and, given a truth file, every pose,
smoothness, floor and force metric of both papers against it. Backs `physmocap evaluate` and the synthetic
benchmark.

A truth file holds at least joint_names (J,) (TRUTH_JOINTS among them), joints_world (T, J, 3) in its own world (Z
up, floor z = 0, metres, finite), camera_R (3, 3) and camera_t (3,) of the camera that filmed it (world -> camera)
and fps; `write_synthetic_case` in physmocap.mocap.synthetic writes such files. The run's points are brought into
the truth's world through both cameras (run world -> camera -> truth world), so each side may choose its world
freely; floor metrics then use the true floor and the true contacts (Rempe 3.2 labels of the true sole points).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from . import metrics
from .body.model import CONTACT_POINTS
from .body.rotations import is_rotation
from .errors import InputError
from .io.atomic import read_npz
from .io.finite import json_text
from .result import UNIT_TOLERANCE

# Joints whose definitions agree between the body model, MediaPipe and motion capture skeletons (pelvis, spine,
# neck and head are placed differently by each and are left out of pose errors).
EVAL_JOINTS = ("left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist",
               "left_hip", "left_knee", "left_ankle", "left_heel", "left_toe", "right_hip", "right_knee",
               "right_ankle", "right_heel", "right_toe")


def score_against_truth(points: np.ndarray, names, com: np.ndarray, truth: dict, body_mass: float,
                        grf: np.ndarray | None = None, residual: np.ndarray | None = None) -> dict[str, float]:
    """Metrics of a motion given in the TRUE world: points (T, P, 3) named `names`, centre of mass (T, 3);
    grf (T, 4, 3) solved contact forces (None: the forces the centre of mass implies); residual (T, 6)."""
    fps = float(truth["fps"])
    true_names = [str(n) for n in truth["joint_names"]]
    names = [str(n) for n in names]
    pred = points[:, [names.index(j) for j in EVAL_JOINTS]]
    true = truth["joints_world"][:, [true_names.index(j) for j in EVAL_JOINTS]]
    if len(pred) != len(true):
        raise InputError(f"the run has {len(pred)} frames and the truth {len(true)}: they must match.")
    hips = [EVAL_JOINTS.index("left_hip"), EVAL_JOINTS.index("right_hip")]
    pred_root, true_root = pred[:, hips].mean(1), true[:, hips].mean(1)
    with_root_p = np.concatenate([pred_root[:, None], pred], axis=1)
    with_root_t = np.concatenate([true_root[:, None], true], axis=1)
    limbs = list(range(1, len(EVAL_JOINTS) + 1))
    feet = points[:, [names.index(n) for n in CONTACT_POINTS]]
    true_contacts = true_contact_labels(truth)
    forces = truth_grf_statistics(com, truth, body_mass, grf, true_contacts)
    mpe, mpe_std, pnp = metrics.mpe_pnp(feet, true_contacts)
    foot = metrics.foot_contact_errors(feet, true_contacts, fps=fps)
    smooth, smooth_std = metrics.e_smooth(pred, true)
    out = dict(
        mpjpe_root_mm=1000 * metrics.mpjpe(with_root_p, with_root_t, align="root", joints=limbs),
        mpjpe_procrustes_mm=1000 * metrics.mpjpe(pred, true, align="procrustes"),
        global_root_mm=1000 * float(np.linalg.norm(pred_root - true_root, axis=-1).mean()),
        global_mpjpe_mm=1000 * metrics.mpjpe(pred, true, align="none"),
        first_frame_aligned_mm=1000 * metrics.mpjpe(pred, true, align="first_frame"),
        pck150=metrics.pck(with_root_p, with_root_t, align="root", joints=limbs),
        auc=metrics.auc(with_root_p, with_root_t, align="root", joints=limbs),
        e_smooth_mm=1000 * smooth, e_smooth_std_mm=1000 * smooth_std,
        acceleration_error=metrics.acceleration_error(pred, true, fps),
        mpe_mm=1000 * mpe, mpe_std_mm=1000 * mpe_std, pnp_percent=pnp,
        floating_percent=foot["floating_percent"], penetration_percent=foot["penetration_percent"],
        skate_percent=foot["skate_percent"],
        grf_mean_percent_bw=forces["mean_percent_bw"], grf_max_percent_bw=forces["max_percent_bw"],
        grf_ballistic_percent_bw=forces["ballistic_percent_bw"],
        residual_mean_percent_bw=(float("nan") if residual is None else 100 * float(
            np.linalg.norm(residual[:, :3], axis=-1).mean()) / (body_mass * metrics.GRAVITY)),
    )
    return {k: float(v) for k, v in out.items()}


def true_contact_labels(truth: dict) -> np.ndarray:
    """(T, 4) contacts of the truth's sole points by the project's labelling (physmocap.contacts.labels)."""
    from .contacts.labels import contact_labels

    names = [str(n) for n in truth["joint_names"]]
    return contact_labels(truth["joints_world"][:, [names.index(n) for n in CONTACT_POINTS]], float(truth["fps"]))


def truth_grf_statistics(com: np.ndarray, truth: dict, body_mass: float, grf: np.ndarray | None = None,
                         true_contacts: np.ndarray | None = None) -> metrics.GrfStatistics:
    """metrics.grf_statistics of the solved forces grf (T, 4, 3), or without them of the forces the centre of
    mass com (T, 3, in the true world) implies, against the true contacts (`true_contact_labels`, computed here
    unless given); its flight_percent_bw holds the per-frame forces in true flight, which a benchmark pools over
    clips for the set's ballistic median."""
    net = grf.sum(axis=1) if grf is not None else metrics.implied_grf(com, body_mass, float(truth["fps"]))
    contacts = true_contact_labels(truth) if true_contacts is None else true_contacts
    return metrics.grf_statistics(net, body_mass, contacts)


TRUTH_JOINTS = tuple(dict.fromkeys(EVAL_JOINTS + CONTACT_POINTS))  # the truth's joints that a score reads


def load_truth(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A truth file (module docstring) checked for what scoring reads; InputError naming the file and the key
    otherwise (a missing array, names without TRUTH_JOINTS, a shape, a number that is not finite, a camera_R
    that is not a rotation, fps not positive)."""
    truth = read_npz(path, "truth")
    for key in ("joint_names", "joints_world", "camera_R", "camera_t", "fps"):
        if key not in truth:
            raise InputError(f"{path}: truth file has no '{key}' array.")
    names = truth["joint_names"]
    listed = [str(n) for n in names.reshape(-1)] if names.dtype.kind in "US" else []
    missing = [j for j in TRUTH_JOINTS if listed.count(j) != 1]
    if names.ndim != 1 or missing:
        raise InputError(f"{path}: joint_names must list each of {', '.join(TRUTH_JOINTS)} once (first wrong: "
                         f"{missing[0] if missing else 'its shape'}).")
    shapes = {  # key -> (the shape as the message states it, whether an array has it)
        "joints_world": (f"(T, {len(names)}, 3)",
                         lambda v: v.ndim == 3 and len(v) > 0 and v.shape[1:] == (len(names), 3)),
        "camera_R": ("(3, 3)", lambda v: v.shape == (3, 3)), "camera_t": ("(3,)", lambda v: v.shape == (3,)),
        "fps": ("()", lambda v: v.size == 1)}
    for key, (shape, has_shape) in shapes.items():
        value = truth[key]
        if value.dtype.kind not in "fiu" or not has_shape(value):
            raise InputError(f"{path}: {key} must be numbers of shape {shape}, got {value.dtype} {value.shape}.")
        if not np.isfinite(value).all():
            raise InputError(f"{path}: {key} holds a value that is not a finite number.")
        truth[key] = value.astype(float).reshape(() if key == "fps" else value.shape)
    if not is_rotation(truth["camera_R"], UNIT_TOLERANCE):
        raise InputError(f"{path}: camera_R is not a rotation.")
    if truth["fps"] <= 0:
        raise InputError(f"{path}: fps must be positive, got {float(truth['fps']):g}.")
    return truth


def to_truth_world(points: np.ndarray, R_run: np.ndarray, t_run: np.ndarray, truth: dict) -> np.ndarray:
    """(..., 3) points of the run's world -> the truth's world, through the camera both share."""
    camera = points @ np.asarray(R_run).T + t_run
    return (camera - truth["camera_t"]) @ truth["camera_R"]


def evaluate(result_path: str | os.PathLike, truth_path: str | os.PathLike | None = None) -> dict:
    """Every metric of a run: {"run": the report's metrics (final and kinematic motion), "truth": {final: ...,
    kinematic: ...} when a truth file is given}."""
    from .body.kinematics import center_of_mass, forward_kinematics
    from .export import body_from_result
    from .result import load_result
    from .viz.report import run_metrics

    result = load_result(result_path)
    out: dict = {"run": {m.key: {"final": m.final, "kinematic": m.kinematic, "unit": m.unit, "label": m.label}
                         for m in run_metrics(result)}}
    if truth_path is None:
        return out
    truth = load_truth(truth_path)
    if len(truth["joints_world"]) != len(result["joints_world"]):
        raise InputError(f"{truth_path}: the truth has {len(truth['joints_world'])} frames and the run {result_path} "
                         f"{len(result['joints_world'])}; they must match.")
    body = body_from_result(result)
    names = list(result["joint_names"])
    physics = str(result.get("physics", "none")) != "none"
    out["truth"] = {}
    for motion, points_key, qpos_key in (("final", "joints_world", "qpos"),
                                         ("kinematic", "joints_world_kinematic", "qpos_kinematic")):
        points = to_truth_world(result[points_key], result["camera_R"], result["camera_t"], truth)
        com = to_truth_world(center_of_mass(body, forward_kinematics(body, result[qpos_key])), result["camera_R"],
                             result["camera_t"], truth)
        solved = physics and motion == "final"
        out["truth"][motion] = score_against_truth(
            points, names, com, truth, float(result["body_mass"]),
            grf=result["grf"] if solved else None, residual=result["residual_root_force"] if solved else None)
    return out


def write_evaluation(path: str | os.PathLike, evaluation: dict) -> None:
    from .io.atomic import write_text

    write_text(Path(path), json_text(evaluation, indent=2))
