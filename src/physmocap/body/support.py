"""Support on the floor: the support polygon, a pure 2D kernel on the few contact points of a frame, shared by the
physics' balance test (every frame, so plain floats) and the viewer's support polygons; and which frames rest on
a part of the body the sole contact model has no point for, or sink below the floor, shared by both physics
methods' diagnoses."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Sequence

import numpy as np

from ..motion import frame_ranges, long_runs
from .model import CONTACT_POINTS

log = logging.getLogger("physmocap")

# The body points whose nearness to the floor means the body rests on them: knees, the seat, elbows, the trunk and
# head. Not the feet (the contact model's own), nor the hands, which reach to the floor without carrying weight
# (a dribble; the long-armed cartoon rig's fingers skim it while walking) and whose support the force check catches.
RESTING_POINTS: tuple[str, ...] = ("pelvis", "spine", "neck", "head", "left_shoulder", "left_elbow", "right_shoulder",
                                   "right_elbow", "left_hip", "left_knee", "right_hip", "right_knee")
# m: such a point this close to the floor (or below it) rests on it: a kneeling knee's joint centre sits about this
# high (docs/decisions/physics-limits.md, "Other body parts")
RESTING_HEIGHT = 0.05
# m: a foot this far above or below the floor stands on another level: a stair's riser is 0.15-0.2 m, while fits sink
# unlabelled feet up to 0.09 m under the floor on six of the seven real videos (docs/decisions/refine-short-runs.md,
# "Lower ground")
STEP_HEIGHT = 0.15
# degrees: both thighs nearer level than this, for SEATED_TIME, sit on a seat: the seated thighs of CMU's stool clips
# lie 10-34 degrees from level (10th-90th percentile), standing, walking and jumping ones at least 31
# (docs/decisions/physics-limits.md, "A seat")
SEATED_THIGH = 30.0
# s: squatting to scoop (CMU 002_06) levels the thighs for 0.3-0.6 s at a time; a seated person stays
SEATED_TIME = 1.0
THIGH_POINTS: tuple[str, ...] = ("left_hip", "left_knee", "right_hip", "right_knee")
_LEVEL_SLOPE_SQUARED = math.tan(math.radians(SEATED_THIGH)) ** 2  # a level thigh's rise^2 / run^2 stays under this


def resting_points(point_names: Sequence[str]) -> list[int]:
    """Indices into point_names of the RESTING_POINTS it holds."""
    return [i for i, name in enumerate(point_names) if name in RESTING_POINTS]


def resting_off_feet(heights: np.ndarray) -> np.ndarray:
    """(...,) bool: heights (..., P) m above the floor of the body's `resting_points` -> whether any rests on the
    floor (within RESTING_HEIGHT, or below it): a knee, an elbow or the seat carrying weight that no sole point can,
    or a fit whose body sinks through the floor."""
    return np.asarray(heights).min(axis=-1) < RESTING_HEIGHT


def unexplained_frames(point_names: Sequence[str], points: np.ndarray, com: np.ndarray,
                       contacts: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: frames of an input motion, its body points (T, P, 3) m (point_names order) and centre of mass com
    (T, 3) m, whose body is under the floor (`under_the_floor`, with the contact labels (T, 4)), or rests on the
    floor off its feet (`resting_off_feet`: a knee, an elbow, the seat). The body stands on its soles in the contact
    model, so its COM and its lowest sole point are on or above the floor; below it is a detection or floor error (a
    person leaving the view, a floor at another height, a drop off the floor's edge, whose feet pass under the floor
    before the COM does). Both physics methods keep the kinematic motion there: optimised, such frames asked for
    forces of several body weights (intel_highcam_walk_stand at 10 fps: docs/decisions/trajopt-frame-rate.md), and a
    body sliding on a knee departed 13-14 cm from its input (docs/decisions/physics-limits.md, "Other body
    parts")."""
    heights = np.asarray(points)[:, resting_points(point_names), 2]
    return under_the_floor(point_names, points, com, contacts) | resting_off_feet(heights)


def thighs_level(thigh_points: np.ndarray) -> np.ndarray:
    """(...,) bool: the THIGH_POINTS' positions (..., 4, 3) m, z up -> whether both thighs lie within SEATED_THIGH
    of level (their elevation either way: rise^2 < tan^2 x run^2, as `thighs_level_now` in floats)."""
    thighs = thigh_points[..., [0, 2], :] - thigh_points[..., [1, 3], :]  # hip minus knee, left and right
    run = thighs[..., 0] ** 2 + thighs[..., 1] ** 2
    return (thighs[..., 2] ** 2 < _LEVEL_SLOPE_SQUARED * run).all(axis=-1)


