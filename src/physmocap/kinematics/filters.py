"""One-Euro filter (Casiez, Roussel and Vogel 2012) on poses, applied in the velocity space of the manifold."""

from __future__ import annotations

import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel


def _alpha(cutoff: np.ndarray, rate: float) -> np.ndarray:
    tau = 1.0 / (2 * np.pi * cutoff)
    return 1.0 / (1.0 + tau * rate)


def one_euro_qpos(body: BodyModel, qpos: np.ndarray, fps: float, min_cutoff: float = 1.5, beta: float = 0.3,
                  derivative_cutoff: float = 1.0) -> np.ndarray:
    """Filter a pose sequence (T, nq) causally. Cutoffs in Hz; beta in 1/(unit of the dof's speed).

    Each degree of freedom gets its own adaptive cutoff: slow motion is smoothed hard (no jitter), fast
    motion passes with little lag. Orientations are filtered on the manifold, never per quaternion component.
    """
    out = np.array(qpos, dtype=float)
    speed = np.zeros(body.nv)
    for t in range(1, len(qpos)):
        step = kin.difference(body, out[t - 1:t], qpos[t:t + 1])[0]  # towards the new measurement
        a_d = _alpha(np.full(body.nv, derivative_cutoff), fps)
        speed = a_d * step * fps + (1 - a_d) * speed
        a = _alpha(min_cutoff + beta * np.abs(speed), fps)
        out[t] = kin.integrate(body, out[t - 1:t], (a * step)[None])[0]
    return out
