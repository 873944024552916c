"""Pose correction of PhysCap 4.3.1: a stationary person on both feet whose centre of gravity projects outside the
base of support is straightened step by step, first by tilting the whole body upright about the feet, then by
straightening knees and hips, until the pose is balanced or the person moves; then the correction relaxes."""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..body.kinematics import rigid_transform_qpos
from ..body.model import CONTACT_POINTS, BodyModel
from ..body.rotations import axis_angle_matrix, quat_exp, quat_log
from ..body.support import convex_hull_2d
from ..camera import WORLD_UP

SMALL_LEAN = np.radians(2.0)  # below this the tilt is done and the legs are straightened instead
RELAXED = 1e-3  # rad of tilt, share of the bend: a relaxing correction below this is dropped (invisible)
FOOT_BREADTH = 0.055  # of the standing height (Drillis & Contini 1966): the sole's width about its heel-toe line
# rad: a knee bent more than this is a posture (seated, squatting), not a standing fit's error; seated on stools
# the correction stood the body up (docs/decisions/physics-balance.md, "Seated")
STANDING_BEND = math.radians(45.0)


def support_distance(point: np.ndarray, support: np.ndarray) -> float:
    """m: how far the 2D `point` lies outside the convex hull of `support` (k >= 1, 2), along the outward normal of
    the hull's farthest edge (<= 0 inside); for one or two distinct points, the distance to their segment."""
    hull = convex_hull_2d(support.tolist())
    if len(hull) >= 3:
        x, y = float(point[0]), float(point[1])
        # distance outside each counter-clockwise edge a -> b along its outward normal (dy, -dx) / length
        return max(((by - ay) * (x - ax) - (bx - ax) * (y - ay)) / math.hypot(bx - ax, by - ay)
                   for (ax, ay), (bx, by) in zip(hull, hull[1:] + hull[:1], strict=True))
    a, b = support.min(axis=0), support.max(axis=0)
    ends = support[[np.argmin(support @ (b - a)), np.argmax(support @ (b - a))]]
    d = ends[1] - ends[0]
    s = np.clip((point - ends[0]) @ d / max(d @ d, 1e-12), 0.0, 1.0)
    return float(np.linalg.norm(ends[0] + s * d - point))


def inside_support(point: np.ndarray, support: np.ndarray, margin: float = 0.02) -> bool:
    """Whether the 2D `point` lies in the convex hull of `support` (k, 2), grown by `margin` metres."""
    return len(support) > 0 and support_distance(point, support) <= margin


def sole_support(contacts: np.ndarray) -> np.ndarray:
    """(4,) the sole points (CONTACT_POINTS: heel and toe of the left, then the right foot) that bound the base of
    support for the contacts (4,): both points of every foot with either in contact. A stationary person stands
    on the soles of the feet that touch the floor; the labels of one flat foot flicker between its heel and toe,
    and a left heel with a right toe alone bound a line, which no observed centre of mass lies on (on one standing
    video the correction then leant the body 16 degrees)."""
    return np.repeat(contacts.reshape(2, 2).any(axis=1), 2)


def _norm(vector: np.ndarray) -> float:
    """np.linalg.norm of a vector (the square root of its dot product with itself), without numpy's Python layer."""
    return math.sqrt(vector.dot(vector))


def _angle_to_up(vector: np.ndarray) -> float:
    """rad: the angle between `vector` (3,) and WORLD_UP; the cosine clipped to [-1, 1] in floats (np.clip's cost per
    call is about that of the rest of the correction's arithmetic)."""
    return float(np.arccos(min(max(vector @ WORLD_UP / _norm(vector), -1.0), 1.0)))