def thighs_level_now(left_hip, left_knee, right_hip, right_knee) -> bool:
    """`thighs_level` of one frame in plain floats (each point three floats, m): the physics stream asks it every
    frame, where numpy's cost per call outweighs the arithmetic."""
    for (hx, hy, hz), (kx, ky, kz) in ((left_hip, left_knee), (right_hip, right_knee)):
        if (hz - kz) ** 2 >= _LEVEL_SLOPE_SQUARED * ((hx - kx) ** 2 + (hy - ky) ** 2):
            return False
    return True


def seated_run_frames(fps: float) -> int:
    """The fewest frames at fps (frames/s) of level thighs that make a seated run: SEATED_TIME's worth."""
    return math.ceil(SEATED_TIME * fps - 1e-9)


def seated_frames(point_names: Sequence[str], points: np.ndarray, fps: float, observed: np.ndarray) -> np.ndarray:
    """(T,) bool: observed frames (T,) bool of runs at least SEATED_TIME long (fps frames/s) in which both thighs of
    the body points (T, P, 3) m (point_names order; z up) lie within SEATED_THIGH of level: a seat, which the contact
    model has no point for, carries the body (the feet alone then claimed the whole weight, 0.97-1.01 body weights
    on CMU's stool clips)."""
    thigh_points = points[:, [list(point_names).index(name) for name in THIGH_POINTS]]
    return long_runs(thighs_level(thigh_points) & np.asarray(observed, bool), seated_run_frames(fps))


def under_the_floor(point_names: Sequence[str], points: np.ndarray, com: np.ndarray,
                    contacts: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: frames whose body stands, wholly or partly, on another level: its COM below the floor, or a foot
    with no contact label (contacts (T, 4) bool, CONTACT_POINTS order; None: none) whose lowest sole point lies
    deeper than RESTING_HEIGHT under it. A foot labelled in contact is held on the floor by the contact model (a
    fit sunk by its depth error is lifted onto it); an unlabelled foot deep under it stands on lower ground: both
    feet there (sports2d's drop off the box, its start fitted 1.2 m too near), or one, a stair climber's, whose
    weight the other foot on the floor was left to carry alone (the character leant 15 cm off its input,
    docs/decisions/physics-limits.md, "A foot on another level, a point that climbs")."""
    index = [point_names.index(name) for name in CONTACT_POINTS]
    soles = np.asarray(points)[:, index, 2].reshape(len(points), 2, 2)  # (T, foot, heel / toe)
    labelled = np.zeros(soles.shape, bool) if contacts is None else np.asarray(contacts, bool).reshape(soles.shape)
    deep_free_foot = (soles.min(axis=2) < -RESTING_HEIGHT) & ~labelled.any(axis=2)
    return (np.asarray(com)[:, 2] < 0.0) | deep_free_foot.any(axis=1)


def observed_unexplained_frames(point_names: Sequence[str], points: np.ndarray, com: np.ndarray, fps: float,
                                observed: np.ndarray, method: str, contacts: np.ndarray | None = None) -> np.ndarray:
    """(T,) bool: `unexplained_frames` (with the contact labels (T, 4)) and `seated_frames` (the whole clip at fps
    frames/s) among the observed frames (T,) bool, each stretch logged as `method`'s ("physics", "trajopt"), which
    keeps the kinematic motion there."""
    unexplained = np.asarray(observed, bool) & unexplained_frames(point_names, points, com, contacts)
    if unexplained.any():
        log.warning("%s: on frames %s the input's centre of mass or feet lie below the floor or the body rests on a "
                    "knee, an elbow or the seat, which the feet on the floor cannot explain: the kinematic motion is "
                    "kept there.", method, ", ".join(frame_ranges(np.flatnonzero(unexplained))))
    seated = seated_frames(point_names, points, fps, observed) & ~unexplained
    if seated.any():
        log.warning("%s: on frames %s the body sits (both thighs within %g degrees of level for %g s or more), and "
                    "the feet on the floor cannot carry what a seat does: the kinematic motion is kept there.",
                    method, ", ".join(frame_ranges(np.flatnonzero(seated))), SEATED_THIGH, SEATED_TIME)
    return unexplained | seated


def convex_hull_2d(points: Iterable[Iterable[float]]) -> list[tuple[float, float]]:
    """(n, 2) points in metres (an array or nested sequences) -> the hull's vertices counter-clockwise, from the
    smallest (x, y), without repeated or collinear points (Andrew's monotone chain: for the four sole points, a
    hundred times quicker than Qhull). Fewer than three distinct points come back sorted (a point or a segment)."""
    unique = sorted({(float(x), float(y)) for x, y in points})
    if len(unique) < 3:
        return unique

    def half(ordered: list[tuple[float, float]]) -> list[tuple[float, float]]:
        chain: list[tuple[float, float]] = []
        for p in ordered:
            while len(chain) >= 2 and ((chain[-1][0] - chain[-2][0]) * (p[1] - chain[-2][1])
                                       - (chain[-1][1] - chain[-2][1]) * (p[0] - chain[-2][0])) <= 0.0:
                chain.pop()
            chain.append(p)
        return chain[:-1]

    return half(unique) + half(unique[::-1])
