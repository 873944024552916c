"""The retarget stage: a run's result.npz and a character file in, the motion on the character out.

    DIR/
      character.bvh   the character's own hierarchy, names, offsets and channel orders, animated
      character.glb   (glTF characters) the same mesh, skin and nodes with the animation "physmocap" added
      result.npz      the result contract on the character: its joints, generalised coordinates, forces, mass
      retarget.json   the character's measurements, the mapping, the figures of `retarget_metrics`, the times,
                      and how far the character's path leaves the capture's (path_departure_*)

Steps: read and map the rig, build the character's body model (character.py), retarget (solve.py), run the
physics on the character's body model (PhysCap, or trajectory optimisation), move the rig with it (writers.py).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..body import kinematics as kin
from ..body.model import CONTACT_POINTS, BodyModel
from ..config import Settings
from ..errors import InputError
from ..export import body_from_result
from ..io.atomic import write_text
from ..io.finite import json_text
from ..metrics import (
    FLOATING_THRESHOLD,
    GRAVITY,
    GrfMeasure,
    contact_skating,
    foot_contact_errors,
    grf_statistics,
)
from ..result import RESULT_POINTS, load_result, save_result
from .character import Character, build_character
from .mapping import load_character_config
from .rig import read_rig
from .solve import Retargeted, on_another_level, retarget_qpos, solve_feet
from .writers import RigMotion, rig_motion, rig_positions, write_rig_bvh, write_rig_glb

if TYPE_CHECKING:
    from ..dynamics.stage import PhysicsMotion
    from ..trajopt.stage import TrajoptMotion

PHYSICS_METHODS = ("physcap", "trajopt", "none")
# Bones compared between the source and the character (body-model points), and the same on the rig (roles).
BODY_BONES = (("pelvis", "spine"), ("spine", "neck"), ("neck", "head"), ("left_hip", "right_hip"),
              ("left_shoulder", "right_shoulder"),
              *((f"{s}_{a}", f"{s}_{b}") for s in ("left", "right")
                for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"),
                             ("ankle", "toe"))))
RIG_BONES = (("left_hip", "right_hip"), ("left_shoulder", "right_shoulder"), ("hips_mid", "shoulders_mid"),
             *((f"{s}_{a}", f"{s}_{b}") for s in ("left", "right")
               for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))))


@dataclass
class RetargetReport:
    """files: name -> path; metrics: see `retarget_metrics`; character: its measurements; notes."""

    files: dict[str, str]
    metrics: dict
    character: dict
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> str:
        return json_text(dict(files=self.files, metrics=self.metrics, character=self.character, notes=self.notes),
                         indent=2)


def _directions(points: np.ndarray, names: list[str], bones) -> np.ndarray:
    """(T, n, 3) unit directions of the bones (pairs of names) of points (T, P, 3)."""
    a = points[:, [names.index(x) for x, _ in bones]]
    b = points[:, [names.index(y) for _, y in bones]]
    d = b - a
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)


def _rig_role_points(character: Character, positions: np.ndarray) -> tuple[np.ndarray, list[str]]:
    roles = [r for r in character.bones if r != "head"]
    pts = [positions[:, character.bones[r]] for r in roles]
    b = character.bones
    roles += ["hips_mid", "shoulders_mid"]
    pts += [(positions[:, b["left_hip"]] + positions[:, b["right_hip"]]) / 2,
            (positions[:, b["left_shoulder"]] + positions[:, b["right_shoulder"]]) / 2]
    return np.stack(pts, axis=1), roles


def follows_gap(frames: np.ndarray) -> np.ndarray:
    """(n,) bool for the n selected frames of a (T,) mask: those whose previous selected frame is not the one
    just before them."""
    index = np.flatnonzero(frames)
    return np.concatenate([[False], np.diff(index) > 1])


def retarget_metrics(character: Character, source_points: np.ndarray, qpos: np.ndarray, positions: np.ndarray,
                     contacts: np.ndarray, fps: float, grf: np.ndarray | None, breaks: np.ndarray,
                     unexplained: np.ndarray | None = None, other_level: np.ndarray | None = None) -> dict:
    """Figures of a retargeted motion (issue 19), all finite or None:

    skate_percent, penetration_percent, floating_percent: Rempe's foot metrics (metrics.foot_contact_errors) of the
        character's heel and toe points against the source's contacts, over the frames on this floor (not
        `solve.on_another_level`, whose feet are under it on purpose; another_level_frames counts those);
        contact_frames_kept: share of the source's contact point-frames in which the character's point is within
        FLOATING_THRESHOLD of the floor and not sliding more than the skate threshold; bone_cosine_body /
        bone_cosine_rig: mean cosine between the source's bone directions and the body model's / the rig's (limbs,
        hip and shoulder lines, trunk); bone_length_error_m: the largest change of any rig bone's length over the
        motion; grf_mean_percent_bw: mean magnitude of the net ground reaction force in the character's body weights
        (Rempe's measure; None without physics), grf_vertical_mean_percent_bw: the mean of its vertical component,
        which over a clip equals the weight less what the root's residual force carries, plus the change of vertical
        momentum (docs/decisions/retarget-grf.md); grf_explained_mean_percent_bw,
        grf_vertical_explained_mean_percent_bw: the magnitude and the vertical component over the frames the physics
        explains (unexplained (n,) bool: the frames it flagged and handed back, whose forces, where any are written,
        carry the character, not the motion handed back; None: all explained); com: mean centre of mass height as a
        share of the standing height.
    The rows are the frames with a person; breaks (n,) bool marks those that follow a gap: nothing slides into them."""
    body = character.body
    pose = kin.forward_kinematics(body, qpos)
    this_floor = np.ones(len(qpos), bool) if other_level is None else ~np.asarray(other_level, bool)
    on_floor = np.flatnonzero(this_floor)
    feet = pose.points[on_floor][:, body.point_index(CONTACT_POINTS)]
    contacts = np.asarray(contacts, bool)[on_floor]
    breaks = np.asarray(breaks, bool)[on_floor] | follows_gap(this_floor)
    foot = foot_contact_errors(feet, contacts, fps, breaks=breaks)
    heights = feet[..., 2]
    sliding = contact_skating(feet, contacts, fps, breaks=breaks)
    kept = contacts & (np.abs(heights) <= FLOATING_THRESHOLD) & ~sliding
    names = list(RESULT_POINTS)
    body_points = pose.points[:, body.point_index(RESULT_POINTS)]
    cos_body = np.sum(_directions(body_points, names, BODY_BONES) * _directions(source_points, names, BODY_BONES), -1)
    rig_points, roles = _rig_role_points(character, positions)
    source_roles = np.stack([source_points[:, names.index(r)] if r in names else
                             (source_points[:, names.index("left_hip")]
                              + source_points[:, names.index("right_hip")]) / 2
                             if r == "hips_mid" else
                             (source_points[:, names.index("left_shoulder")]
                              + source_points[:, names.index("right_shoulder")]) / 2 for r in roles], axis=1)
    cos_rig = np.sum(_directions(rig_points, roles, RIG_BONES) * _directions(source_roles, roles, RIG_BONES), -1)
    parents = character.rig.parents
    children = np.flatnonzero(parents >= 0)
    rest_lengths = np.linalg.norm(character.rest[children] - character.rest[parents[children]], axis=-1)
    lengths = np.linalg.norm(positions[:, children] - positions[:, parents[children]], axis=-1)
    com = kin.center_of_mass(body, pose)
    return dict(
        frames=int(len(qpos)),  # those measured
        another_level_frames=int(len(qpos) - len(on_floor)),
        skate_percent=foot["skate_percent"], penetration_percent=foot["penetration_percent"],
        floating_percent=foot["floating_percent"],
        contact_frames_kept=float(kept.sum() / contacts.sum()) if contacts.any() else None,
        bone_cosine_body=float(cos_body.mean()), bone_cosine_rig=float(cos_rig.mean()),
        bone_length_error_m=float(np.abs(lengths - rest_lengths).max()) if len(children) else 0.0,
        grf_mean_percent_bw=None if grf is None else grf_statistics(grf, body.mass)["mean_percent_bw"],
        grf_vertical_mean_percent_bw=None if grf is None else grf_statistics(grf, body.mass,
                                                                             measure="vertical")["mean_percent_bw"],
        grf_explained_mean_percent_bw=_explained_mean(grf, body.mass, unexplained, "magnitude"),
        grf_vertical_explained_mean_percent_bw=_explained_mean(grf, body.mass, unexplained, "vertical"),
        com_height_share=float(com[:, 2].mean() / body.height),
    )


def _explained_mean(grf: np.ndarray | None, mass: float, unexplained: np.ndarray | None,
                    measure: GrfMeasure) -> float | None:
    """Mean net GRF (% of the weight, mass kg; metrics.grf_statistics' measure) over the frames of grf (n, 4, 3) N
    not flagged in unexplained (n,); None without physics or without such frames."""
    if grf is None:
        return None
    explained = np.ones(len(grf), bool) if unexplained is None else ~np.asarray(unexplained, bool)
    return grf_statistics(grf[explained], mass, measure=measure)["mean_percent_bw"] if explained.any() else None


@dataclass
class _PhysicsOutcome:
    """The retargeted motion after physics (T frames): qpos with the feet planted again, the contacts used, and
    where physics ran the simulated qpos, grf (T, 4, 3) N, residual (T, 6), fallback, corrected and unexplained
    flags (T,) (the character's own: frames its contact model could not explain); without physics qpos is the
    retargeted motion, simulated and grf None, the rest zeros."""

    qpos: np.ndarray
    contacts: np.ndarray
    simulated: np.ndarray | None
    grf: np.ndarray | None
    residual: np.ndarray
    fallback: np.ndarray
    corrected: np.ndarray
    unexplained: np.ndarray


def _run_physics(body: BodyModel, retargeted_qpos: np.ndarray, fps: float, contacts: np.ndarray, stationary: np.ndarray,
                 valid: np.ndarray, other_level: np.ndarray, physics: str, settings: Settings,
                 notes: list[str]) -> _PhysicsOutcome:
    """`physics` on the character's body model over the frames from the first to the last with a person; the
    capture's extrapolation before and after them (no observations) keeps the kinematic motion, without forces,
    as the pipeline's physics does. A note says how many frames fell back."""
    T = len(retargeted_qpos)
    outcome = _PhysicsOutcome(retargeted_qpos, contacts, None, None, np.zeros((T, 6)), np.zeros(T, bool),
                              np.zeros(T, bool), np.zeros(T, bool))
    span = slice(*((int(np.argmax(valid)), T - int(np.argmax(valid[::-1]))) if valid.any() else (0, 0)))
    if physics == "none" or span.stop - span.start < 3:
        return outcome
    motion: PhysicsMotion | TrajoptMotion
    if physics == "physcap":
        from ..dynamics.stage import run_physcap

        # The source's contacts in use already hold its resting points (B.4's, or its own physics' rest test)
        motion = run_physcap(body, retargeted_qpos[span], fps, contacts[span], stationary[span], settings.physics,
                             valid=valid[span], resting_labelled=True, whole_clip=True)
    else:
        from ..trajopt.stage import run_trajopt

        motion = run_trajopt(body, retargeted_qpos[span], fps, contacts[span], settings.trajopt, None, valid[span])
    grf, used_contacts, simulated = np.zeros((T, 4, 3)), contacts.copy(), retargeted_qpos.copy()
    grf[span], outcome.residual[span], used_contacts[span] = motion.grf, motion.residual, motion.contacts
    outcome.fallback[span], outcome.corrected[span], simulated[span] = motion.qp_failures > 0, motion.corrected, \
        motion.qpos
    if motion.unexplained is not None:
        outcome.unexplained[span] = motion.unexplained
    if outcome.fallback.any():
        notes.append(f"physics fell back on {int(outcome.fallback.sum())} frames (kinematic motion kept there)")
    # The tracker's feet can drift a few centimetres off their spots (balance correction, soft contacts); the
    # same IK plants them again on the simulated motion (docs/decisions/retarget-feet-after-physics.md).
    outcome.qpos, _ = solve_feet(body, simulated, contacts, fps, other_level)
    outcome.contacts, outcome.simulated, outcome.grf = used_contacts, simulated, grf
    return outcome


def _write_rig_files(out_dir: Path, character: Character, rig_moves: RigMotion, fps: float) -> dict[str, str]:
    """character.bvh, and character.glb for a glTF rig; the names of those and of the files written later."""
    files = {"bvh": str(out_dir / "character.bvh"), "result": str(out_dir / "result.npz"),
             "report": str(out_dir / "retarget.json")}
    out_dir.mkdir(parents=True, exist_ok=True)
    write_rig_bvh(files["bvh"], character, rig_moves, fps)
    if character.rig.kind == "gltf":
        files["glb"] = str(out_dir / "character.glb")
        write_rig_glb(files["glb"], character, rig_moves, fps)
    return files


def _simulated_metrics(character: Character, source_points: np.ndarray, simulated: np.ndarray, grf: np.ndarray,
                       final: np.ndarray, points: np.ndarray, frames: np.ndarray, fps: float,
                       contacts: np.ndarray, other_level: np.ndarray) -> dict:
    """The foot and bone figures of the simulated motion before the feet were planted again, and how far that
    moved the points (metres: mean, 99th percentile of each frame's largest)."""
    before = retarget_metrics(character, source_points[frames], simulated[frames],
                              rig_positions(character, rig_motion(character, simulated[frames])),
                              contacts[frames], fps, grf[frames], follows_gap(frames), other_level=other_level[frames])
    shift = np.linalg.norm(final - kin.forward_kinematics(character.body, simulated).points[:, points],
                           axis=-1)[frames]
    return {"simulated": {k: before[k] for k in ("skate_percent", "penetration_percent", "floating_percent",
                                                 "contact_frames_kept", "bone_cosine_rig")},
            "moved_after_physics_m": dict(mean=float(shift.mean()),
                                          frame_max_p99=float(np.percentile(shift.max(axis=1), 99)))}


def _character_result(source: dict[str, np.ndarray], character: Character, character_path: str | os.PathLike,
                      physics: str, retargeted: Retargeted, outcome: _PhysicsOutcome, final: np.ndarray,
                      kinematic: np.ndarray, positions: np.ndarray, masses: dict[str, float]) -> dict[str, np.ndarray]:
    """The source's result.npz with the motion, forces, body and rig of the character; ValueError (a bug) when a
    motion array is not finite."""
    body, T = character.body, len(outcome.qpos)
    result = dict(source)
    result.update(
        joints_world=final, joints_world_kinematic=kinematic, qpos=outcome.qpos, qpos_kinematic=retargeted.qpos,
        contacts=np.asarray(outcome.contacts, bool), grf=np.zeros((T, 4, 3)) if outcome.grf is None else outcome.grf,
        residual_root_force=outcome.residual, physics=np.array(physics), physics_fallback=outcome.fallback,
        physics_unexplained=outcome.unexplained, balance_corrected=outcome.corrected,
        physics_deviation=np.linalg.norm(final - kinematic, axis=-1).mean(axis=1),
        body_mass=np.array(body.mass, dtype=np.float64), body_height=np.array(body.height, dtype=np.float64),
        body_lengths=np.array(json.dumps(body.lengths.__dict__)), body_segment_masses=np.array(json.dumps(masses)),
        character_file=np.array(str(character_path)), rig_joint_names=np.array(character.rig.names),
        rig_joints_world=positions,
        center_of_mass=kin.center_of_mass(body, kin.forward_kinematics(body, outcome.qpos)),
        retarget_scale=np.array(retargeted.scale, dtype=np.float64))
    for key in ("joints_world", "qpos", "grf", "rig_joints_world"):
        if not np.all(np.isfinite(result[key])):
            raise ValueError(f"retargeting produced non-finite {key}")  # a bug, not a user error
    return result


def _path_departure(final: np.ndarray, source: np.ndarray, scale: float) -> np.ndarray:
    """(n,) m: how far the character's pelvis (final (n, points, 3), at the source's size) leaves the capture's
    (source (n, points, 3)) along the floor: the price of feet that stay where the source's slid
    (solve.follow_planted_feet)."""
    return np.linalg.norm(final[:, 0, :2] / scale - source[:, 0, :2], axis=-1)


def retarget_result(result_path: str | os.PathLike, character_path: str | os.PathLike, out_dir: str | os.PathLike,
                    *, character_map: str | os.PathLike | None = None, physics: str = "physcap",
                    settings: Settings | None = None) -> RetargetReport:
    """Retarget the motion of a result.npz onto a character (BVH or glTF) and write DIR (see the module)."""
    if physics not in PHYSICS_METHODS:
        raise InputError(f"physics must be one of {', '.join(PHYSICS_METHODS)}, got {physics!r}.")
    settings = settings or Settings()
    source = load_result(result_path)
    out_dir = Path(out_dir)
    config = load_character_config(character_map)
    rig = read_rig(character_path, config.units_to_metres)
    source_body = body_from_result(source)
    character = build_character(rig, config, float(source["body_mass"]), float(source["body_height"]))
    body, fps = character.body, float(source["fps"])
    valid = np.asarray(source["valid"], bool)
    # No foot is held through a frame without a person (its labels come from interpolated keypoints).
    contacts = np.asarray(source["contacts"], bool) & valid[:, None]
    T = len(source["qpos"])

    started = time.perf_counter()
    other_level = valid & on_another_level(source_body, source["qpos"], contacts)
    retargeted = retarget_qpos(body, source["qpos"], source_body.lengths, contacts, fps, valid, other_level)
    retarget_seconds = time.perf_counter() - started
    notes = list(character.notes)
    started = time.perf_counter()
    outcome = _run_physics(body, retargeted.qpos, fps, contacts, np.asarray(source["stationary"], bool), valid,
                           other_level, physics, settings, notes)
    physics_seconds = time.perf_counter() - started

    rig_moves = rig_motion(character, outcome.qpos)
    positions = rig_positions(character, rig_moves)
    files = _write_rig_files(out_dir, character, rig_moves, fps)
    points = body.point_index(RESULT_POINTS)
    final = kin.forward_kinematics(body, outcome.qpos).points[:, points]
    kinematic = kin.forward_kinematics(body, retargeted.qpos).points[:, points]
    frames = valid if valid.any() else np.ones(T, bool)  # figures over the frames with a person
    grf = outcome.grf
    metrics = retarget_metrics(character, source["joints_world"][frames], outcome.qpos[frames], positions[frames],
                               contacts[frames], fps, None if grf is None else grf[frames], follows_gap(frames),
                               outcome.unexplained[frames], other_level[frames])
    departure = _path_departure(final[frames], source["joints_world"][frames], retargeted.scale)
    metrics.update(retarget_ms_per_frame=1000 * retarget_seconds / T, physics_ms_per_frame=1000 * physics_seconds / T,
                   unexplained_frames=int(outcome.unexplained[frames].sum()),
                   physics=physics, scale=retargeted.scale, path_departure_mean_m=float(departure.mean()),
                   path_departure_max_m=float(departure.max()),
                   residual_vertical_mean_percent_bw=None if grf is None else float(
                       100 * outcome.residual[frames, 2].mean() / (body.mass * GRAVITY)))
    if outcome.simulated is not None and grf is not None:  # the same figures before the feet were planted again
        metrics.update(_simulated_metrics(character, source["joints_world"], outcome.simulated, grf, final, points,
                                          frames, fps, contacts, other_level))
    masses = {b.name: round(b.mass, 4) for b in body.bodies}
    save_result(files["result"], _character_result(source, character, character_path, physics, retargeted, outcome,
                                                   final, kinematic, positions, masses))
    described = dict(file=str(character_path), kind=rig.kind, joints=len(rig.names),
                     bones={role: rig.names[j] for role, j in character.bones.items()},
                     units_to_metres=character.units_to_metres, height_m=round(body.height, 4),
                     mass_kg=round(body.mass, 3), segment_masses_kg=masses,
                     lengths_m={k: round(v, 4) for k, v in body.lengths.__dict__.items()})
    report = RetargetReport(files, metrics, described, notes)
    write_text(files["report"], report.to_json())
    return report