class BalanceCorrector:
    """Keeps the accumulated corrections of 4.3.1 from frame to frame (causal)."""

    def __init__(self, body: BodyModel, rate: float = 0.1):
        self.body, self.rate = body, rate
        # m: the base of support reaches half a foot's breadth beyond the heel and toe points; on the points
        # alone one foot's support was a line that no observed centre of mass stayed on, and every one-legged
        # stance was "unbalanced" (docs/decisions/physics-balance.md)
        self.margin = FOOT_BREADTH / 2.0 * body.lengths.standing_height
        self.model = body.mujoco_model()
        self.data = mujoco.MjData(self.model)
        self.sites = np.array([self.model.site(n).id for n in CONTACT_POINTS])
        self.neck = self.model.site("neck").id
        self.pelvis = self.model.site("pelvis").id
        self.legs = [(body.qpos_address[body.joint_index[f"{s}_knee"]],
                      body.qpos_address[body.joint_index[f"{s}_hip"]]) for s in ("left", "right")]
        self.reset()

    def reset(self) -> None:
        self.tilt = 0.0  # xi of the paper: accumulated correction angle, radians
        self.straighten = 0.0  # accumulated share of knee and hip bending removed
        self._support = np.zeros((0, 2))  # m, the last corrected frame's support points: a relaxation turns about it

    def _state(self, qpos):
        d = self.data
        d.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        return (d.subtree_com[1].copy(), d.site_xpos[self.sites].copy(),
                d.site_xpos[self.neck] - d.site_xpos[self.pelvis])

    def correct(self, q_kin: np.ndarray, stationary: bool, contacts: np.ndarray) -> tuple[np.ndarray, bool]:
        """The corrected pose for this frame and whether a correction applied."""
        if not stationary or not contacts.reshape(2, 2).any(axis=1).all() or self._not_standing(q_kin):
            # Moving, on one foot (as often a slow step as a balance) or in the air: what was accumulated relaxes
            # about the last support. Dropped in one frame, it stepped the target by up to 19 cm at the head
            # (docs/decisions/physics-balance.md).
            if self.tilt == 0.0 and self.straighten == 0.0:
                return q_kin, False  # nothing to relax: no kinematics to compute
            return self._relaxed(q_kin, self._state(q_kin)[2], self._support)
        com, sites, spine = self._state(q_kin)
        support = sites[sole_support(contacts), :2]
        self._support = support
        if inside_support(com[:2], support, self.margin):
            # The pose as observed is balanced: a correction accumulated for an earlier, unbalanced one relaxes at
            # the rate it grew. Kept instead, one transient imbalance moved a person standing still for seconds
            # (docs/decisions/physics-balance.md).
            return self._relaxed(q_kin, spine, support)
        q = self._corrected(q_kin, spine, support)
        com, _, spine_now = self._state(q)
        if inside_support(com[:2], support, self.margin):
            return q, True  # balanced: keep the accumulated correction while the person stands still
        remaining = _angle_to_up(spine_now)
        if remaining > SMALL_LEAN:
            self.tilt += self.rate * remaining  # xi_{t+1} = xi_t + theta_t / 10
        elif self.straighten < 1.0:
            # PhysCap straightens knees and hips only while that brings the centre of mass nearer the support:
            # legs bent in a stance whose feet the fit misplaced in depth do not balance straightened, and the
            # straightening ran on to straight legs (docs/decisions/physics-balance.md)
            bend = self.straighten
            self.straighten = min(1.0, bend + self.rate)
            straighter = self._state(self._corrected(q_kin, spine, support))[0]
            if support_distance(straighter[:2], support) >= support_distance(com[:2], support):
                self.straighten = bend
        return q, True

    def _not_standing(self, q_kin: np.ndarray) -> bool:
        """Whether a knee of the pose (nq,) bends more than STANDING_BEND: a posture (seated, squatting) whose centre
        of mass a seat may hold, not a standing fit's lean (PhysCap 4.3.1 corrects standing poses)."""
        return max(abs(float(q_kin[knee])) for knee, _ in self.legs) > STANDING_BEND

    def _relaxed(self, q_kin: np.ndarray, spine: np.ndarray, support: np.ndarray) -> tuple[np.ndarray, bool]:
        """correct's return for a frame that needs no new correction: the accumulated one shrunk at the rate it grew
        and applied about `support` (k, 2), or dropped once invisible."""
        self.tilt *= 1.0 - self.rate
        self.straighten *= 1.0 - self.rate
        if (self.tilt < RELAXED and self.straighten < RELAXED) or not len(support):
            self.reset()
            return q_kin, False
        return self._corrected(q_kin, spine, support), True

    def _corrected(self, q_kin: np.ndarray, spine: np.ndarray, support: np.ndarray) -> np.ndarray:
        """q_kin (nq,) tilted upright by the accumulated angle (at most its lean, `spine` the neck - pelvis vector)
        about the middle of the `support` points (k, 2), then straightened."""
        q = q_kin
        axis = np.array([spine[1], -spine[0], 0.0])  # spine x WORLD_UP
        length = _norm(axis)
        if length > 1e-9 and self.tilt > 0.0:
            axis /= length
            tilt = min(self.tilt, _angle_to_up(spine))
            pivot = np.zeros(3)
            pivot[:2] = support.mean(axis=0)
            R = axis_angle_matrix(axis, np.array(tilt))
            q = rigid_transform_qpos(q[None], R, pivot - R @ pivot)[0]
        return self._straightened(q)

    def _straightened(self, qpos: np.ndarray) -> np.ndarray:
        """Knees and hips moved `straighten` of the way towards straight."""
        if self.straighten == 0.0:
            return qpos
        q = qpos.copy()
        keep = 1.0 - self.straighten
        for knee, hip in self.legs:
            q[knee] *= keep
            q[hip:hip + 4] = quat_exp(keep * quat_log(q[hip:hip + 4]))
        return q
