"""Which bone of a character is which joint of the body model: by name for the common rig conventions, by the
hierarchy for the trunk, or from the user's TOML map.

Named roles (the limbs and the head) are matched on normalised names: lower case, without a namespace
("mixamorig:"), without the prefixes "CC_Base_", "DEF-", "J_Bip_" and "Bip01", without separators. A pattern's
"*" stands for a side token ("left"/"l" or "right"/"r") before or after the word, which covers Mixamo and CMU
(LeftUpLeg), Daz (lThigh), Character Creator (CC_Base_L_Thigh), Blender Rigify (DEF-thigh.L), the Unreal
mannequin (thigh_l), VRoid (J_Bip_L_UpperLeg) and VRM humanoid names (leftUpperLeg). Earlier patterns win.

The trunk is found from the hierarchy: pelvis = the common ancestor of the thighs, spine = the first bone above
the pelvis on the way to the arms (or the pelvis itself in a rig without a lower back), neck = the first bone
above the arms' common ancestor on the way to the head.

TOML file (every key optional; bones by name, units in metres per file unit, masses in kg):

    units_to_metres = 0.01
    [bones]
    left_knee = "Leg_L_Lower"
    [mass]
    total = 36.5
    [mass.fractions]   # shares of the total for head, trunk, arms (both), legs (both); the rest keep de Leva's
    head = 0.40
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError
from ..settings_fields import is_number, read_toml
from .rig import Rig

SIDES = ("left", "right")
# Limb roles: body-model joint name (without side) -> name patterns, "*" = side token.
LIMB_PATTERNS: dict[str, tuple[str, ...]] = {
    "hip": ("*upleg", "*upperleg", "*thigh", "*thighbend", "*hip"),
    "knee": ("*leg", "*lowerleg", "*shin", "*calf", "*shinbend", "*knee"),
    "ankle": ("*foot", "*ankle"),
    "toe": ("*toebase", "*toes", "*toe", "*ball", "*toe1"),
    "shoulder": ("*arm", "*upperarm", "*shldr", "*shldrbend", "*shoulder"),
    "elbow": ("*forearm", "*lowerarm", "*forearmbend", "*elbow"),
    "wrist": ("*hand", "*wrist"),
}
HEAD_PATTERNS = ("head", "chead", "spine006")  # VRoid J_Bip_C_Head; Rigify numbers its head spine.006
# VRM humanoid bone names of the roles (used when the glTF file declares its humanoid).
VRM_BONES = {"hip": "UpperLeg", "knee": "LowerLeg", "ankle": "Foot", "toe": "Toes", "shoulder": "UpperArm",
             "elbow": "LowerArm", "wrist": "Hand"}
OPTIONAL_ROLES = ("left_toe", "right_toe")
ROLES = tuple(f"{side}_{part}" for side in SIDES for part in LIMB_PATTERNS) + ("head",)
PREFIXES = ("ccbase", "def", "jbip", "bip01", "bip001", "org")
SIDE_TOKENS = {"left": ("left", "l"), "right": ("right", "r")}


def normalise(name: str) -> str:
    """'mixamorig:LeftUpLeg' -> 'leftupleg', 'CC_Base_L_Thigh' -> 'lthigh', 'DEF-thigh.L' -> 'thighl'."""
    text = re.sub(r"[^0-9a-z]", "", name.split(":")[-1].lower())
    for prefix in PREFIXES:
        if text.startswith(prefix) and len(text) > len(prefix):
            return text[len(prefix):]
    return text


def _candidates(pattern: str, side: str) -> list[str]:
    word = pattern.replace("*", "")
    return [f"{token}{word}" for token in SIDE_TOKENS[side]] + [f"{word}{token}" for token in SIDE_TOKENS[side]]


@dataclass(frozen=True)
class CharacterConfig:
    """The TOML file's contents: bones (role -> bone name), units_to_metres, total mass (kg) and mass fractions
    (group -> share of the total), each None or empty where not given."""

    bones: dict[str, str] = field(default_factory=dict)
    units_to_metres: float | None = None
    mass: float | None = None
    mass_fractions: dict[str, float] = field(default_factory=dict)
    path: str = ""


MASS_GROUPS = ("head", "trunk", "arms", "legs")
MAPPABLE = ROLES + ("pelvis", "spine", "neck")


MIN_MASS_FRACTION = 1e-3  # the smallest share of a group (a tenth of a human's hands'), so no segment is massless


def _table(data: dict, key: str, path: Path, prefix: str = "") -> dict:
    """data[key] as a TOML table ({} when absent); InputError when it is a plain value."""
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise InputError(f"{path}: {prefix}{key} must be a table ([{prefix}{key}] with keys below it), got {value!r}.")
    return value


def load_character_config(path: str | os.PathLike | None) -> CharacterConfig:
    """Read the TOML map; InputError naming the file and the bad key."""
    if path is None:
        return CharacterConfig()
    path = Path(path)
    data = read_toml(path, "character map")
    unknown = set(data) - {"bones", "units_to_metres", "mass"}
    if unknown:
        raise InputError(f"{path}: unknown key {sorted(unknown)[0]} (expected bones, units_to_metres, mass).")
    bones = _table(data, "bones", path)
    bad = [k for k in bones if k not in MAPPABLE]
    if bad:
        raise InputError(f"{path}: [bones] key {bad[0]} is not a body-model joint (one of {', '.join(MAPPABLE)}).")
    mass = _table(data, "mass", path)
    fractions = _table(mass, "fractions", path, "mass.")
    unnamed = [k for k, v in bones.items() if not isinstance(v, str) or not v]
    if unnamed:
        raise InputError(f"{path}: [bones] {unnamed[0]} must be a bone's name in quotes, got {bones[unnamed[0]]!r}.")
    bad = [k for k in fractions if k not in MASS_GROUPS]
    if bad:
        raise InputError(f"{path}: [mass.fractions] key {bad[0]} is not one of {', '.join(MASS_GROUPS)}.")
    total = mass.get("total")
    if total is not None and not (is_number(total) and 1.0 <= total <= 2000.0):
        raise InputError(f"{path}: mass.total must be a number of kg between 1 and 2000, got {total!r}.")
    shares = list(fractions.values())
    in_range = all(is_number(v) and MIN_MASS_FRACTION <= v < 1.0 for v in shares)
    all_given = len(shares) == len(MASS_GROUPS)
    rest = 1.0 - sum(shares) if in_range else 0.0  # what the groups not given share
    if not in_range or (all_given and abs(rest) > 1e-6) or (not all_given and rest < MIN_MASS_FRACTION):
        raise InputError(f"{path}: mass.fractions must each lie between {MIN_MASS_FRACTION:g} and 1 and add up to 1 "
                         f"when all four groups are given, to at most {1 - MIN_MASS_FRACTION:g} otherwise.")
    units = data.get("units_to_metres")
    if units is not None and not (is_number(units) and 0 < units < float("inf")):
        raise InputError(f"{path}: units_to_metres must be a positive number, got {units!r}.")
    return CharacterConfig({k: str(v) for k, v in bones.items()}, None if units is None else float(units),
                           None if total is None else float(total), {k: float(v) for k, v in fractions.items()},
                           str(path))


def _common_ancestor(rig: Rig, joints: list[int]) -> int:
    def chain(j: int) -> list[int]:
        out = []
        while j >= 0:
            out.append(j)
            j = int(rig.parents[j])
        return out

    common = set(chain(joints[0]))
    for j in joints[1:]:
        common &= set(chain(j))
    return max(common, key=lambda a: len(chain(a)))  # the deepest


def _path_down(rig: Rig, top: int, bottom: int) -> list[int]:
    """Joints from just below `top` down to `bottom` (inclusive), top to bottom."""
    out = []
    while bottom != top and bottom >= 0:
        out.append(bottom)
        bottom = int(rig.parents[bottom])
    return out[::-1]


def _named_bones(rig: Rig, config: CharacterConfig) -> dict[str, int]:
    """The roles found by name: the TOML map's bones, then VRM humanoid bones and the name patterns of the limbs
    and the head."""
    by_name: dict[str, int] = {}
    for j, name in enumerate(rig.names):
        if not rig.end_site[j]:
            by_name.setdefault(normalise(name), j)
    exact = {name: j for j, name in enumerate(rig.names)}
    found: dict[str, int] = {}
    for role, bone in config.bones.items():
        if bone not in exact:
            raise InputError(f"{config.path}: [bones] {role} = {bone!r} names no bone of {rig.path}.")
        found[role] = exact[bone]
    vrm = rig.humanoid or {}
    for side in SIDES:
        for part, patterns in LIMB_PATTERNS.items():
            role = f"{side}_{part}"
            if role in found:
                continue
            vrm_bone = f"{side}{VRM_BONES[part]}"
            if vrm_bone in vrm:
                found[role] = vrm[vrm_bone]
                continue
            for pattern in patterns:
                hit = next((by_name[c] for c in _candidates(pattern, side) if c in by_name), None)
                if hit is not None:
                    found[role] = hit
                    break
    if "head" not in found:
        hit = vrm.get("head", next((by_name[p] for p in HEAD_PATTERNS if p in by_name), None))
        if hit is not None:
            found["head"] = hit
    return found


def _add_trunk(rig: Rig, found: dict[str, int]) -> None:
    """The pelvis, spine and neck the map did not name, found in place from the hips, shoulders and head."""
    if "pelvis" not in found:
        found["pelvis"] = _common_ancestor(rig, [found["left_hip"], found["right_hip"]])
    arms = _common_ancestor(rig, [found["left_shoulder"], found["right_shoulder"]])
    if "spine" not in found:
        trunk = _path_down(rig, found["pelvis"], arms)
        if found["pelvis"] in _path_down(rig, -1, arms):
            found["spine"] = trunk[0] if trunk else found["pelvis"]
        else:  # the pelvis is a branch of its own (Character Creator): the spine starts beside it
            top = _common_ancestor(rig, [found["pelvis"], arms])
            beside = _path_down(rig, top, arms)
            if not beside:
                raise InputError(f"{rig.path}: no spine found between the pelvis {rig.names[found['pelvis']]} and "
                                 f"the shoulders; name it in a TOML map ([bones] spine = \"BoneName\") given with "
                                 "--character-map.")
            found["spine"] = beside[0]
    if "neck" not in found:
        chain = _path_down(rig, arms, found["head"])
        found["neck"] = chain[0] if chain else found["head"]


def map_bones(rig: Rig, config: CharacterConfig | None = None) -> dict[str, int]:
    """Role (body-model joint name: pelvis, spine, neck, head, left_hip, ..., right_toe) -> rig joint index.

    Toes are optional. InputError (one sentence) listing the roles no bone could be found for."""
    found = _named_bones(rig, config or CharacterConfig())
    required = [r for r in ROLES if r not in OPTIONAL_ROLES]
    missing = [r for r in required if r not in found]
    if missing:
        raise InputError(
            f"{rig.path}: no bone found for {', '.join(missing)}; name them in a TOML map ([bones] "
            f"{missing[0]} = \"BoneName\") given with --character-map (bones: {_sample(rig)}).")
    toes = [f"{s}_toe" for s in SIDES]
    for toe, ankle in zip(toes, ("left_ankle", "right_ankle"), strict=True):
        if toe in found and int(rig.parents[found[toe]]) != found[ankle]:
            del found[toe]  # a "toe" that is not the foot's child is some other bone
    _check_distinct(rig, found)  # before the trunk is sought between them
    _add_trunk(rig, found)
    _check_distinct(rig, found)
    return found


def _check_distinct(rig: Rig, found: dict[str, int]) -> None:
    """InputError where one bone plays two roles (the spine and neck may share one with another role)."""
    roles_of: dict[int, str] = {}
    for role, joint in found.items():
        if joint in roles_of and role not in ("neck", "spine") and roles_of[joint] not in ("neck", "spine"):
            raise InputError(f"{rig.path}: bone {rig.names[joint]} matches both {roles_of[joint]} and {role}; "
                             "set one of them in a TOML map given with --character-map.")
        roles_of.setdefault(joint, role)


def _sample(rig: Rig, count: int = 12) -> str:
    names = [n for j, n in enumerate(rig.names) if not rig.end_site[j]]
    return ", ".join(names[:count]) + (", ..." if len(names) > count else "")
