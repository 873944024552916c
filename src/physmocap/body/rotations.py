"""Batched rotation kernels on numpy arrays. Quaternions are (w, x, y, z), MuJoCo's order."""

from __future__ import annotations

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    out = np.empty(q.shape[:-1] + (3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions with w >= 0."""
    from scipy.spatial.transform import Rotation

    shape = R.shape[:-2]
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(shape + (4,))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b, batched over leading axes."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_left_matrix(p: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 4, 4) matrices L with L @ q == quat_multiply(p, q)."""
    w, x, y, z = np.moveaxis(p, -1, 0)
    rows = [[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_exp(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 4) unit quaternions."""
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(half)/angle, with its series near zero
    small = angle < 1e-8
    scale = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(half), rotvec * scale], axis=-1)


def quat_log(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3) rotation vectors of angle in [0, pi]."""
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    vec = q[..., 1:]
    sin_half = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, np.clip(q[..., :1], -1.0, 1.0))
    small = sin_half < 1e-8
    scale = np.where(small, 2.0 / np.clip(q[..., :1], 1e-12, None), angle / np.where(small, 1.0, sin_half))
    return vec * scale


def axis_angle_matrix(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices about a fixed unit `axis` (3,) by `angle` (...,) radians -> (..., 3, 3)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def rotation_between(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector `source` to unit vector `target` (not opposite)."""
    axis = np.cross(source, target)
    cos = float(source @ target)
    skew = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + skew + skew @ skew / (1.0 + cos)


def unwrap_rotation_vectors(rotvec: np.ndarray) -> np.ndarray:
    """(T, ..., 3) rotation vectors along time -> the same rotations, each frame's vector on the branch of the log
    (phi + 2 pi k phi / |phi|, k in -1, 0, 1) nearest the previous frame's: differences are the rotation's own steps
    where it passes a half turn, instead of jumps of up to 2 pi."""
    out = np.array(rotvec, dtype=float)
    axis = unit_vectors(out)
    turns = 2 * np.pi * np.array([-1.0, 0.0, 1.0]).reshape((3,) + (1,) * (out.ndim - 1))
    for t in range(1, len(out)):
        branches = out[t] + turns * axis[t]  # (3, ..., 3)
        nearest = np.argmin(np.linalg.norm(branches - out[t - 1], axis=-1), axis=0)
        out[t] = np.take_along_axis(branches, nearest[None, ..., None], axis=0)[0]
    return out


def so3_right_jacobian_inverse(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3): d log(exp(phi) exp(delta)) / d delta at delta = 0."""
    angle = np.linalg.norm(rotvec, axis=-1)[..., None, None]
    K = np.zeros(rotvec.shape[:-1] + (3, 3))
    x, y, z = np.moveaxis(rotvec, -1, 0)
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 0] = -z, y, z
    K[..., 1, 2], K[..., 2, 0], K[..., 2, 1] = -x, -y, x
    small = angle < 1e-6
    safe = np.where(small, 1.0, angle)
    coeff = np.where(small, 1.0 / 12.0, 1.0 / safe**2 - (1 + np.cos(safe)) / (2 * safe * np.sin(safe)))
    return np.eye(3) + 0.5 * K + coeff * (K @ K)


def unit_vectors(v: np.ndarray) -> np.ndarray:
    """(..., 3) vectors scaled to length 1 along the last axis (zero vectors stay near zero)."""
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def is_rotation(R: np.ndarray, tolerance: float) -> bool:
    """Whether the (3, 3) matrix R is a proper rotation: orthonormal to `tolerance` (largest entry of R R' - I)
    and not a reflection."""
    return bool(np.abs(R @ R.T - np.eye(3)).max() <= tolerance and np.linalg.det(R) > 0)
