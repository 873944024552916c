"""Foot-lock: which foot points may be in contact before physics runs, the control users know from commercial
tools. The offline pipeline and live capture both go through `lock_feet`.

- "auto": the contacts the contact stage predicted;
- "always": every foot point (left heel, left toe, right heel, right toe) within the contact height of the floor,
  whatever was predicted: for motion that stays on the ground (standing, slow walking, work on the spot);
- "never": no contact at all: for airborne or swimming motion, where the floor must never pull a foot down.
"""

from __future__ import annotations

import numpy as np

from ..body.kinematics import forward_kinematics
from ..body.model import CONTACT_POINTS, BodyModel
from ..config import PhysicsSettings
from ..errors import InputError

FOOT_LOCK_MODES: tuple[str, ...] = ("auto", "always", "never")


def foot_point_heights(body: BodyModel, qpos: np.ndarray) -> np.ndarray:
    """(T, 4) heights above the floor z = 0, metres, of the contact points (CONTACT_POINTS order) of the motion
    qpos (T, nq) in the world frame."""
    points = forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)]
    return points[..., 2]


def foot_lock(predicted: np.ndarray, heights: np.ndarray, mode: str, contact_height: float) -> np.ndarray:
    """Contact flags (T, 4) to hand to physics, for the foot-lock `mode` (see the module docstring).

    predicted: (T, 4) bool, the contact stage's flags (left heel, left toe, right heel, right toe).
    heights: (T, 4) metres above the floor of the same points (e.g. `foot_point_heights` of the kinematic motion).
    contact_height: metres; "always" sets a point's flag while the point is at most this high
    (physics.contact_height, the same threshold the tracker applies to predicted contacts).
    """
    predicted = np.asarray(predicted, dtype=bool)
    heights = np.asarray(heights, dtype=float)
    if mode not in FOOT_LOCK_MODES:
        raise InputError(f"foot-lock must be one of {', '.join(FOOT_LOCK_MODES)}, got '{mode}'.")
    if predicted.ndim != 2 or predicted.shape[1] != len(CONTACT_POINTS) or heights.shape != predicted.shape:
        raise ValueError(f"predicted and heights must both have shape (T, 4), got {predicted.shape} and "
                         f"{heights.shape}.")
    if mode == "auto":
        return predicted.copy()
    if mode == "always":
        return heights <= contact_height
    return np.zeros_like(predicted)


def lock_feet(predicted: np.ndarray, body: BodyModel, qpos: np.ndarray, settings: PhysicsSettings) -> np.ndarray:
    """(T, 4) bool, the contacts physics uses for the kinematic motion qpos (T, nq) (world frame, floor z = 0):
    `foot_lock` with settings.foot_lock and settings.contact_height (metres). One frame: predicted (1, 4) and
    qpos (1, nq)."""
    if settings.foot_lock == "auto":  # the heights are not needed: skip the forward kinematics
        return np.asarray(predicted, dtype=bool).copy()
    return foot_lock(predicted, foot_point_heights(body, qpos), settings.foot_lock, settings.contact_height)
