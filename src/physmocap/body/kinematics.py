"""Forward kinematics, point Jacobians and manifold updates, batched over frames with numpy.

These kernels are the body model's own kinematics; tests check them against the compiled MuJoCo model and
against finite differences on the manifold. Shapes: T frames, B bodies, P points, nq/nv as in MuJoCo.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .model import BodyModel
from .rotations import (
    axis_angle_matrix,
    matrix_to_quat,
    quat_conjugate,
    quat_exp,
    quat_log,
    quat_multiply,
    quat_to_matrix,
)


@dataclass
class Tables:
    """Index arrays derived once from a BodyModel."""

    parent: np.ndarray  # (B,)
    offset: np.ndarray  # (B, 3)
    qadr: np.ndarray  # (B,)
    vadr: np.ndarray  # (B,)
    kind: tuple[str, ...]  # (B,)
    axis: np.ndarray  # (B, 3) hinge axes (zeros elsewhere)
    point_body: np.ndarray  # (P,)
    point_offset: np.ndarray  # (P, 3)
    dof_body: np.ndarray  # (nv,)
    dof_column: np.ndarray  # (nv,) which body axis a rotational dof turns about (0..2), -1 for hinge/linear
    influences: np.ndarray  # (P, nv) bool: the dof moves the point
    ball_bodies: np.ndarray  # bodies with ball joints
    hinge_bodies: np.ndarray  # bodies with hinge joints


@lru_cache(maxsize=16)
def tables(model: BodyModel) -> Tables:
    B = len(model.bodies)
    kind = tuple(b.joint_type for b in model.bodies)
    axis = np.zeros((B, 3))
    for i, b in enumerate(model.bodies):
        if b.axis is not None:
            axis[i] = b.axis
    dof_column = np.full(model.nv, -1)
    for i, b in enumerate(model.bodies):
        a = model.dof_address[i]
        if b.joint_type == "free":
            dof_column[a + 3:a + 6] = [0, 1, 2]
        elif b.joint_type == "ball":
            dof_column[a:a + 3] = [0, 1, 2]
    point_body = np.array([p.body for p in model.points])
    influences = model.ancestors[point_body][:, model.dof_body]
    return Tables(
        parent=np.array([b.parent for b in model.bodies]),
        offset=np.stack([b.offset for b in model.bodies]),
        qadr=model.qpos_address,
        vadr=model.dof_address,
        kind=kind,
        axis=axis,
        point_body=point_body,
        point_offset=np.stack([p.offset for p in model.points]),
        dof_body=model.dof_body,
        dof_column=dof_column,
        influences=influences,
        ball_bodies=np.array([i for i, k in enumerate(kind) if k == "ball"]),
        hinge_bodies=np.array([i for i, k in enumerate(kind) if k == "hinge"]),
    )


@dataclass
class Pose:
    """Forward kinematics of T frames.

    rotations: (T, B, 3, 3) body orientations in the world; origins: (T, B, 3) joint centres;
    points: (T, P, 3) every named point of the model.
    """

    rotations: np.ndarray
    origins: np.ndarray
    points: np.ndarray


def forward_kinematics(model: BodyModel, qpos: np.ndarray) -> Pose:
    """qpos (T, nq) -> Pose."""
    tab = tables(model)
    qpos = np.atleast_2d(qpos)
    T, B = len(qpos), len(tab.parent)
    R = np.empty((T, B, 3, 3))
    p = np.empty((T, B, 3))
    for b in range(B):
        a = tab.qadr[b]
        if tab.kind[b] == "free":
            quat = qpos[:, a + 3:a + 7]
            R[:, b] = quat_to_matrix(quat / np.linalg.norm(quat, axis=1, keepdims=True))
            p[:, b] = qpos[:, a:a + 3]
            continue
        parent_R = R[:, tab.parent[b]]
        p[:, b] = p[:, tab.parent[b]] + parent_R @ tab.offset[b]
        if tab.kind[b] == "ball":
            quat = qpos[:, a:a + 4]
            local = quat_to_matrix(quat / np.linalg.norm(quat, axis=1, keepdims=True))
        else:
            local = axis_angle_matrix(tab.axis[b], qpos[:, a])
        R[:, b] = parent_R @ local
    points = p[:, tab.point_body] + np.einsum("tpij,pj->tpi", R[:, tab.point_body], tab.point_offset)
    return Pose(R, p, points)


def dof_axes(model: BodyModel, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """World axes (T, nv, 3) and anchors (T, nv, 3) of every rotational dof; zero axes for the root's
    translation dofs."""
    tab = tables(model)
    R = pose.rotations[:, tab.dof_body]  # (T, nv, 3, 3)
    axes = np.zeros(R.shape[:2] + (3,))
    rot = tab.dof_column >= 0
    axes[:, rot] = np.einsum("tnij,nj->tni", R[:, rot], np.eye(3)[tab.dof_column[rot]])
    hinge = tab.vadr[tab.hinge_bodies]
    axes[:, hinge] = np.einsum("tbij,bj->tbi", pose.rotations[:, tab.hinge_bodies], tab.axis[tab.hinge_bodies])
    return axes, pose.origins[:, tab.dof_body]


def point_jacobian(model: BodyModel, pose: Pose, point_ids: np.ndarray) -> np.ndarray:
    """d(point positions)/d(velocity) for the chosen points: (T, len(point_ids), 3, nv).

    Columns are the world axis of each dof crossed with the lever arm from the joint; the root's three
    translation dofs map one to one."""
    tab = tables(model)
    axes, anchors = dof_axes(model, pose)
    pts = pose.points[:, point_ids]  # (T, n, 3)
    lever = pts[:, :, None, :] - anchors[:, None, :, :]  # (T, n, nv, 3)
    cols = np.cross(axes[:, None], lever) * tab.influences[point_ids][None, :, :, None]
    J = np.moveaxis(cols, 3, 2)  # (T, n, 3, nv)
    J[:, :, 0, 0] = J[:, :, 1, 1] = J[:, :, 2, 2] = 1.0
    return J


def integrate(model: BodyModel, qpos: np.ndarray, dv: np.ndarray) -> np.ndarray:
    """qpos (T, nq) moved by velocity-space steps dv (T, nv) on the manifold (like mj_integratePos, dt = 1)."""
    tab = tables(model)
    qpos = np.array(np.atleast_2d(qpos), dtype=float)
    dv = np.atleast_2d(dv)
    qpos[:, 0:3] += dv[:, 0:3]
    q = qpos[:, 3:7]
    q = quat_multiply(q, quat_exp(dv[:, 3:6]))
    qpos[:, 3:7] = q / np.linalg.norm(q, axis=1, keepdims=True)
    qa, va = tab.qadr[tab.ball_bodies], tab.vadr[tab.ball_bodies]
    quats = qpos[:, qa[:, None] + np.arange(4)]
    steps = dv[:, va[:, None] + np.arange(3)]
    quats = quat_multiply(quats, quat_exp(steps))
    qpos[:, qa[:, None] + np.arange(4)] = quats / np.linalg.norm(quats, axis=2, keepdims=True)
    qpos[:, tab.qadr[tab.hinge_bodies]] += dv[:, tab.vadr[tab.hinge_bodies]]
    return qpos


def difference(model: BodyModel, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Velocity-space difference dv (T, nv) with integrate(qa, dv) == qb (like mj_differentiatePos, dt = 1)."""
    tab = tables(model)
    qa, qb = np.atleast_2d(qa), np.atleast_2d(qb)
    dv = np.empty((len(qa), model.nv))
    dv[:, 0:3] = qb[:, 0:3] - qa[:, 0:3]
    dv[:, 3:6] = quat_log(quat_multiply(quat_conjugate(qa[:, 3:7]), qb[:, 3:7]))
    qadr, vadr = tab.qadr[tab.ball_bodies], tab.vadr[tab.ball_bodies]
    idx = qadr[:, None] + np.arange(4)
    rel = quat_multiply(quat_conjugate(qa[:, idx]), qb[:, idx])
    dv[:, vadr[:, None] + np.arange(3)] = quat_log(rel)
    dv[:, tab.vadr[tab.hinge_bodies]] = qb[:, tab.qadr[tab.hinge_bodies]] - qa[:, tab.qadr[tab.hinge_bodies]]
    return dv


