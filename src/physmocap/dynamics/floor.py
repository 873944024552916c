"""Causal floor refinement for the online physics.

The online fit places the floor once, from its warm-up (a few seconds in which a person standing still gives
clustered foot points and a poorly determined tilt). The physics then holds the feet on that plane, so a tilt of
2-5 degrees puts them centimetres under the true floor. `FloorRefiner` keeps fitting the floor to the kinematic
sole points that the contact stage reports in contact, as frames arrive, and moves its estimate towards each new
fit at a limited rate. The physics runs in the refined frame, where the floor is z = 0; `to_physics` and
`to_kinematic` map poses between it and the kinematic world, `vector_to_kinematic` forces.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..body.model import CONTACT_POINTS, BodyModel
from ..camera import WORLD_UP, fit_floor

MIN_POINTS = 40  # contact points before a refit: ten frames of both feet flat on the floor
TILT_PRIOR = 0.01  # fit_floor's pull towards the warm-up's floor, weaker than the warm-up's own 0.05 (which kept
# 0.4 of a 3 degree tilt over 2 m of walking): on the synthetic set PNP 88.1% -> 89.8%, MPE 36.6 -> 37.9 mm
MAX_POINTS = 4000  # kept points; beyond, every other one is dropped (the whole history stays covered, thinner)


def floor_frame(normal: np.ndarray, offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(R, shift, quat): the rigid map x -> R x + shift taking the plane normal . x + offset = 0 (normal near
    up) to z = 0, the plane's point nearest the origin to the origin, with the smallest rotation; quat is R's
    quaternion (w, x, y, z). Scalar MuJoCo calls: it runs every frame while the online floor turns."""
    quat, rotation = np.zeros(4), np.zeros(9)
    mujoco.mju_quatZ2Vec(quat, normal)  # the smallest rotation taking up to the normal; R is its inverse
    mujoco.mju_negQuat(quat, quat)
    mujoco.mju_quat2Mat(rotation, quat)
    rotation = rotation.reshape(3, 3)
    return rotation, rotation @ (offset * normal), quat


