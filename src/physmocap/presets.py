"""Per-activity presets, the smoothing strength and foot-lock: the controls users know from commercial tools.

A preset is a named set of overrides of `physmocap.config.Settings` fields, {section: {field: value}}, applied on
top of the defaults or a settings file; options given on the command line after it still win. The smoothing
strength scales the fit's temporal weights. Foot-lock decides which foot points may be in contact before
physics runs:

- "auto": the contacts the contact stage predicted;
- "always": every foot point (left heel, left toe, right heel, right toe) within the contact height of the floor,
  whatever was predicted: for motion that stays on the ground (standing, slow walking, work on the spot);
- "never": no contact at all: for airborne or swimming motion, where the floor must never pull a foot down.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from .body.kinematics import forward_kinematics
from .body.model import CONTACT_POINTS, BodyModel
from .config import Settings
from .errors import InputError

FOOT_LOCK_MODES: tuple[str, ...] = ("auto", "always", "never")


@dataclass(frozen=True)
class Preset:
    """overrides: {section of Settings: {field: value}}. rationale: why these values suit the activity."""

    overrides: dict[str, dict[str, Any]]
    rationale: str


PRESETS: dict[str, Preset] = {
    "walking": Preset(
        {"fit": {"weight_smooth": 0.1, "weight_depth": 0.03},
         "physics": {"contact_height": 0.1, "slide_speed": 0.3, "balance_correction": True}},
        "The defaults, stated: the fit weights and the slide speed were tuned on CMU walks and the contact height "
        "is PhysCap's, whose test clips are mostly walking.",
    ),
    "running": Preset(
        {"fit": {"weight_smooth": 0.03, "weight_depth": 0.01},
         "physics": {"contact_height": 0.05, "balance_correction": False}},
        "Limbs accelerate hard, so a third of the smoothing keeps the swing peaks; stances are short and the feet "
        "pass close to the floor in flight, so a lower contact height keeps flight frames free of contacts; a "
        "runner is never stationary, so balance correction is off.",
    ),
    "jumping": Preset(
        {"fit": {"weight_smooth": 0.02, "weight_depth": 0.01},
         "physics": {"contact_height": 0.05, "balance_correction": False}},
        "Take-off and landing are real impulses that acceleration smoothing would spread out, so it is the "
        "weakest; flight must have no contact at all (low contact height); crouches before a jump are "
        "deliberately off-balance, so balance correction stays off.",
    ),
    "dancing": Preset(
        {"fit": {"weight_smooth": 0.05, "weight_depth": 0.02},
         "physics": {"contact_height": 0.08, "slide_speed": 0.5, "friction": 0.5, "balance_correction": False}},
        "Dancers pivot and slide on the balls of their feet, so a contact may keep 50 cm/s of sliding on a "
        "smoother floor; held poses such as dips and leans are off-balance on purpose, so balance correction "
        "is off; moderate smoothing keeps sharp accents.",
    ),
    "standing": Preset(
        {"fit": {"weight_smooth": 0.5, "weight_depth": 0.1},
         "physics": {"contact_height": 0.1, "slide_speed": 0.01, "balance_correction": True,
                     "correction_rate": 0.2}},
        "Near-static poses: five times the smoothing removes detector jitter without visible lag, feet may "
        "barely slide (1 cm/s), and balance correction straightens leans twice as fast as the default.",
    ),
}


def apply_preset(settings: Settings, name: str) -> Settings:
    """`settings` with the preset `name`'s overrides applied (InputError for an unknown name)."""
    if name not in PRESETS:
        raise InputError(f"unknown preset '{name}': choose one of {', '.join(sorted(PRESETS))}.")
    for section, fields in PRESETS[name].overrides.items():
        settings = settings.replace(section, **fields)
    return settings.check()


def apply_smoothing(settings: Settings, strength: float) -> Settings:
    """`settings` with the fit's temporal weights (joint acceleration `fit.weight_smooth` and depth change
    `fit.weight_depth`) multiplied by `strength`: 0 turns smoothing off, 1 keeps the settings, 3 smooths three
    times as strongly. Dimensionless, 0 .. 100."""
    if not np.isfinite(strength) or not 0.0 <= strength <= 100.0:
        raise InputError(f"smoothing strength = {strength} is out of range: expected 0 to 100.")
    if strength == 1.0:
        return settings
    fit = dataclasses.replace(settings.fit, weight_smooth=settings.fit.weight_smooth * strength,
                              weight_depth=settings.fit.weight_depth * strength)
    return dataclasses.replace(settings, fit=fit).check()


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
