"""Per-activity presets and the smoothing strength: the controls users know from commercial tools (foot-lock, the
third, lives in `contacts.footlock`).

A preset is a named set of overrides of `physmocap.config.Settings` fields, {section: {field: value}}, applied on
top of the defaults or a settings file; options given on the command line after it still win. The smoothing
strength scales the fit's temporal weights.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

from .config import Settings
from .errors import InputError


@dataclass(frozen=True)
class Preset:
    """overrides: {section of Settings: {field: value}}. rationale: why these values suit the activity."""

    overrides: dict[str, dict[str, Any]]
    rationale: str


SMOOTHING_LIMITS = (0.0, 100.0)  # the smoothing strength's range, a dimensionless factor

PRESETS: dict[str, Preset] = {
    "walking": Preset(
        {"fit": {"weight_smooth": 0.1, "weight_depth": 0.03},
         "physics": {"contact_height": 0.1, "slide_speed": 0.3, "balance_correction": True}},
        "The defaults, stated: the fit weights and the slide speed were tuned on CMU walks and the contact height "
        "is PhysCap's, whose test clips are mostly walking.",
    ),
    "running": Preset(
        {"fit": {"weight_smooth": 0.03, "weight_depth": 0.01, "angle_speed_huber": 2.0,
                 "angle_speed_huber_frames": "all"},
         "physics": {"contact_height": 0.05, "balance_correction": False}},
        "Limbs accelerate hard, so a third of the smoothing keeps the swing peaks, and the refinement's joint-angle "
        "velocity term pulls only linearly on joints turning faster than 2 rad/s on every frame (by default only "
        "where the body runs), so it does not shrink the legs' swing; stances are short and the feet pass close to "
        "the floor in flight, so a lower contact height keeps flight frames free of contacts; a runner is never "
        "stationary, so balance correction is off.",
    ),
    "jumping": Preset(
        {"fit": {"weight_smooth": 0.02, "weight_depth": 0.01, "angle_speed_huber": 2.0,
                 "angle_speed_huber_frames": "all"},
         "physics": {"contact_height": 0.05, "balance_correction": False}},
        "Take-off and landing are real impulses that acceleration smoothing would spread out, so it is the "
        "weakest, and the legs' fast extension is not shrunk (as running); flight must have no contact at all "
        "(low contact height); crouches before a jump are deliberately off-balance, so balance correction stays "
        "off.",
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
                     "correction_time": 0.149}},
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
    `fit.weight_depth`) multiplied by `strength` (within SMOOTHING_LIMITS): 0 turns smoothing off, 1 keeps the
    settings, 3 smooths three times as strongly."""
    low, high = SMOOTHING_LIMITS
    if not math.isfinite(strength) or not low <= strength <= high:
        raise InputError(f"smoothing strength = {strength} is out of range: expected {low:g} to {high:g}.")
    if strength == 1.0:
        return settings
    fit = dataclasses.replace(settings.fit, weight_smooth=settings.fit.weight_smooth * strength,
                              weight_depth=settings.fit.weight_depth * strength)
    return dataclasses.replace(settings, fit=fit).check()