class FloorRefiner:
    """The floor plane n . x + d = 0 in the kinematic world (starting at z = 0), refined from contact points.

    refit_interval: s between robust refits; first_refit: s of frames before the first (the warm-up placed the
    floor from as many); tilt_rate: rad/s and lift_rate: m/s, the fastest the estimate moves towards a new fit
    (the physics sees its targets move, so it must be gentle); keep_tilt: refine the height only, for a warm-up
    floor that was not trusted and was levelled with the posture instead (its feet's plane leant from it)."""

    def __init__(self, body: BodyModel, fps: float, refit_interval: float, tilt_rate: float, lift_rate: float,
                 first_refit: float, keep_tilt: bool = False):
        self.model = body.mujoco_model()
        self.data = mujoco.MjData(self.model)
        self.sites = np.array([self.model.site(n).id for n in CONTACT_POINTS])
        self.refit_frames = max(1, round(refit_interval * fps))
        self.first_refit = round(first_refit * fps)
        self.max_turn, self.max_lift = tilt_rate / fps, lift_rate / fps
        self.keep_tilt = keep_tilt
        self.normal, self.offset = WORLD_UP.copy(), 0.0  # the current estimate
        self.fitted_normal, self.fitted_offset = WORLD_UP.copy(), 0.0  # the latest fit, approached at the rates above
        self._points = np.empty((MAX_POINTS, 3))
        self._point_frames = np.empty(MAX_POINTS, int)  # the frame each point came from
        self._count = self._frames = 0
        self._previous_contacts = np.zeros(len(CONTACT_POINTS), bool)
        self.rotation, self.shift = np.eye(3), np.zeros(3)  # kinematic world -> physics frame: x' = R x + shift
        self.quat, self.inverse_quat = np.array([1.0, 0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0, 0.0])  # of R, R'

    def push(self, q_kin: np.ndarray, contacts: np.ndarray) -> None:
        """Add a frame's kinematic pose (nq,) and its predicted contacts (4,); refit and step the estimate. A
        point is evidence of the floor from the second frame of its contact on: a landing foot is still moving,
        and a lone detection between frames without a person (whose contacts have no neighbour) can be anywhere
        (on one video 12 m behind the person, which lifted the floor 0.5 m over the standing feet)."""
        resting = contacts & self._previous_contacts
        self._previous_contacts = contacts.copy()
        if resting.any():
            self.data.qpos[:] = q_kin
            mujoco.mj_kinematics(self.model, self.data)
            points = self.data.site_xpos[self.sites[resting]]
            if self._count + len(points) > MAX_POINTS:
                kept, kept_frames = self._points[:self._count:2], self._point_frames[:self._count:2]
                self._count = len(kept)
                self._points[:self._count], self._point_frames[:self._count] = kept, kept_frames
            self._points[self._count:self._count + len(points)] = points
            self._point_frames[self._count:self._count + len(points)] = self._frames
            self._count += len(points)
        self._frames += 1
        if (self._frames >= self.first_refit and self._frames % self.refit_frames == 0
                and self._count >= MIN_POINTS):
            self._refit()
        self._step()

    def _refit(self) -> None:
        """The latest fit: the tilt of a robust plane through every contact point kept, its height under the feet,
        the median over frames of each frame's lowest point lying on it. The character's feet cannot sink, so a
        floor through the middle of a fit's contact points held the body up by their spread (10-15 mm on real
        videos, against the image; docs/decisions/physics-online-support.md)."""
        points, frames = self._points[:self._count], self._point_frames[:self._count]
        if self.keep_tilt:  # the feet that leant the warm-up's plane would lean this one too
            normal, offset = WORLD_UP, 0.0
        else:
            floor, _ = fit_floor(points, WORLD_UP, prior_weight=TILT_PRIOR)
            normal, offset = floor.normal, floor.offset
        first_of_frame = np.flatnonzero(np.diff(frames, prepend=-1))  # kept in the order they came
        lowest = np.minimum.reduceat(points @ normal + offset, first_of_frame)
        self.fitted_normal, self.fitted_offset = normal, offset - float(np.median(lowest))

    def _step(self) -> None:
        """Move the estimate towards the latest fit by at most max_turn and max_lift, and update the map."""
        if self.offset == self.fitted_offset and np.array_equal(self.normal, self.fitted_normal):
            return  # settled (or nothing fitted yet): most frames
        axis = np.zeros(3)
        mujoco.mju_cross(axis, self.normal, self.fitted_normal)
        sine = mujoco.mju_normalize3(axis)
        if np.arcsin(min(sine, 1.0)) <= self.max_turn:  # the two stay within a few degrees of up
            self.normal = self.fitted_normal.copy()
        else:
            turn, turned = np.zeros(4), np.zeros(3)
            mujoco.mju_axisAngle2Quat(turn, axis, self.max_turn)
            mujoco.mju_rotVecQuat(turned, self.normal, turn)
            self.normal = turned
        lift = self.fitted_offset - self.offset  # arriving exactly, so that the next frame finds it settled
        if abs(lift) <= self.max_lift:
            self.offset = self.fitted_offset
        else:
            self.offset += np.copysign(self.max_lift, lift)
        self.rotation, self.shift, self.quat = floor_frame(self.normal, self.offset)
        mujoco.mju_negQuat(self.inverse_quat, self.quat)

    # ---- maps between the kinematic world and the physics frame ---------------------------------------------
    # Per frame, so MuJoCo's quaternion functions rather than the batched rigid_transform_qpos (0.7 ms a call).
    def to_physics(self, qpos: np.ndarray) -> np.ndarray:
        """A pose (nq,) of the kinematic world in the physics frame."""
        out = qpos.copy()
        out[:3] = self.rotation @ qpos[:3] + self.shift
        mujoco.mju_mulQuat(out[3:7], self.quat, qpos[3:7])
        return out

    def to_kinematic(self, qpos: np.ndarray) -> np.ndarray:
        """A pose (nq,) of the physics frame in the kinematic world."""
        out = qpos.copy()
        out[:3] = self.rotation.T @ (qpos[:3] - self.shift)
        mujoco.mju_mulQuat(out[3:7], self.inverse_quat, qpos[3:7])
        return out

    @property
    def plane(self) -> np.ndarray:
        """(4,) the current estimate n . x + d = 0 in the kinematic world."""
        return np.append(self.normal, self.offset)

    def vector_to_kinematic(self, vectors: np.ndarray) -> np.ndarray:
        """(..., 3) forces or directions of the physics frame in the kinematic world."""
        return vectors @ self.rotation

    def wrench_to_kinematic(self, forces: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Contact forces (4, 3) N and root residual (6,) (force N, torque N m in the pelvis frame) of the physics
        frame in the kinematic world, new arrays: the forces turn, the pelvis-frame torque does not."""
        return self.vector_to_kinematic(forces), np.concatenate([self.vector_to_kinematic(residual[:3]), residual[3:]])
