"""The physics stage: the PhysCap tracker run over a kinematic motion, frame by frame."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..body import kinematics as kin
from ..body.model import BodyModel
from ..config import PhysicsSettings
from .balance import BalanceCorrector
from .physcap import PhysCapTracker


@dataclass
class PhysicsMotion:
    """qpos: (T, nq) physically tracked motion; grf: (T, 4, 3) N per contact point (l heel, l toe, r heel,
    r toe), world frame; residual: (T, 6) direct root actuation (force N in the world, torque N m in the pelvis
    frame); contacts: (T, 4) contacts in use; corrected: (T,) frames whose pose the balance correction changed;
    qp_failures: (T,) integration steps whose QP failed and fell back; seconds: time spent."""

    qpos: np.ndarray
    grf: np.ndarray
    residual: np.ndarray
    contacts: np.ndarray
    corrected: np.ndarray
    qp_failures: np.ndarray
    seconds: float


def kinematic_derivatives(body: BodyModel, qpos: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Causal (backward) finite differences on the manifold: velocities and accelerations (T, nv)."""
    velocity = np.zeros((len(qpos), body.nv))
    velocity[1:] = kin.difference(body, qpos[:-1], qpos[1:]) * fps
    acceleration = np.zeros_like(velocity)
    acceleration[2:] = np.diff(velocity[1:], axis=0) * fps
    return velocity, acceleration


def run_physcap(body: BodyModel, qpos_kin: np.ndarray, fps: float, contacts: np.ndarray, stationary: np.ndarray,
                settings: PhysicsSettings, progress=None) -> PhysicsMotion:
    """Track the kinematic motion (T, nq) with the physics character; contacts (T, 4) and stationary (T,)
    come from the contact stage. Causal: frame t uses frames up to t only."""
    start = time.perf_counter()
    T = len(qpos_kin)
    velocity, acceleration = kinematic_derivatives(body, qpos_kin, fps)
    tracker = PhysCapTracker(body, settings, fps)
    balance = BalanceCorrector(body, settings.correction_rate)
    tracker.reset(qpos_kin[0], velocity[0])
    out = PhysicsMotion(np.empty_like(qpos_kin), np.zeros((T, 4, 3)), np.zeros((T, 6)), np.zeros((T, 4), bool),
                        np.zeros(T, bool), np.zeros(T, int), 0.0)
    for t in range(T):
        target = qpos_kin[t]
        if settings.balance_correction:
            target, out.corrected[t] = balance.correct(target, bool(stationary[t]), contacts[t])
        frame = tracker.track(target, velocity[t], acceleration[t], contacts[t])
        out.qpos[t] = tracker.qpos
        out.grf[t], out.residual[t], out.contacts[t], out.qp_failures[t] = (
            frame.contact_forces, frame.residual, frame.active, frame.qp_failures)
        if progress:
            progress(t + 1, T)
    out.seconds = time.perf_counter() - start
    return out
