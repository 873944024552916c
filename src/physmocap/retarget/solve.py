"""Retargeting a motion of the project's skeleton onto a character's body model (Rempe et al. 2020, appendix D):
uniform scale by the leg length, then inverse kinematics on positions with the character's fixed bone lengths
and joint limits, the feet's contact points on the character's own soles and planted where the source's are.

Both skeletons have the same joints and the same rest directions, so the source's joint rotations with its root
scaled give the character the source's bone directions exactly (`scaled_qpos`); only the feet then miss the
floor or slide where proportions differ (another ankle height, foot length, thigh-to-shank ratio). The IK
(`solve_feet`) keeps every joint near that pose and puts each contact point, while the source has it in contact,
on one fixed spot of the floor for the whole contact (where it touched down), and every contact point on or above
the floor; hinges stay within their limits. Frames are independent, so all are solved at once (Levenberg-Marquardt,
one small system per frame).

A monocular capture's feet often move along the floor while labelled in contact (its global translation drifts:
depth, a person walking out of the picture). A foot planted where it touched down and a body that follows the
source's translation then pull a metre apart, and the IK compromises: the feet slide or sink. So the body's
horizontal translation follows the planted feet (`follow_planted_feet`): while a contact point is held, the whole
pose moves with the offset that keeps that point on its spot, and that offset stays until another held contact
changes it; the pose itself stays the source's. Each new footstep lands up to STEP_ADJUSTMENT leg lengths nearer
the source's own footprint, so the character returns to the capture's path over the following steps
(docs/decisions/retarget-follow-planted-feet.md).

Scaling a path in space but not in time scales its accelerations too: a jump scaled by 0.5 would fall at g / 2,
a flight neither the character's physics nor a viewer can believe. So over each whole-body flight the root keeps
the source's rise above the chord from take-off to landing at full size (`flights_at_full_gravity`), and the
character falls as the source does (docs/decisions/retarget-grf.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body import kinematics as kin
from ..body.ik import solve_points
from ..body.model import CONTACT_POINTS, JOINT_NAMES, BodyModel
from ..body.support import under_the_floor
from ..contacts.flights import STANDING_SUPPORT, ease_frames, edge_easing, flight_support
from ..metrics import GRAVITY
from ..motion import valid_runs

POSE_WEIGHT = 1.0  # each joint's pull towards the scaled source pose (residual in metres)
CONTACT_WEIGHT = 30.0  # a contact point's pull to its planted spot; much stronger than the pose, so feet stay put
IK_ITERATIONS = 12
SAME_FOOT = (1, 0, 3, 2)  # the other contact point of each contact point's foot (CONTACT_POINTS' order)
STEP_ADJUSTMENT = 0.2  # leg lengths a footstep may land nearer the source's own footprint (0 ..; 0: never)


@dataclass
class Retargeted:
    """qpos: (T, nq) the character's motion after IK; scaled: (T, nq) before it; scale: the uniform scale;
    planted: (T, 4, 3) the contact points' planted spots (nan where not in contact)."""

    qpos: np.ndarray
    scaled: np.ndarray
    scale: float
    planted: np.ndarray


def leg_length(lengths) -> float:
    return lengths.thigh + lengths.shank


def scaled_qpos(source_qpos: np.ndarray, scale: float, lift: float = 0.0) -> np.ndarray:
    """(T, nq) the source's joint rotations with its root position times `scale` (about the origin on the floor),
    raised by `lift` metres (the character's ankle height above its soles less the scaled source's)."""
    qpos = np.array(source_qpos, dtype=float)
    qpos[:, 0:3] *= scale
    qpos[:, 2] += lift
    return qpos


