"""Inputs of the reduced (centroidal) model from a full-body motion: Rempe et al. 2020, section 3.3 and B.5.

Every body segment carries its de Leva (1996) mass and inertia (the BodyModel's); from the kinematic motion come
the centre of mass, the whole-body inertia tensor about it in the root's frame (time-varying: arms swing), the
root orientation standing for the COM orientation, the heel and toe positions, the hip joints of the legs
relative to the COM (for the leg-length constraint), and the torque the swinging limbs' angular momentum needs
beyond the single rigid body's (ours). World frame: Z up, floor z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..body import kinematics as kin
from ..body.model import CONTACT_POINTS, BodyModel

# The hip joint whose reach bounds each contact point (CONTACT_POINTS order).
CONTACT_HIPS: tuple[str, ...] = ("left_hip", "left_hip", "right_hip", "right_hip")


@dataclass
class ReducedMotion:
    """The reduced model's view of a motion of T frames.

    times: (T,) s from the first frame; com: (T, 3) m; rotation: (T, 3, 3) root orientation (body -> world);
    euler: (T, 3) the same as Z-Y-X Euler angles (yaw, pitch, roll), rad, unwrapped over time (see
    `euler_to_matrix`); inertia: (T, 3, 3) whole-body inertia about the COM in the root frame, kg m^2;
    feet: (T, 4, 3) heel and toe positions (CONTACT_POINTS order), m; hips: (T, 4, 3) the hip joint of each
    contact point's leg relative to the COM, in the root frame, m; mass: kg; foot_length: (2,) heel to toe of
    the left and right foot, m; leg_length: (4,) the farthest each contact point can be from its hip, m;
    internal_torque: (T, 3) N m, world frame: the rate of change of the motion's whole-body angular momentum about
    its COM that the reduced model's single rotating body does not produce (see `internal_torque`).
    """

    times: np.ndarray
    com: np.ndarray
    rotation: np.ndarray
    euler: np.ndarray
    inertia: np.ndarray
    feet: np.ndarray
    hips: np.ndarray
    mass: float
    foot_length: np.ndarray
    leg_length: np.ndarray
    internal_torque: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.times)

    def frames(self, sl: slice | np.ndarray) -> ReducedMotion:
        return ReducedMotion(self.times[sl], self.com[sl], self.rotation[sl], self.euler[sl], self.inertia[sl],
                             self.feet[sl], self.hips[sl], self.mass, self.foot_length, self.leg_length,
                             self.internal_torque[sl])


def euler_to_matrix(euler: np.ndarray) -> np.ndarray:
    """(..., 3) Z-Y-X Euler angles (yaw about z, then pitch about the new y, then roll about the new x) ->
    (..., 3, 3) rotation matrices R = Rz(yaw) Ry(pitch) Rx(roll)."""
    shape = euler.shape[:-1]
    return Rotation.from_euler("ZYX", euler.reshape(-1, 3)).as_matrix().reshape(shape + (3, 3))


def matrix_to_euler(rotation: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations -> (T, 3) Z-Y-X Euler angles, yaw and roll unwrapped along the first axis so that
    they change continuously (a person turning round keeps counting). Singular at pitch = +-90 degrees (the
    body horizontal), which standing, walking and dancing do not reach."""
    euler = Rotation.from_matrix(rotation).as_euler("ZYX")
    euler[:, 0] = np.unwrap(euler[:, 0])
    euler[:, 2] = np.unwrap(euler[:, 2])
    return euler


def world_inertia(body: BodyModel, pose: kin.Pose, com: np.ndarray) -> np.ndarray:
    """(T, 3, 3) whole-body inertia about `com` (T, 3) in the world frame: every segment's principal moments
    rotated into the world, plus its mass at its distance from the COM (parallel axis theorem)."""
    R = pose.rotations  # (T, B, 3, 3)
    masses = body.body_masses
    seg_com = pose.origins + np.einsum("tbij,bj->tbi", R, np.stack([b.com for b in body.bodies]))
    principal = np.stack([b.inertia for b in body.bodies])  # (B, 3)
    rotated = np.einsum("tbij,bj,tbkj->tik", R, principal, R)
    d = seg_com - com[:, None]
    parallel = (np.einsum("b,tbi,tbi->t", masses, d, d)[:, None, None] * np.eye(3)
                - np.einsum("b,tbi,tbj->tij", masses, d, d))
    return rotated + parallel


def _angular_velocity(rotation: np.ndarray, fps: float) -> np.ndarray:
    """(T, ...) world angular velocities, rad/s, of rotations (T, ..., 3, 3) by finite differences (R' R^T)."""
    W = np.einsum("t...ij,t...kj->t...ik", np.gradient(rotation, axis=0) * fps, rotation)
    return 0.5 * np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]],
                          axis=-1)


