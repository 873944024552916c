import numpy as np
import pytest
from pathlib import Path

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