def flights_at_full_gravity(heights: np.ndarray, contacts: np.ndarray, valid: np.ndarray, fps: float,
                            scale: float) -> np.ndarray:
    """(T,) m: the source's root heights (T,) m times `scale`, except over each whole-body flight of the labels (no
    point in contact, contacts (T, 4) bool) between two frames with a person (valid (T,)) and a contact, at `fps`
    frames/s, whose root falls as a body in flight does (`flight_support` at most STANDING_SUPPORT): there the
    scaled chord from take-off to landing plus the source's own rise above it, unscaled. The chord is straight, so
    the height's second difference, the fall, stays the source's. A flight with an end outside the clip or beside
    frames without a person has no measured extent, and one held up (a labelling error) does not fall: both are
    only scaled."""
    heights = np.asarray(heights, dtype=float)
    out = scale * heights
    airborne = np.asarray(valid, bool) & ~np.asarray(contacts, bool).any(axis=1)
    times = np.arange(len(out)) / fps
    for start, after in valid_runs(airborne):
        before = start - 1
        if before < 0 or after >= len(out) or not (valid[before] and valid[after]):
            continue
        if not flight_support(heights, times, start, after, GRAVITY) <= STANDING_SUPPORT:
            continue
        frames = np.arange(start, after)
        chord = np.interp(frames, [before, after], heights[[before, after]])
        out[frames] = scale * chord + (heights[frames] - chord)
    return out