def internal_torque(body: BodyModel, pose: kin.Pose, com: np.ndarray, inertia_world: np.ndarray,
                    fps: float) -> np.ndarray:
    """(T, 3) N m: dL/dt - (I_w w' + w x I_w w) of a motion, world frame. L is the whole-body angular momentum
    about the COM (every segment's spin and its mass moving about the COM); the bracket the torque the reduced
    model's one rigid body needs, with the whole body's inertia I_w turning at the root's angular velocity w.
    The difference is what swinging legs and arms add (ours: the paper's reduced model omits it, so balancing
    the angular momentum of a walk's swinging leg needed contact points and a COM away from the observed ones).
    Finite differences of the motion; zeros for fewer than 3 frames."""
    if len(com) < 3:
        return np.zeros_like(com)
    R = pose.rotations  # (T, B, 3, 3)
    masses = body.body_masses
    seg_com = pose.origins + np.einsum("tbij,bj->tbi", R, np.stack([b.com for b in body.bodies]))
    principal = np.stack([b.inertia for b in body.bodies])  # (B, 3)
    spin = np.einsum("tbij,bj,tbkj,tbk->ti", R, principal, R, _angular_velocity(R, fps))
    d = seg_com - com[:, None]
    v = np.gradient(seg_com, axis=0) * fps - (np.gradient(com, axis=0) * fps)[:, None]
    momentum = spin + np.einsum("b,tbi->ti", masses, np.cross(d, v))
    w = _angular_velocity(R[:, 0], fps)
    rigid = np.einsum("tij,tj->ti", inertia_world, np.gradient(w, axis=0) * fps) + np.cross(
        w, np.einsum("tij,tj->ti", inertia_world, w))
    return np.gradient(momentum, axis=0) * fps - rigid


def leg_reach(body: BodyModel) -> np.ndarray:
    """(4,) the farthest each contact point can be from its hip joint: thigh + shank + the point's distance from
    the ankle (the leg straight, the foot turned towards the point), metres."""
    names = body.point_names
    out = np.empty(len(CONTACT_POINTS))
    L = body.lengths
    for k, name in enumerate(CONTACT_POINTS):
        side = name.split("_")[0]
        point = body.points[names.index(name)]
        ankle = body.points[names.index(f"{side}_ankle")]
        out[k] = L.thigh + L.shank + float(np.linalg.norm(point.offset - ankle.offset))
    return out


def foot_lengths(body: BodyModel) -> np.ndarray:
    """(2,) heel-to-toe distance of the left and right foot, metres."""
    names = body.point_names
    out = []
    for side in ("left", "right"):
        heel, toe = body.points[names.index(f"{side}_heel")], body.points[names.index(f"{side}_toe")]
        out.append(float(np.linalg.norm(toe.offset - heel.offset)))
    return np.array(out)


def reduced_motion(body: BodyModel, qpos: np.ndarray, fps: float, pose: kin.Pose | None = None) -> ReducedMotion:
    """The reduced model's inputs (B.5) from a full-body motion qpos (T, nq) in the floor's world frame; pose: its
    forward kinematics where the caller has them (None: computed here)."""
    pose = kin.forward_kinematics(body, qpos) if pose is None else pose
    com = kin.center_of_mass(body, pose)
    rotation = pose.rotations[:, 0]
    inertia_world = world_inertia(body, pose, com)
    inertia = np.einsum("tji,tjk,tkl->til", rotation, inertia_world, rotation)  # R^T I_w R
    feet = pose.points[:, body.point_index(CONTACT_POINTS)]
    hips_world = pose.points[:, body.point_index(CONTACT_HIPS)] - com[:, None]
    hips = np.einsum("tji,tkj->tki", rotation, hips_world)  # R^T (hip - com)
    return ReducedMotion(np.arange(len(qpos)) / fps, com, rotation, matrix_to_euler(rotation),
                         0.5 * (inertia + inertia.transpose(0, 2, 1)), feet, hips, float(body.mass),
                         foot_lengths(body), leg_reach(body), internal_torque(body, pose, com, inertia_world, fps))


def boundary_velocity(com: np.ndarray, fps: float, seconds: float, end: bool) -> np.ndarray:
    """(3,) mean COM velocity (m/s) over the first (or last) `seconds` of com (T, 3), at least one frame interval
    (Rempe C.2: 5 frames at 30 fps; in seconds, so that a low frame rate does not average over longer)."""
    n = min(max(1, int(round(seconds * fps))), len(com) - 1)
    if n < 1:
        return np.zeros(3)
    segment = com[-n - 1:] if end else com[:n + 1]
    return (segment[-1] - segment[0]) * fps / n
