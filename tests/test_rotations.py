"""Rotation kernels: the derivative of the log against finite differences."""

import numpy as np
import pytest

from physmocap.body.rotations import quat_exp, quat_log, quat_multiply, so3_right_jacobian_inverse

AXIS = np.array([0.36, -0.48, 0.8])


@pytest.mark.parametrize("angle", [1e-8, 0.3, 2.0, np.pi - 1e-3])
def test_right_jacobian_inverse_matches_finite_differences(angle):
    """d log(exp(phi) exp(delta)) / d delta at delta = 0, by central differences of quat_log."""
    phi = angle * AXIS
    q = quat_exp(phi)
    J = so3_right_jacobian_inverse(phi)
    eps = 1e-7
    for k in range(3):
        step = np.zeros(3)
        step[k] = eps
        plus, minus = (quat_log(quat_multiply(q, quat_exp(s * step))) for s in (1.0, -1.0))
        assert np.allclose((plus - minus) / (2 * eps), J[:, k], atol=1e-6)