def ball_rotation_vectors(model: BodyModel, qpos: np.ndarray) -> np.ndarray:
    """(T, n_ball, 3) rotation vectors of the ball joints relative to the rest pose."""
    tab = tables(model)
    idx = tab.qadr[tab.ball_bodies][:, None] + np.arange(4)
    return quat_log(np.atleast_2d(qpos)[:, idx])


def center_of_mass(model: BodyModel, pose: Pose) -> np.ndarray:
    """(T, 3) whole-body centre of mass."""
    com = pose.origins + np.einsum("tbij,bj->tbi", pose.rotations, np.stack([b.com for b in model.bodies]))
    return np.einsum("tbi,b->ti", com, model.body_masses) / model.mass


# Each body's segment as two named points its centre of mass lies on (or near): joint to joint, the hand along its
# forearm, the foot along its sole (heel to toe).
SEGMENT_POINTS: dict[str, tuple[str, str]] = {
    "pelvis": ("pelvis", "spine"), "torso": ("spine", "neck"), "head": ("neck", "head"),
    **{f"{side}_{body}": (f"{side}_{a}", f"{side}_{b}") for side in ("left", "right")
       for body, a, b in (("upper_arm", "shoulder", "elbow"), ("forearm", "elbow", "wrist"),
                          ("hand", "elbow", "wrist"), ("thigh", "hip", "knee"), ("shin", "knee", "ankle"),
                          ("foot", "heel", "toe"))},
}


