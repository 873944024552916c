from pathlib import Path

import numpy as np
import pytest

import physmocap  # noqa: F401 - single-threaded BLAS before numpy work
from physmocap.body import kinematics as kin
from physmocap.body.model import build_body_model, template_lengths

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
DEMO_VIDEO = REPO / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4"


@pytest.fixture(scope="session")
def body():
    return build_body_model(template_lengths(1.75), 72.0)


def random_poses(body, count, rng, scale=0.4):
    """Random poses around the rest pose, moved on the manifold."""
    q = np.repeat(body.rest_qpos[None], count, axis=0)
    return kin.integrate(body, q, rng.normal(scale=scale, size=(count, body.nv)))


def assert_frame_terms_jacobian(fitter, q, targets, atol=2e-6):
    """The fitter's per-frame residual Jacobian against central finite differences on the manifold."""
    r, J = fitter.frame_terms(q, *fitter.evaluate(q), targets)
    eps = 1e-6
    for k in range(J.shape[-1]):
        step = np.zeros((len(q), J.shape[-1]))
        step[:, k] = eps
        qp, qm = fitter.integrate(q, step), fitter.integrate(q, -step)
        rp, _ = fitter.frame_terms(qp, *fitter.evaluate(qp), targets)
        rm, _ = fitter.frame_terms(qm, *fitter.evaluate(qm), targets)
        assert np.allclose((rp - rm) / (2 * eps), J[..., k], atol=atol), k


# Hypothesis (tests/test_fuzz.py): "ci" by default; `pytest --hypothesis-profile=long` for a deeper search.
try:
    from hypothesis import settings as _hypothesis_settings

    _hypothesis_settings.register_profile("ci", max_examples=100, deadline=None, derandomize=True)
    _hypothesis_settings.register_profile("long", max_examples=1000, deadline=None)
    _hypothesis_settings.load_profile("ci")
except ImportError:  # hypothesis is a test dependency; only test_fuzz.py needs it
    pass
