"""A character: its rig placed in the world, its body model (the rig's own bone lengths and mass distribution),
and which body-model segment each of its bones follows.

World: metres, x forward, y left, z up, floor z = 0 (DESIGN.md). The rig's axes are found from its anatomy (left:
right hip to left hip; up: feet to head), its unit from the TOML map or its legs (`rig.guess_units`), its floor
from the lowest point of its mesh or, without one, of its joints; its hip midpoint stands above the origin.

Body model: `SkeletonLengths` measured on the rig's rest pose (vertical heights for the trunk, joint distances for
the limbs, contact points on the character's own soles), de Leva's segments scaled to it; the total mass and the
shares of the head, trunk, arms and legs can be set (`CharacterConfig`), e.g. Rempe et al.'s E.6 characters with
40 % of the mass in the head or 36 % in the arms.

Each rig joint follows one body: a mapped bone the body it starts (hip -> thigh, ...), any other bone the body of
its nearest mapped ancestor (a clavicle the torso, fingers the hand, a root above the hips the pelvis). Because
the rig's rest pose need not be the body model's T-pose (an A-pose, arms down, feet turned out), each body carries
the constant rotation C taking its rest direction in the body model onto its bone's rest direction in the rig; a
bone's world rotation relative to its rest is then R_body(t) C^T, which points it where the body points.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..body.model import TEMPLATE_RATIOS, BodyModel, SkeletonLengths, build_body_model
from ..body.rotations import rotation_between
from ..errors import InputError
from ..mocap.bvh_reader import HEEL_BEHIND_ANKLE
from .mapping import CharacterConfig, map_bones
from .rig import Rig, guess_units, with_rest_frame

# Body model bodies started by each mapped role.
ROLE_BODY = {"pelvis": "pelvis", "spine": "torso", "neck": "head",
             **{f"{s}_{part}": f"{s}_{body}" for s in ("left", "right")
                for part, body in (("hip", "thigh"), ("knee", "shin"), ("ankle", "foot"), ("shoulder", "upper_arm"),
                                   ("elbow", "forearm"), ("wrist", "hand"))}}
MASS_GROUP_BODIES = {
    "head": ("head",), "trunk": ("pelvis", "torso"),
    "arms": tuple(f"{s}_{b}" for s in ("left", "right") for b in ("upper_arm", "forearm", "hand")),
    "legs": tuple(f"{s}_{b}" for s in ("left", "right") for b in ("thigh", "shin", "foot")),
}
HEAD_SHARE_BELOW_EARS = TEMPLATE_RATIOS["head_height"] / (TEMPLATE_RATIOS["head_height"] + TEMPLATE_RATIOS["head_top"])
TOE_OF_FOOT_TIP = 0.75  # without a toe bone the toe contact point lies this share of the way to the foot's tip
CROWN_ABOVE_HEAD_BONE = 0.25  # crown above the head bone without a mesh or head end, in leg lengths
MIN_TRUNK_LENGTH = 0.02  # m: a spine joint level with the hips (no lower back) still gets this much


@dataclass(frozen=True, eq=False)
class Character:
    """rig; bones: role -> rig joint; file_to_world: (3, 3) rotation of the file's axes into the world's;
    units_to_metres; origin: (3,) world point (metres) moved to the origin; rest: (J, 3) rig joints at rest in the
    world, metres; segment: (J,) body each joint follows; alignment: (B, 3, 3) the bodies' C; body: the body model;
    notes: what was assumed."""

    rig: Rig
    bones: dict[str, int]
    file_to_world: np.ndarray
    units_to_metres: float
    origin: np.ndarray
    rest: np.ndarray
    segment: np.ndarray
    alignment: np.ndarray
    body: BodyModel
    notes: tuple[str, ...]

    def to_world(self, points_file: np.ndarray) -> np.ndarray:
        """(..., 3) file positions -> world metres."""
        return points_file @ self.file_to_world.T * self.units_to_metres - self.origin

    def to_file(self, points_world: np.ndarray) -> np.ndarray:
        """(..., 3) world metres -> file positions."""
        return (points_world + self.origin) / self.units_to_metres @ self.file_to_world


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def build_character(rig: Rig, config: CharacterConfig | None = None, default_mass: float = 70.0,
                    default_height: float | None = None) -> Character:
    """Map, place and measure the rig and build its body model.

    default_mass: total mass (kg) when the config gives none, for a character of default_height metres (None:
    taken as is); a character of another height gets it scaled by the cube of the height ratio (same density)."""
    config = config or CharacterConfig()
    bones = map_bones(rig, config)
    notes: list[str] = []
    if rig.kind == "bvh" and not _upright(rig, bones) and rig.first_frame is not None:
        rig = with_rest_frame(rig, rig.first_frame)
        notes.append("the zero pose is not standing: the first frame taken as the rest pose")
    if not _upright(rig, bones):
        raise InputError(f"{rig.path}: the rest pose does not stand (feet and head on the same side of the hips); "
                         "a character in a T-pose or A-pose is needed.")
    world_file = rig.rest_world()
    positions = world_file[:, :3, 3]
    P = {role: positions[j] for role, j in bones.items()}
    left = _unit(P["left_hip"] - P["right_hip"])
    up = P["head"] - (P["left_ankle"] + P["right_ankle"]) / 2
    up = _unit(up - (up @ left) * left)
    forward = np.cross(left, up)
    A = np.stack([forward, left, up])

    units = config.units_to_metres or rig.units_to_metres
    if not np.isfinite(units):
        legs = np.mean([np.linalg.norm(P[f"{s}_hip"] - P[f"{s}_knee"]) + np.linalg.norm(P[f"{s}_knee"]
                        - P[f"{s}_ankle"]) for s in ("left", "right")])
        units = guess_units(float(legs))
        if not np.isfinite(units):
            raise InputError(f"{rig.path}: cannot tell the file's length unit from legs {legs:.3g} units long; "
                             "set units_to_metres in a TOML map given with --character-map.")
        notes.append(f"length unit taken as {units:g} m")
    rotated = positions @ A.T * units
    _check_height(rig, float(np.ptp(rotated[:, 2])))  # the joints' extent, before measuring anything in metres
    lowest = rotated[:, 2].min()
    if rig.vertices is not None and len(rig.vertices):
        lowest = float((rig.vertices @ A.T * units)[:, 2].min())
    else:
        notes.append("no mesh: the soles taken at the lowest joint")
    hips_mid = (rotated[bones["left_hip"]] + rotated[bones["right_hip"]]) / 2
    origin = np.array([hips_mid[0], hips_mid[1], lowest])
    rest = rotated - origin
    lengths, foot_tips, hand_tips = _measure(rig, bones, rest, A, units, origin, notes)
    _check_proportions(rig, lengths)
    height = lengths.standing_height
    mass = config.mass
    if mass is None:
        mass = default_mass * (1.0 if default_height is None else (height / default_height) ** 3)
    body = distribute_mass(build_body_model(lengths, mass), config.mass_fractions)
    segment = _segments(rig, bones, body)
    alignment = _alignment(bones, rest, foot_tips, hand_tips, body)
    return Character(rig, bones, A, float(units), origin, rest, segment, alignment, body, tuple(notes))


CHARACTER_HEIGHTS = (0.1, 20.0)  # m: the standing heights a character may have (a mouse to a giant)


def _check_height(rig: Rig, height: float) -> None:
    """InputError unless `height` (m) lies within CHARACTER_HEIGHTS."""
    low, high = CHARACTER_HEIGHTS
    if not low <= height <= high:
        raise InputError(f"{rig.path}: the character stands {height:.3g} m tall, outside {low:g}-{high:g} m; check its "
                         "OFFSETs or set units_to_metres in a TOML map given with --character-map.")


def _check_proportions(rig: Rig, lengths: SkeletonLengths) -> None:
    """InputError unless the character stands CHARACTER_HEIGHTS tall and no length of its body exceeds its height
    (an OFFSET or unit out of range would otherwise reach the body model as an infinite mass or inertia)."""
    height = lengths.standing_height
    _check_height(rig, height)
    for name, value in vars(lengths).items():
        if not abs(value) <= height:
            raise InputError(f"{rig.path}: the character's {name} measures {value:.3g} m, more than its height of "
                             f"{height:.3g} m; check the rig's rest pose.")


def _upright(rig: Rig, bones: dict[str, int]) -> bool:
    """Whether the rest pose stands: the head and the knees and ankles on opposite sides of the hips, the knees
    between the hips and the ankles."""
    P = rig.rest_world()[:, :3, 3]
    hips = (P[bones["left_hip"]] + P[bones["right_hip"]]) / 2
    up = P[bones["head"]] - hips
    return all((P[bones[f"{s}_knee"]] - hips) @ up < 0 and (P[bones[f"{s}_ankle"]] - P[bones[f"{s}_knee"]]) @ up < 0
               for s in ("left", "right"))


def _measure(rig: Rig, bones: dict[str, int], rest: np.ndarray, A: np.ndarray, units: float, origin: np.ndarray,
             notes: list[str]) -> tuple[SkeletonLengths, dict[str, np.ndarray], dict[str, np.ndarray | None]]:
    """SkeletonLengths of the rig at rest (world metres, floor z = 0), and by side the tips of the feet and of the
    hands (None: a hand without fingers)."""
    P = {role: rest[j] for role, j in bones.items()}

    def mean_distance(a: str, b: str) -> float:
        return float(np.mean([np.linalg.norm(P[f"{s}_{a}"] - P[f"{s}_{b}"]) for s in ("left", "right")]))

    foot_tips: dict[str, np.ndarray] = {}
    hand_tips: dict[str, np.ndarray | None] = {}
    toe_front = []
    for side in ("left", "right"):
        ankle = P[f"{side}_ankle"]
        if f"{side}_toe" in P:
            toe, share = P[f"{side}_toe"], 1.0
        else:
            below = rig.descendants(bones[f"{side}_ankle"])
            if not below:
                raise InputError(f"{rig.path}: the foot {rig.names[bones[f'{side}_ankle']]} has no toe bone or end; "
                                 "its length is unknown.")
            toe, share = rest[max(below, key=lambda j: rest[j, 0])], TOE_OF_FOOT_TIP
            notes.append(f"{side} toe contact point {TOE_OF_FOOT_TIP:g} of the way to the foot's tip")
        foot_tips[side] = toe
        toe_front.append(share * (toe - ankle)[0])
        hand = bones[f"{side}_wrist"]
        fingers = rig.children(hand)
        hand_tips[side] = rest[fingers].mean(axis=0) if fingers else None
    pelvis_z = (P["left_hip"][2] + P["right_hip"][2]) / 2
    shoulders_z = (P["left_shoulder"][2] + P["right_shoulder"][2]) / 2
    spine_low = max(P["spine"][2] - pelvis_z, MIN_TRUNK_LENGTH) if bones["spine"] != bones["pelvis"] \
        else MIN_TRUNK_LENGTH
    spine_up = max(shoulders_z - pelvis_z - spine_low, MIN_TRUNK_LENGTH)
    crown = _crown(rig, bones, rest, A, units, origin, shoulders_z)
    head_total = crown - shoulders_z
    face = head_total / (TEMPLATE_RATIOS["head_height"] + TEMPLATE_RATIOS["head_top"])  # a stature for the face
    hand_lengths = [np.linalg.norm(tip - P[f"{side}_wrist"]) for side, tip in hand_tips.items() if tip is not None]
    forearm = mean_distance("elbow", "wrist")
    hand_length = float(np.mean(hand_lengths)) if hand_lengths else forearm * 0.38
    foot_front = float(np.mean(toe_front))
    if foot_front <= 0.01:
        raise InputError(f"{rig.path}: the feet do not point forward at rest (toes {foot_front:.3f} m ahead of "
                         "the ankles); the rig's axes cannot be told.")
    lengths = SkeletonLengths(
        hip_width=float(np.linalg.norm(P["left_hip"] - P["right_hip"])), thigh=mean_distance("hip", "knee"),
        shank=mean_distance("knee", "ankle"),
        ankle_height=float(np.mean([P["left_ankle"][2], P["right_ankle"][2]])),
        heel_back=HEEL_BEHIND_ANKLE * foot_front, toe_front=foot_front, spine_low=float(spine_low),
        spine_up=float(spine_up), shoulder_width=float(np.linalg.norm(P["left_shoulder"] - P["right_shoulder"])),
        upper_arm=mean_distance("shoulder", "elbow"), forearm=forearm, hand_length=hand_length,
        hand_width=hand_length * TEMPLATE_RATIOS["hand_width"] / TEMPLATE_RATIOS["hand_length"],
        head_height=head_total * HEAD_SHARE_BELOW_EARS, head_top=head_total * (1 - HEAD_SHARE_BELOW_EARS),
        ear_width=face * TEMPLATE_RATIOS["ear_width"], nose_forward=face * TEMPLATE_RATIOS["nose_forward"],
        nose_down=face * TEMPLATE_RATIOS["nose_down"], eye_forward=face * TEMPLATE_RATIOS["eye_forward"],
        eye_up=face * TEMPLATE_RATIOS["eye_up"], eye_width=face * TEMPLATE_RATIOS["eye_width"])
    return lengths, foot_tips, hand_tips


def _crown(rig: Rig, bones: dict[str, int], rest: np.ndarray, A: np.ndarray, units: float, origin: np.ndarray,
           shoulders_z: float) -> float:
    """Height of the top of the head: the mesh's highest point, else the head bone's own end (an End Site or a
    leaf named *top* / *end*), else CROWN_ABOVE_HEAD_BONE leg lengths above the head bone (an adult's skull base
    lies about 0.12 of the stature below the crown, the legs about 0.49 of it)."""
    head = bones["head"]
    if rig.vertices is not None and len(rig.vertices):
        return float((rig.vertices @ A.T * units)[:, 2].max() - origin[2])
    ends = [j for j in rig.children(head) if rig.end_site[j] or not rig.children(j)
            and any(w in rig.names[j].lower() for w in ("top", "end"))]
    if ends:
        return float(max(rest[j, 2] for j in ends))
    legs = np.mean([np.linalg.norm(rest[bones[f"{s}_hip"]] - rest[bones[f"{s}_knee"]])
                    + np.linalg.norm(rest[bones[f"{s}_knee"]] - rest[bones[f"{s}_ankle"]]) for s in ("left", "right")])
    return float(max(rest[head, 2] + CROWN_ABOVE_HEAD_BONE * legs, shoulders_z + 0.1 * legs))


def distribute_mass(body: BodyModel, fractions: dict[str, float]) -> BodyModel:
    """The body with the given shares of its total mass in the mass groups (head, trunk, arms, legs); the other
    groups share the rest in de Leva's proportions. Each body's inertia scales with its mass (same shape)."""
    if not fractions:
        return body
    index = body.body_index
    base = {g: sum(body.bodies[index[b]].mass for b in names) for g, names in MASS_GROUP_BODIES.items()}
    free = [g for g in MASS_GROUP_BODIES if g not in fractions]
    rest_share = 1.0 - sum(fractions.values())
    free_base = sum(base[g] for g in free)
    factor = {}
    for group, names in MASS_GROUP_BODIES.items():
        target = (fractions[group] if group in fractions else rest_share * base[group] / free_base) * body.mass
        for name in names:
            factor[name] = target / base[group]
    bodies = tuple(dataclasses.replace(b, mass=b.mass * factor[b.name], inertia=b.inertia * factor[b.name])
                   for b in body.bodies)
    return BodyModel(bodies, body.points, body.lengths, body.mass, body.height, body.contact_radius)


def _segments(rig: Rig, bones: dict[str, int], body: BodyModel) -> np.ndarray:
    """(J,) the body each rig joint follows (see the module docstring)."""
    starts = {bones[role]: body.body_index[name] for role, name in ROLE_BODY.items()}
    pelvis = body.body_index["pelvis"]
    out = np.empty(len(rig.names), dtype=int)
    for j in range(len(rig.names)):
        a = j
        while a >= 0 and a not in starts:
            a = int(rig.parents[a])
        out[j] = starts[a] if a >= 0 else pelvis
    return out


def _alignment(bones: dict[str, int], rest: np.ndarray, foot_tips: dict[str, np.ndarray],
               hand_tips: dict[str, np.ndarray | None], body: BodyModel) -> np.ndarray:
    """(B, 3, 3) each body's C: the smallest rotation of its rest direction in the body model onto the rig's."""
    P = {role: rest[j] for role, j in bones.items()}
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    directions: dict[str, tuple[np.ndarray, np.ndarray]] = {
        "torso": (up, (P["left_shoulder"] + P["right_shoulder"]) / 2 - P["spine"]),
        "head": (up, P["head"] - P["neck"]),
    }
    for side, sign in (("left", 1.0), ("right", -1.0)):
        out = np.array([0.0, sign, 0.0])
        directions[f"{side}_upper_arm"] = (out, P[f"{side}_elbow"] - P[f"{side}_shoulder"])
        directions[f"{side}_forearm"] = (out, P[f"{side}_wrist"] - P[f"{side}_elbow"])
        hand_tip = hand_tips[side]
        directions[f"{side}_hand"] = (out, (P[f"{side}_wrist"] - P[f"{side}_elbow"]) if hand_tip is None
                                      else hand_tip - P[f"{side}_wrist"])
        directions[f"{side}_thigh"] = (down, P[f"{side}_knee"] - P[f"{side}_hip"])
        directions[f"{side}_shin"] = (down, P[f"{side}_ankle"] - P[f"{side}_knee"])
        toward_toe = foot_tips[side] - P[f"{side}_ankle"]
        directions[f"{side}_foot"] = (np.array([1.0, 0.0, 0.0]), toward_toe * np.array([1.0, 1.0, 0.0]))
    C = np.tile(np.eye(3), (len(body.bodies), 1, 1))
    for name, (model_direction, rig_direction) in directions.items():
        norm = np.linalg.norm(rig_direction)
        if norm < 1e-9:
            continue
        rig_direction = rig_direction / norm
        if model_direction @ rig_direction > -0.99:  # an opposite bone (a broken rig) keeps C = I
            C[body.body_index[name]] = rotation_between(model_direction, rig_direction)
    return C