def follow_planted_feet(points: np.ndarray, contacts: np.ndarray,
                        step_adjustment: float) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal offset of the whole body (T, 2) that keeps each held contact point on its spot, and the spots
    (T, 4, 3) on z = 0 (nan outside contacts). points: (T, 4, 3) the contact points of the source pose; contacts:
    (T, 4) bool; step_adjustment: metres, the most a footstep moves towards the source's own footprint.

    While points are held (in contact on this frame and the one before) the offset is their mean (spot - point);
    otherwise it keeps its last value. A point touching down beside its foot's held heel or toe takes that point's
    offset (a foot is rigid); any other touches down at the body's offset less up to `step_adjustment` of it, so
    the offset a drifting contact leaves returns to zero over the following steps instead of adding up."""
    T, K = contacts.shape
    offsets = np.zeros((T, 2))
    spots = np.full((T, K, 3), np.nan)
    spot = np.full((K, 2), np.nan)
    offset = np.zeros(2)
    for t in range(T):
        held = contacts[t] & contacts[t - 1] if t > 0 else np.zeros(K, bool)
        if held.any():
            offset = (spot[held] - points[t, held, :2]).mean(axis=0)
        length = float(np.linalg.norm(offset))
        stepped = offset * max(0.0, 1.0 - step_adjustment / length) if length > 0 else offset
        for k in np.flatnonzero(contacts[t] & ~held):
            other = SAME_FOOT[k]
            spot[k] = points[t, k, :2] + (spot[other] - points[t, other, :2] if held[other] else stepped)
        offsets[t] = offset
        spots[t, contacts[t], :2] = spot[contacts[t]]
        spots[t, contacts[t], 2] = 0.0
    return offsets, spots


def _smooth_offsets(offsets: np.ndarray, fps: float) -> np.ndarray:
    """The offsets (T, 2) averaged over 2 n + 1 frames, n = `ease_frames(fps)` (the contacts' easing, EASE_TIME),
    so that the body eases, rather than jumps, when the held contacts change (the held feet stay on their spots
    through the IK). The ends are extended by point reflection, which keeps a steady drift exact up to the first and
    last frame."""
    width = min(ease_frames(fps), len(offsets) - 1)
    if width < 1:
        return offsets.copy()
    head = 2 * offsets[0] - offsets[width:0:-1]
    tail = 2 * offsets[-1] - offsets[-2:-2 - width:-1]
    padded = np.concatenate([head, offsets, tail])
    kernel = np.ones(2 * width + 1) / (2 * width + 1)
    return np.stack([np.convolve(padded[:, i], kernel, "valid") for i in range(offsets.shape[1])], axis=1)


def on_another_level(body: BodyModel, qpos: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """(T,) bool: frames of the source motion qpos (T, nq) on its own body, with its contacts (T, 4), whose body is
    under the floor (z = 0; body.support.under_the_floor, as both physics methods read it): it stands on another
    level (the grass below the box the floor was found on). Judged on the source, whose B.4 feet rest on its floor,
    not on the scaled character, whose feet may sink by its proportions. The character's frames there are neither
    lifted onto the floor nor held above it: lifted, a character stood 1.3 m above its source for 50 frames, and its
    physics explained the climb back with 113% of its weight."""
    pose = kin.forward_kinematics(body, qpos)
    return under_the_floor(body.point_names, pose.points, kin.center_of_mass(body, pose), contacts)


def _ik_goals(body: BodyModel, qpos: np.ndarray, contacts: np.ndarray, fps: float, joints: np.ndarray,
              feet: np.ndarray, contact_columns: np.ndarray,
              other_level: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """solve_feet's starting motion (T, nq) (lifted out of the floor, moved by `follow_planted_feet`), the joints'
    goals (T, J, 3) with the contact points eased onto their spots, their weights (T, J), and the spots (T, 4, 3)."""
    qpos = np.array(qpos, dtype=float)
    # A frame sunk into the floor is first lifted whole out of it, so that the joints' targets stand on the floor;
    # not a frame on another level, which the character follows there.
    sunk = np.maximum(0.0, -kin.forward_kinematics(body, qpos).points[:, feet, 2].min(axis=1))
    qpos[:, 2] += np.where(other_level, 0.0, sunk)
    targets = kin.forward_kinematics(body, qpos).points[:, joints]
    offsets, spots = follow_planted_feet(targets[:, contact_columns], contacts,
                                         STEP_ADJUSTMENT * leg_length(body.lengths))
    offsets = _smooth_offsets(offsets, fps)
    qpos[:, 0:2] += offsets
    targets[..., :2] += offsets[:, None]
    # A contact point eases onto and off the spot of its nearer contact.
    blend, edges = edge_easing(contacts, fps)
    eased = np.where((edges >= 0)[..., None], spots[np.maximum(edges, 0), np.arange(contacts.shape[1])], np.nan)
    goal = targets.copy()
    goal_feet = np.where(np.isnan(eased), targets[:, contact_columns],
                         blend[..., None] * np.nan_to_num(eased) + (1 - blend[..., None]) * targets[:, contact_columns])
    goal[:, contact_columns] = goal_feet
    weights = np.full(goal.shape[:2], POSE_WEIGHT)
    weights[:, contact_columns] = POSE_WEIGHT + (CONTACT_WEIGHT - POSE_WEIGHT) * blend
    return qpos, goal, weights, spots


def solve_feet(body: BodyModel, qpos: np.ndarray, contacts: np.ndarray, fps: float,
               other_level: np.ndarray | None = None, iterations: int = IK_ITERATIONS) -> tuple[np.ndarray, np.ndarray]:
    """IK of every frame: joints (JOINT_NAMES) towards their positions in `qpos` (T, nq) (a frame whose lowest
    contact point is below the floor lifted out of it first, then every frame moved by `follow_planted_feet`),
    contact points (CONTACT_POINTS) in contact (T, 4) onto their planted spots, every contact point on or above
    z = 0, hinges within their limits; the frames other_level (T,) bool (`on_another_level`; None: none) are
    neither lifted nor held above the floor. Returns the solved qpos (T, nq) and the planted spots (T, 4, 3)."""
    other_level = np.zeros(len(qpos), bool) if other_level is None else np.asarray(other_level, bool)
    joints = body.point_index(JOINT_NAMES)
    feet = body.point_index(CONTACT_POINTS)
    contact_columns = np.array([list(JOINT_NAMES).index(n) for n in CONTACT_POINTS])
    qpos, goal, weights, spots = _ik_goals(body, qpos, contacts, fps, joints, feet, contact_columns, other_level)
    return solve_points(body, qpos, joints, goal, weights, feet, iterations, floor_frames=~other_level), spots


def retarget_qpos(body: BodyModel, source_qpos: np.ndarray, source_lengths, contacts: np.ndarray, fps: float,
                  valid: np.ndarray | None = None, other_level: np.ndarray | None = None) -> Retargeted:
    """The source motion (T, nq) of a skeleton with `source_lengths` (SkeletonLengths) on `body`: uniform scale
    by the leg lengths (flights at full gravity: `flights_at_full_gravity`, over the valid (T,) frames, None:
    all), the soles brought to the character's, then `solve_feet` (other_level: see there)."""
    scale = leg_length(body.lengths) / leg_length(source_lengths)
    contacts = np.asarray(contacts, bool)
    lift = body.lengths.ankle_height - scale * source_lengths.ankle_height
    scaled = scaled_qpos(source_qpos, scale, lift)
    valid = np.ones(len(contacts), bool) if valid is None else np.asarray(valid, bool)
    scaled[:, 2] = flights_at_full_gravity(source_qpos[:, 2], contacts, valid, fps, scale) + lift
    qpos, spots = solve_feet(body, scaled, contacts, fps, other_level)
    return Retargeted(qpos, scaled, scale, spots)
