"""Rotation kernels: the derivative of the log against finite differences."""

import numpy as np
import pytest

from physmocap.body.rotations import (
    quat_exp,
    quat_log,
    quat_multiply,
    so3_right_jacobian_inverse,
    unwrap_rotation_vectors,
)

AXIS = np.array([0.36, -0.48, 0.8])


@pytest.mark.parametrize("angle", [1e-8, 0.3, 2.0, np.pi - 1e-3, 3.4, 5.0])
def test_right_jacobian_inverse_matches_finite_differences(angle):
    """d log(exp(phi) exp(delta)) / d delta at delta = 0, by central differences of quat_log, on phi's branch of
    the log past a half turn (the unwrapped vectors of the fit's joint-angle velocity term)."""
    phi = angle * AXIS
    q = quat_exp(phi)
    J = so3_right_jacobian_inverse(phi)
    eps = 1e-7
    for k in range(3):
        step = np.zeros(3)
        step[k] = eps
        plus, minus = (unwrap_rotation_vectors(np.stack([phi, quat_log(quat_multiply(q, quat_exp(s * step)))]))[1]
                       for s in (1.0, -1.0))
        assert np.allclose((plus - minus) / (2 * eps), J[:, k], atol=1e-6)


def test_unwrapped_rotation_vectors_step_through_a_half_turn():
    """A joint turning steadily from 2.9 to 3.4 rad about one axis: quat_log wraps at pi (the vector flips to the
    other side), the unwrapped vectors keep the rotation's own steps and the same rotations."""
    axis = np.array([0.0, 0.6, 0.8])
    angles = np.linspace(2.9, 3.4, 11)
    wrapped = quat_log(quat_exp(angles[:, None] * axis))[:, None]  # (T, 1, 3): one joint
    assert np.linalg.norm(np.diff(wrapped, axis=0), axis=-1).max() > 6.0
    unwrapped = unwrap_rotation_vectors(wrapped)
    np.testing.assert_allclose(unwrapped[:, 0], angles[:, None] * axis, atol=1e-9)
    same = quat_multiply(quat_exp(unwrapped), quat_exp(-wrapped))
    np.testing.assert_allclose(np.abs(same[..., 0]), 1.0, atol=1e-9)