def center_of_mass_point_weights(model: BodyModel) -> dict[str, float]:
    """Weights (summing to 1) of the model's named points whose weighted sum is its whole-body centre of mass, to
    about a millimetre: every body carries its (de Leva) mass at the fraction along its segment (SEGMENT_POINTS)
    where its own centre of mass projects in the rest pose (the feet's and hands' centres off their lines are
    ignored)."""
    rest = forward_kinematics(model, model.rest_qpos[None])
    rest_com = rest.origins[0] + np.einsum("bij,bj->bi", rest.rotations[0], np.stack([b.com for b in model.bodies]))
    weights: dict[str, float] = {}
    for b, body in enumerate(model.bodies):
        a, c = SEGMENT_POINTS[body.name]
        pa, pc = rest.points[0, model.point_index([a, c])]
        fraction = float((rest_com[b] - pa) @ (pc - pa) / ((pc - pa) @ (pc - pa)))
        weights[a] = weights.get(a, 0.0) + body.mass * (1 - fraction) / model.mass
        weights[c] = weights.get(c, 0.0) + body.mass * fraction / model.mass
    return weights


def center_of_mass_from_points(model: BodyModel, points: np.ndarray, names) -> np.ndarray:
    """(T, 3) whole-body centre of mass of a skeleton known only by its joint positions (e.g. motion capture), by
    `center_of_mass_point_weights`. points: (T, P, 3) named `names` (the model's joint and contact point names,
    any order)."""
    names = [str(n) for n in names]
    total = np.zeros(points.shape[:1] + (3,))
    for name, weight in center_of_mass_point_weights(model).items():
        total += weight * points[:, names.index(name)]
    return total


def rigid_transform_qpos(qpos: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Move whole poses by x -> R x + t (the root's position and orientation; joints are relative)."""
    out = qpos.copy()
    out[:, 0:3] = qpos[:, 0:3] @ R.T + t
    out[:, 3:7] = quat_multiply(matrix_to_quat(R)[None], qpos[:, 3:7])
    return out
