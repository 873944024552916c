"""Read BVH motion capture files and turn them into the project's joint set.

Two layers:

- A general BVH reader: `parse_bvh` (hierarchy + motion, any channel order and rotation order, position channels
  on any joint, End Sites kept as joints of their own) and `forward_kinematics`, vectorised over frames.
- `load_mocap`, which maps the two skeletons found in the shared CMU data onto the project's 20 named points
  (`JOINT_NAMES`) in the world frame of DESIGN.md (metres, Z up, floor z = 0) and returns a `MocapClip`.

BVH semantics used here (the common reading, as in Blender and the CMU conversions):
- A joint's local transform is a translation by OFFSET (plus its position channels, if any) followed by its
  rotation channels applied in the order listed: channels "Zrotation Yrotation Xrotation" give
  R = Rz(a) @ Ry(b) @ Rx(c), so that a point in the joint's frame maps to the parent's frame as p -> R p + offset.
- Position channels add to the OFFSET. The CC3 exports need this: their root OFFSET holds the hip height and the
  position channels only the displacement from it.
- An End Site has an OFFSET and no channels; it is kept as a joint named "<parent>_End".
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..body.rotations import rotation_between, unit_vectors
from ..errors import InputError

# The project's named points, in this order everywhere (see DESIGN.md, "The result file").
JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "spine", "neck", "head",
    "left_shoulder", "left_elbow", "left_wrist", "right_shoulder", "right_elbow", "right_wrist",
    "left_hip", "left_knee", "left_ankle", "left_heel", "left_toe",
    "right_hip", "right_knee", "right_ankle", "right_heel", "right_toe",
)
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINT_NAMES)}

_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


@dataclass(frozen=True)
class BvhJoint:
    """One joint of a BVH hierarchy.

    name: joint name; End Sites are named "<parent>_End".
    parent: index of the parent joint in `BvhData.joints`, -1 for the root.
    offset: (3,) translation from the parent's frame, in the file's units and axes.
    channels: channel names in file order, e.g. ("Xposition", "Yposition", "Zposition", "Zrotation", ...).
    channel_start: column of this joint's first channel in `BvhData.motion`.
    """

    name: str
    parent: int
    offset: np.ndarray
    channels: tuple[str, ...]
    channel_start: int


@dataclass(frozen=True)
class BvhData:
    """A parsed BVH file. Joints are in file order, so every parent comes before its children.

    joints: the hierarchy, End Sites included.
    frame_time: seconds per frame.
    motion: (T, C) channel values in file order; positions in file units, rotations in degrees.
    """

    joints: tuple[BvhJoint, ...]
    frame_time: float
    motion: np.ndarray

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(joint.name for joint in self.joints)

    def index(self, name: str) -> int:
        """Index of the joint called `name`; KeyError if there is none."""
        for i, joint in enumerate(self.joints):
            if joint.name == name:
                return i
        raise KeyError(name)


def parse_bvh(text: str, source: str = "<string>") -> BvhData:
    """Parse the text of a BVH file. Any problem raises InputError naming `source`."""
    header, separator, motion_text = text.partition("MOTION")
    if not separator:
        raise InputError(f"{source}: not a BVH file (no MOTION section).")
    tokens = header.split()
    if not tokens or tokens[0] != "HIERARCHY":
        raise InputError(f"{source}: not a BVH file (it does not start with HIERARCHY).")
    try:
        joints, num_channels = _parse_hierarchy(tokens)
        frames_match = re.search(r"Frames:\s*(\d+)", motion_text)
        time_match = re.search(r"Frame Time:\s*([-+0-9.eE]+)", motion_text)
        if frames_match is None or time_match is None:
            raise ValueError("no 'Frames:' or 'Frame Time:' line")
        num_frames = int(frames_match.group(1))
        frame_time = float(time_match.group(1))
        values = np.array(motion_text[time_match.end() :].split(), dtype=np.float64)
    except (ValueError, IndexError) as exc:
        raise InputError(f"{source}: malformed BVH ({exc}).") from None
    if not frame_time > 0 or not np.isfinite(frame_time):
        raise InputError(f"{source}: Frame Time is {frame_time}, expected a positive number of seconds.")
    if values.size != num_frames * num_channels:
        raise InputError(
            f"{source}: the MOTION section holds {values.size} numbers, expected {num_frames} frames x "
            f"{num_channels} channels."
        )
    motion = values.reshape(num_frames, num_channels)
    if not np.isfinite(motion).all():
        frame, channel = np.argwhere(~np.isfinite(motion))[0]
        raise InputError(f"{source}: the MOTION section holds a value that is not a finite number (frame {frame}, "
                         f"channel {channel}).")
    return BvhData(tuple(joints), frame_time, motion)


def _parse_hierarchy(tokens: list[str]) -> tuple[list[BvhJoint], int]:
    """The joints of a BVH HIERARCHY section (its whitespace-separated tokens, "HIERARCHY" first) and the
    number of motion channels. Raises ValueError or IndexError where the text is malformed."""
    joints: list[BvhJoint] = []
    stack: list[int] = []  # indices of the joints whose braces are open
    num_channels = 0
    position = 1
    while position < len(tokens):
        token = tokens[position]
        if token in ("ROOT", "JOINT") or token == "End":
            if token == "End":
                name = f"{joints[stack[-1]].name}_End"
                position += 2  # "End Site"
            else:
                name = tokens[position + 1]
                position += 2
            if tokens[position] != "{":
                raise ValueError(f"expected '{{' after {name}")
            if tokens[position + 1] != "OFFSET":
                raise ValueError(f"expected OFFSET in {name}")
            offset = np.array([float(v) for v in tokens[position + 2 : position + 5]])
            if not np.isfinite(offset).all():
                raise ValueError(f"the OFFSET of {name} is not finite")
            if any(joint.name == name for joint in joints):
                raise ValueError(f"two joints are named {name}")
            position += 5
            channels: tuple[str, ...] = ()
            if token != "End" and tokens[position] == "CHANNELS":
                count = int(tokens[position + 1])
                channels = tuple(tokens[position + 2 : position + 2 + count])
                position += 2 + count
                unknown = [c for c in channels if not re.fullmatch(r"[XYZ](position|rotation)", c)]
                if unknown:
                    raise ValueError(f"unknown channel {unknown[0]} in {name}")
            parent = stack[-1] if stack else -1
            if parent == -1 and joints:
                raise ValueError("more than one ROOT")
            joints.append(BvhJoint(name, parent, offset, channels, num_channels))
            num_channels += len(channels)
            stack.append(len(joints) - 1)
        elif token == "}":
            stack.pop()
            position += 1
        else:
            raise ValueError(f"unexpected '{token}'")
    if stack or not joints:
        raise ValueError("unbalanced braces")
    return joints, num_channels


def read_bvh(path: str | os.PathLike) -> BvhData:
    """Read and parse a BVH file."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the BVH file ({exc}).") from None
    return parse_bvh(text, source=str(path))


def axis_rotation(axis: str, angles: np.ndarray) -> np.ndarray:
    """Rotation matrices about one coordinate axis.

    axis: "X", "Y" or "Z". angles: (T,) radians. Returns (T, 3, 3).
    """
    i = _AXIS_INDEX[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    cos, sin = np.cos(angles), np.sin(angles)
    matrices = np.zeros((len(angles), 3, 3))
    matrices[:, i, i] = 1.0
    matrices[:, j, j] = cos
    matrices[:, k, k] = cos
    matrices[:, k, j] = sin
    matrices[:, j, k] = -sin
    return matrices


def forward_kinematics(bvh: BvhData, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Global positions and orientations of every joint, in the file's axes.

    scale: multiplies lengths (file units -> metres).
    Returns positions (T, N, 3) and rotations (T, N, 3, 3); rotations[t, n] maps joint n's frame to the file's
    global frame. N counts End Sites, which take their parent's rotation.
    """
    num_frames = len(bvh.motion)
    num_joints = len(bvh.joints)
    positions = np.zeros((num_frames, num_joints, 3))
    rotations = np.zeros((num_frames, num_joints, 3, 3))
    for n, joint in enumerate(bvh.joints):
        translation = np.broadcast_to(joint.offset * scale, (num_frames, 3)).copy()
        local_rotation = np.broadcast_to(np.eye(3), (num_frames, 3, 3))
        for c, channel in enumerate(joint.channels):
            values = bvh.motion[:, joint.channel_start + c]
            if channel.endswith("position"):
                translation[:, _AXIS_INDEX[channel[0]]] += values * scale
            else:
                local_rotation = local_rotation @ axis_rotation(channel[0], np.radians(values))
        if joint.parent < 0:
            positions[:, n] = translation
            rotations[:, n] = local_rotation
        else:
            parent_rotation = rotations[:, joint.parent]
            positions[:, n] = positions[:, joint.parent] + np.einsum("tij,tj->ti", parent_rotation, translation)
            rotations[:, n] = parent_rotation @ local_rotation
    return positions, rotations


# ---------------------------------------------------------------------------------------------------------------
# Mapping onto the project's joint set
# ---------------------------------------------------------------------------------------------------------------

# BVH files here are Y up; the world is Z up: (x, y, z)_bvh -> (x, -z, y)_world, a rotation of +90 degrees about X.
BVH_TO_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

CMU_UNITS_TO_METRES = 0.056444  # CMU length unit: (1/0.45) inch
CC3_UNITS_TO_METRES = 0.01  # the CC3 exports are in centimetres (hip 1.05 m, thigh 0.48 m, eyes 1.75 m up)

# Thigh + shank length of the reference adult (stature 1.75 m; both segments about 0.245 of stature).
REFERENCE_LEG_LENGTH = 0.86
# Crown of the head above the head joint (skull base), along the head's up axis, for the reference adult.
REFERENCE_CROWN_ABOVE_HEAD_JOINT = 0.19

# Contact sites on the sole, as fractions of the ankle -> toe-base (MTP joint) distance L of each foot (the height
# of the MTP joint above the sole depends on the skeleton: `_SkeletonLayout.toe_base_above_sole`).
HEEL_BEHIND_ANKLE = 0.35  # heel site behind the ankle, along the sole (about 4.7 cm)
TOE_AHEAD_OF_TOE_BASE = 0.25  # toe site ahead of the MTP joint, under the proximal toes (about 3.4 cm)
# The Daz foot's End Site above the sole, fraction of ankle -> End Site (12.7 cm): 0.15 puts a flat stance's ankle as
# high above its heel site as on the CC3 avatar in the same motion (scripts/contact_daz_geometry.py).
DAZ_TOE_BASE_ABOVE_SOLE = 0.15
DAZ_DEFAULT_FOOT_PITCH_DEGREES = 19.0  # measured 17-20 degrees on the Daz walks 01_01, 02_01, 02_02, 07_0x
# Range a measured flat-foot pitch (of the ankle -> MTP line below the sole plane) is clamped to, and the largest
# difference between the feet taken as real rather than caused by a foot that stands mostly on its toes.
FOOT_PITCH_RANGE = (np.radians(5.0), np.radians(40.0))
MAX_FOOT_PITCH_DIFFERENCE = np.radians(10.0)
STILL_SPEED = 0.2  # m/s: a point slower than this is still (a planted foot)
MIN_STILL_SECONDS = 0.1  # fewer still frames than this are not enough to measure anything
MAX_FLOOR_TILT = np.radians(3.0)  # a larger fitted floor tilt is taken as uneven ground and left alone
TILT_RIDGE = 0.2  # m: floor slopes are measured only along directions where the feet spread more than this
FLOOR_PERCENTILE = 10.0  # floor fallback: this percentile over frames of the lowest of the four sole sites
IMPLAUSIBLE_SPEED = 20.0  # m/s: a named point faster than this is a capture or conversion glitch


@dataclass
class MocapClip:
    """A motion capture clip on the project's joint set, in the world frame of DESIGN.md.

    name: file stem, e.g. "02_01".
    subject: CMU subject id, e.g. "2".
    fps: frames per second.
    joint_names: JOINT_NAMES.
    positions: (T, 20, 3) metres, Z up, floor at z = 0. Joint centres, except pelvis (midpoint of the hips),
        spine (a mid-back joint), neck (base of the neck), head (the head-neck joint at the skull base, not the
        head's centre), and the heel and toe contact sites on the sole (see `load_mocap`).
    head_rotation: (T, 3, 3) the head's axes in world coordinates, as columns: forward (out of the face),
        left, up (towards the crown).
    hand_rotations: (T, 2, 3, 3) left then right hand; columns: distal (wrist towards the middle finger),
        thumb side, and their cross product, which points out of the palm for the left hand and out of the back
        of the hand for the right.
    skeleton: "cmu" or "cc3", the source skeleton.
    notes: what loading found and did: dropped frames, glitches, missing root motion.
    """

    name: str
    subject: str
    fps: float
    joint_names: tuple[str, ...]
    positions: np.ndarray
    head_rotation: np.ndarray
    hand_rotations: np.ndarray
    skeleton: str
    notes: tuple[str, ...] = ()

    @property
    def num_frames(self) -> int:
        return len(self.positions)

    def joint(self, name: str) -> np.ndarray:
        """(T, 3) world positions of one named point."""
        return self.positions[:, JOINT_INDEX[name]]


@dataclass(frozen=True)
class _SkeletonLayout:
    """Where the project's points and segment frames live in one BVH skeleton.

    points: project joint name -> BVH joint at the same place (every name but pelvis, heels and toes).
    toe_bases: BVH joints at the MTP joints (left, right).
    foot_left_local: (3,) the person's left, in the local frame of the ankle joints' rotation.
    head_forward_local, head_left_local: (3,) in the local frame of `points["head"]`'s rotation.
    hands: BVH joints whose rotation carries the hands (left, right).
    hand_distal_local, hand_thumb_local: (2, 3) per hand, in the local frame of `hands`.
    units_to_metres: length scale of the file.
    default_foot_pitch: flat-foot pitch (radians) for feet that are never still; typical of the skeleton's walks.
    toe_base_above_sole: height of the MTP joint centre above the sole, as a fraction of the ankle -> MTP length.
    """

    kind: str
    points: dict[str, str]
    toe_bases: tuple[str, str]
    foot_left_local: np.ndarray
    head_forward_local: np.ndarray
    head_left_local: np.ndarray
    hands: tuple[str, str]
    hand_distal_local: np.ndarray
    hand_thumb_local: np.ndarray
    units_to_metres: float
    default_foot_pitch: float
    toe_base_above_sole: float


def _first_child_offset(bvh: BvhData, parent: str) -> np.ndarray:
    """(3,) the first non-zero OFFSET among the children of `parent`: the rest direction of its bone."""
    parent_index = bvh.index(parent)
    for joint in bvh.joints:
        if joint.parent == parent_index and np.linalg.norm(joint.offset) > 1e-9:
            return joint.offset
    raise InputError(f"BVH joint {parent} has no child with a non-zero OFFSET.")


def _cmu_layout(bvh: BvhData) -> _SkeletonLayout:
    """Raw CMU skeleton, either naming (cgspeed "LeftUpLeg/LeftArm" or 3dsMax-friendly "LeftHip/LeftShoulder").

    Its rest pose (all channels zero) is the subject's calibration pose facing +Z, left +X, up +Y, so every
    local frame is aligned with those axes. The thumb points forward (+Z) in the rest pose (T-pose palms down, or
    arms down palms in). spine = top of the lower back (CMU upperback joint), neck = top of the thorax (CMU
    lowerneck joint). These files give the thorax (and the wrist bone) zero length: the neck and the shoulders
    sit about 10 cm lower on the trunk than in the subject.
    """
    names = set(bvh.joint_names)
    if "LeftUpLeg" in names:
        side = {"hip": "UpLeg", "knee": "Leg", "ankle": "Foot", "toe": "ToeBase", "shoulder": "Arm",
                "elbow": "ForeArm", "wrist": "Hand"}
        trunk = {"spine": "Spine", "neck": "Neck", "head": "Head"}
        hands = ("LeftFingerBase", "RightFingerBase")
    else:
        side = {"hip": "Hip", "knee": "Knee", "ankle": "Ankle", "toe": "Toe", "shoulder": "Shoulder",
                "elbow": "Elbow", "wrist": "Wrist"}
        trunk = {"spine": "Chest", "neck": "lowerneck", "head": "Head"}
        hands = ("lhand", "rhand")
    points = dict(trunk)
    for prefix, bvh_prefix in (("left_", "Left"), ("right_", "Right")):
        for part in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist"):
            points[prefix + part] = bvh_prefix + side[part]
    forward, left = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    distal = np.stack([unit_vectors(_first_child_offset(bvh, hand)) for hand in hands])
    thumb = unit_vectors(forward - (distal @ forward)[:, None] * distal)
    return _SkeletonLayout(
        kind="cmu",
        points=points,
        toe_bases=("Left" + side["toe"], "Right" + side["toe"]),
        foot_left_local=left,
        head_forward_local=forward,
        head_left_local=left,
        hands=hands,
        hand_distal_local=distal,
        hand_thumb_local=thumb,
        units_to_metres=CMU_UNITS_TO_METRES,
        default_foot_pitch=np.radians(25.0),  # measured 14-35 degrees on the walks 02_01 and 131_0x
        toe_base_above_sole=0.15,  # 2 cm; the MTP joints of 02_01 stand 1.2-2.5 cm above the capture's floor
    )


def _cc3_layout(bvh: BvhData) -> _SkeletonLayout:
    """Character Creator 3 skeleton (CC_Base_*), as exported by iClone.

    Its bones run along their local +Y. spine = CC_Base_Spine02 (mid-back, about half-way from the hips to the
    neck), neck = CC_Base_NeckTwist01 (base of the neck). The head's local axes are +Z forward, +X left, +Y up
    (the eyes sit at +-X, symmetric, and forward-up along +Y+Z); the feet's local -X points to the person's left
    (checked on the walks against the hip line). The hand frames come from the finger offsets: distal towards the middle
    finger's base, thumb side from the pinky's base towards the index finger's base.
    """
    offsets = {joint.name: joint.offset for joint in bvh.joints}
    points = {"spine": "CC_Base_Spine02", "neck": "CC_Base_NeckTwist01", "head": "CC_Base_Head"}
    for prefix, bvh_side in (("left_", "L"), ("right_", "R")):
        for part, bone in (("hip", "Thigh"), ("knee", "Calf"), ("ankle", "Foot"), ("shoulder", "Upperarm"),
                           ("elbow", "Forearm"), ("wrist", "Hand")):
            points[prefix + part] = f"CC_Base_{bvh_side}_{bone}"
    distal = np.stack([unit_vectors(offsets[f"CC_Base_{s}_Mid1"]) for s in "LR"])
    thumb = np.stack([offsets[f"CC_Base_{s}_Index1"] - offsets[f"CC_Base_{s}_Pinky1"] for s in "LR"])
    thumb = unit_vectors(thumb - np.sum(thumb * distal, axis=1, keepdims=True) * distal)
    return _SkeletonLayout(
        kind="cc3",
        points=points,
        toe_bases=("CC_Base_L_ToeBase", "CC_Base_R_ToeBase"),
        foot_left_local=np.array([-1.0, 0.0, 0.0]),
        head_forward_local=np.array([0.0, 0.0, 1.0]),
        head_left_local=np.array([1.0, 0.0, 0.0]),
        hands=("CC_Base_L_Hand", "CC_Base_R_Hand"),
        hand_distal_local=distal,
        hand_thumb_local=thumb,
        units_to_metres=CC3_UNITS_TO_METRES,
        default_foot_pitch=np.radians(12.0),  # measured 10-13 degrees on the walks 002_01, 007_0x
        toe_base_above_sole=0.23,  # 3.1 cm, both in the T-pose that starts 007_03-007_12 and in their stances
    )


def _asf_layout(bvh: BvhData) -> _SkeletonLayout:
    """Raw CMU skeleton with the ASF joint names (hip, lfemur, ltibia, lfoot, ltoes, ...; CMU subject 16).

    Same rest pose and units as `_cmu_layout` (facing +Z, left +X, up +Y; CMU length units); each BVH joint sits
    at the start of the ASF bone it is named after, so the hip is `lfemur`, the knee `ltibia`, the ankle `lfoot`,
    the MTP joint `ltoes`, the shoulder `lhumerus`, the elbow `lradius` and the wrist `lwrist`.
    """
    points = {"spine": "upperback", "neck": "lowerneck", "head": "head"}
    for prefix, s in (("left_", "l"), ("right_", "r")):
        for part, bone in (("hip", "femur"), ("knee", "tibia"), ("ankle", "foot"), ("shoulder", "humerus"),
                           ("elbow", "radius"), ("wrist", "wrist")):
            points[prefix + part] = s + bone
    forward, left = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    hands = ("lhand", "rhand")
    distal = np.stack([unit_vectors(_first_child_offset(bvh, hand)) for hand in hands])
    thumb = unit_vectors(forward - (distal @ forward)[:, None] * distal)
    return _SkeletonLayout(
        kind="cmu_asf", points=points, toe_bases=("ltoes", "rtoes"), foot_left_local=left,
        head_forward_local=forward, head_left_local=left, hands=hands, hand_distal_local=distal,
        hand_thumb_local=thumb, units_to_metres=CMU_UNITS_TO_METRES, default_foot_pitch=np.radians(25.0),
        toe_base_above_sole=0.15,  # the raw CMU skeleton's value (`_cmu_layout`)
    )


def _daz_layout(bvh: BvhData) -> _SkeletonLayout:
    """The Daz (Aiko3) skeleton of cgspeed's "Daz-friendly" CMU release (hip, abdomen, chest, neck, head, lCollar,
    lShldr, lForeArm, lHand, lButtock, lThigh, lShin, lFoot), centimetres, Y up.

    Its rest pose is a T-pose facing +Z with the person's left at +X, every local frame aligned with those axes.
    spine = chest (the top of the abdomen, mid-back), neck = neck (base of the neck). The foot has no toe joint:
    its End Site, 12-13 cm from the ankle (as far as the CC3 avatar's MTP joint), stands for the MTP joint. The
    hand frames come from the finger offsets as for the CC3 skeleton.
    """
    offsets = {joint.name: joint.offset for joint in bvh.joints}
    points = {"spine": "chest", "neck": "neck", "head": "head"}
    for prefix, s in (("left_", "l"), ("right_", "r")):
        for part, bone in (("hip", "Thigh"), ("knee", "Shin"), ("ankle", "Foot"), ("shoulder", "Shldr"),
                           ("elbow", "ForeArm"), ("wrist", "Hand")):
            points[prefix + part] = s + bone
    distal = np.stack([unit_vectors(offsets[f"{s}Mid1"]) for s in "lr"])
    thumb = np.stack([offsets[f"{s}Index1"] - offsets[f"{s}Pinky1"] for s in "lr"])
    thumb = unit_vectors(thumb - np.sum(thumb * distal, axis=1, keepdims=True) * distal)
    return _SkeletonLayout(
        kind="daz", points=points, toe_bases=("lFoot_End", "rFoot_End"), foot_left_local=np.array([1.0, 0.0, 0.0]),
        head_forward_local=np.array([0.0, 0.0, 1.0]), head_left_local=np.array([1.0, 0.0, 0.0]),
        hands=("lHand", "rHand"), hand_distal_local=distal, hand_thumb_local=thumb,
        units_to_metres=CC3_UNITS_TO_METRES, default_foot_pitch=np.radians(DAZ_DEFAULT_FOOT_PITCH_DEGREES),
        toe_base_above_sole=DAZ_TOE_BASE_ABOVE_SOLE,
    )


def _skeleton_layout(bvh: BvhData, source: str) -> _SkeletonLayout:
    """The layout of a raw CMU or CC3 skeleton; InputError naming `source` for any other or an incomplete one."""
    names = set(bvh.joint_names)
    if "CC_Base_Hip" in names:
        build = _cc3_layout
    elif "Hips" in names and ("LeftUpLeg" in names or "LeftHip" in names):
        build = _cmu_layout
    elif "lfemur" in names:
        build = _asf_layout
    elif "lThigh" in names and "abdomen" in names:
        build = _daz_layout
    else:
        raise InputError(f"{source}: unknown BVH skeleton (not CMU 'Hips/LeftUpLeg', CMU ASF 'lfemur', Daz "
                         "'abdomen/lThigh' nor CC3 'CC_Base_Hip').")
    try:
        layout = build(bvh)
    except KeyError as missing:
        raise InputError(f"{source}: the skeleton has no joint {missing}.") from None
    needed = [*layout.points.values(), *layout.toe_bases, *layout.hands]
    absent = [name for name in needed if name not in names]
    if absent:
        raise InputError(f"{source}: the skeleton has no joint {absent[0]}.")
    return layout


def _frame_from_axes(rotations: np.ndarray, forward_local: np.ndarray, left_local: np.ndarray) -> np.ndarray:
    """World frames (columns: forward or first axis, left or second axis, their cross product) of a segment.

    rotations: (T, 3, 3) local -> world rotations of the segment; forward_local, left_local: (3,) axes in the
    segment's local frame (left is orthogonalised against forward). Returns (T, 3, 3).
    """
    first = unit_vectors(rotations @ forward_local)
    second = rotations @ left_local
    second = unit_vectors(second - np.sum(second * first, axis=1, keepdims=True) * first)
    return np.stack([first, second, np.cross(first, second)], axis=2)


ACRNN_SUBJECTS: dict[str, str] = {"salsa": "60", "indian": "94", "martial": "135"}
"""CMU subjects of the acRNN dance clips (acrnn_<kind>_<n>.bvh), as ../shared/data/mocap/cmu_daz_cgspeed_dance's
README gives them: not verified per trial, and the salsa clips mix subjects 60 and 61, so each kind is one subject."""


def cmu_subject(path: str | os.PathLike) -> str:
    """CMU subject id from a file name: '02_01.bvh' -> '2', '131_01' -> '131', '002_01.bvh' -> '2',
    'acrnn_salsa_03.bvh' -> '60' (`ACRNN_SUBJECTS`)."""
    stem = Path(path).name.split(".")[0]
    match = re.fullmatch(r"0*(\d+)_\d+", stem)
    if match is not None:
        return match.group(1)
    match = re.fullmatch(r"acrnn_([a-z]+)_\d+", stem)
    if match is not None and match.group(1) in ACRNN_SUBJECTS:
        return ACRNN_SUBJECTS[match.group(1)]
    raise InputError(f"{path}: not a CMU file name of the form <subject>_<trial>.bvh or acrnn_<dance>_<n>.bvh.")


def sole_sites(
    ankle: np.ndarray, toe_base: np.ndarray, foot_left: np.ndarray, flat_pitch: float, toe_base_above_sole: float
) -> tuple[np.ndarray, np.ndarray]:
    """Heel and toe contact sites on the sole, rigid with the foot.

    ankle, toe_base: (T, 3) world positions of the ankle and MTP (toe-base) joint centres, metres.
    foot_left: (T, 3) the person's left in the foot's frame, in world axes (need not be unit or orthogonal).
    flat_pitch: angle (radians) of the ankle -> MTP line below the sole plane, i.e. below the floor when the foot
        stands flat.
    toe_base_above_sole: h, the MTP joint's height above the sole as a fraction of L = |toe_base - ankle|.

    With d the direction of toe_base - ankle, u the foot's dorsal axis (perpendicular to d and to the left axis),
    the sole's forward direction is s = cos(p) d + sin(p) u and its normal n = -sin(p) d + cos(p) u. Then
    toe = toe_base - h L n + 0.25 L s (under the proximal toes) and heel = ankle - (h L + L sin p) n - 0.35 L s
    (under the back of the heel). Returns heel, toe: (T, 3) each.
    """
    along = toe_base - ankle
    length = np.linalg.norm(along, axis=1, keepdims=True)
    forward = along / length
    left = foot_left - np.sum(foot_left * forward, axis=1, keepdims=True) * forward
    dorsal = unit_vectors(np.cross(forward, unit_vectors(left)))
    sole_forward = np.cos(flat_pitch) * forward + np.sin(flat_pitch) * dorsal
    sole_normal = -np.sin(flat_pitch) * forward + np.cos(flat_pitch) * dorsal
    toe = toe_base - toe_base_above_sole * length * sole_normal + TOE_AHEAD_OF_TOE_BASE * length * sole_forward
    ankle_above_sole = toe_base_above_sole * length + length * np.sin(flat_pitch)
    heel = ankle - ankle_above_sole * sole_normal - HEEL_BEHIND_ANKLE * length * sole_forward
    return heel, toe


def _still(points: np.ndarray, fps: float) -> np.ndarray:
    """(T, ...) True where the point's speed is below STILL_SPEED. points: (T, ..., 3) metres."""
    return np.linalg.norm(np.gradient(points, axis=0), axis=-1) * fps < STILL_SPEED


def flat_foot_pitch(ankle: np.ndarray, toe_base: np.ndarray, fps: float) -> float | None:
    """Measure how far one foot's ankle -> MTP line points below the floor when the foot stands flat (radians).

    ankle, toe_base: (T, 3) world positions, Z up, floor level. The foot is still where its ankle and MTP both
    are; a still foot is flat or has its heel raised, and a raised heel pitches the line further down, so the flat
    pitch is the 25th percentile of the pitch over still frames, clamped to FOOT_PITCH_RANGE. Returns None if
    the foot is still for less than MIN_STILL_SECONDS.
    """
    if len(ankle) < 3:
        return None
    along = toe_base - ankle
    pitch = np.arcsin(np.clip(-along[:, 2] / np.linalg.norm(along, axis=1), -1.0, 1.0))
    still = _still(ankle, fps) & _still(toe_base, fps)
    if still.sum() < MIN_STILL_SECONDS * fps:
        return None
    return float(np.clip(np.percentile(pitch[still], 25.0), *FOOT_PITCH_RANGE))


def floor_tilt(toe_bases: np.ndarray, fps: float) -> np.ndarray | None:
    """Fit the floor's slope under the planted feet; return the floor's unit normal, or None if unmeasurable.

    toe_bases: (T, F, 3) world positions of the F feet's MTP joints, Z up. A still MTP joint rests on the floor
    (flat foot or raised heel alike) at a height of its own, so the fit is z = a x + b y + c_f with one
    intercept per foot, by least squares with two rounds of dropping outliers (beyond 3 robust SDs, at least
    1 cm). The slopes (a, b) get a ridge penalty of TILT_RIDGE^2 per point, so that a direction in which the
    feet barely spread (across a straight walk) stays level instead of fitting noise. Returns (3,) pointing up.
    """
    still = _still(toe_bases, fps)
    if still.sum() < MIN_STILL_SECONDS * fps:
        return None
    frame, foot = np.nonzero(still)
    points = toe_bases[frame, foot]
    feet, foot_column = np.unique(foot, return_inverse=True)
    design = np.zeros((len(points), 2 + len(feet)))
    design[:, :2] = points[:, :2] - points[:, :2].mean(axis=0)
    design[np.arange(len(points)), 2 + foot_column] = 1.0
    ridge = np.diag(np.r_[TILT_RIDGE**2, TILT_RIDGE**2, np.zeros(len(feet))])

    def fit(keep: np.ndarray) -> np.ndarray:
        normal_matrix = design[keep].T @ design[keep] + keep.sum() * ridge
        # lstsq: a foot whose every still point was dropped as an outlier leaves its intercept undetermined
        return np.linalg.lstsq(normal_matrix, design[keep].T @ points[keep, 2], rcond=None)[0]

    keep = np.ones(len(points), dtype=bool)
    coefficients = fit(keep)
    for _ in range(2):
        residuals = points[:, 2] - design @ coefficients
        centre = np.median(residuals[keep])
        spread = 1.4826 * np.median(np.abs(residuals[keep] - centre))
        keep = np.abs(residuals - centre) < max(3.0 * spread, 0.01)
        coefficients = fit(keep)
    return unit_vectors(np.array([-coefficients[0], -coefficients[1], 1.0]))


def _frames_per_second(frame_time: float) -> float:
    """1 / frame_time, rounded to the nearest integer when within 0.1 % of it (files print 0.008333 for 1/120)."""
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) < 1e-3 * fps else fps


def _is_prepended_pose(bvh: BvhData, points: np.ndarray) -> bool:
    """Whether frame 0 is a pose added in front of the capture rather than captured.

    points: (T, P, 3) world positions of the named points. Frame 0 counts as prepended when it is the skeleton's
    rest pose (every rotation channel below the root exactly 0, as in a T-pose frame added by a converter), or
    when some point jumps from it to frame 1 by more than 0.3 m and more than 5 times the 99th percentile of the
    largest per-frame step in the rest of the clip (a T-pose somewhere else, as in the CC3 exports).
    """
    if len(points) < 3:
        return False
    rotation_columns = [
        joint.channel_start + c
        for joint in bvh.joints[1:]
        for c, channel in enumerate(joint.channels)
        if channel.endswith("rotation")
    ]
    if rotation_columns and np.all(bvh.motion[0, rotation_columns] == 0.0):
        return True
    steps = np.linalg.norm(np.diff(points, axis=0), axis=-1).max(axis=1)
    return bool(steps[0] > max(0.3, 5.0 * np.percentile(steps[1:], 99)))


def load_mocap(path: str | os.PathLike) -> MocapClip:
    """Load a CMU BVH file (raw CMU skeleton or the CC3 retarget) onto the project's joint set.

    Steps:
    1. Parse and run forward kinematics; scale to metres (raw CMU: x 0.056444; CC3: centimetres, x 0.01) and
       turn Y up into Z up (`BVH_TO_WORLD`).
    2. Drop the frames prepended to the capture (`_first_captured_frame`).
    3. Take joint centres from the skeleton (`_cmu_layout`, `_cc3_layout`); pelvis = midpoint of the hips.
    4. Level the floor (`_levelling_rotation`).
    5. Heel and toe sites (`sole_sites`): neither skeleton has a heel joint or a sole, so both are placed on a
       sole plane rigid with the foot, from the ankle, the MTP joint and the foot's left axis, at each foot's
       flat-foot pitch (`_flat_foot_pitches`).
    6. Shift z so that the floor (`_floor_height`) is z = 0.
    """
    path = Path(path)
    bvh = read_bvh(path)
    layout = _skeleton_layout(bvh, str(path))
    fps = _frames_per_second(bvh.frame_time)
    bvh_positions, bvh_rotations = forward_kinematics(bvh, layout.units_to_metres)
    world = bvh_positions @ BVH_TO_WORLD.T
    notes: list[str] = []

    direct_names = [name for name in JOINT_NAMES if name in layout.points]
    direct_columns = [bvh.index(layout.points[name]) for name in direct_names]
    first = _first_captured_frame(bvh, world[:, direct_columns], fps, notes)
    if len(world) - first < 2:
        raise InputError(f"{path}: the clip has fewer than 2 frames.")
    world = world[first:]
    hips_height = world[:, [bvh.index(layout.points[f"{side}_hip"]) for side in ("left", "right")], 2].mean(axis=1)
    if len(world) > fps and np.ptp(hips_height) < 1e-3:
        notes.append("pelvis height constant: the file has no vertical root motion")

    def world_rotations(name: str) -> np.ndarray:
        """(T, 3, 3) local -> world rotation of a BVH joint."""
        return BVH_TO_WORLD @ bvh_rotations[first:, bvh.index(name)]

    sides = ("left", "right")
    toe_base_columns = [bvh.index(name) for name in layout.toe_bases]
    level = _levelling_rotation(world[:, toe_base_columns], fps, notes)
    world = world @ level.T

    positions = np.zeros((len(world), len(JOINT_NAMES), 3))
    positions[:, [JOINT_INDEX[name] for name in direct_names]] = world[:, direct_columns]
    positions[:, JOINT_INDEX["pelvis"]] = 0.5 * (positions[:, JOINT_INDEX["left_hip"]]
                                                 + positions[:, JOINT_INDEX["right_hip"]])
    ankles = [positions[:, JOINT_INDEX[f"{side}_ankle"]] for side in sides]
    toe_bases = [world[:, column] for column in toe_base_columns]
    pitches = _flat_foot_pitches(ankles, toe_bases, fps, layout.default_foot_pitch, notes)
    for f, side in enumerate(sides):
        foot_left = level @ world_rotations(layout.points[f"{side}_ankle"]) @ layout.foot_left_local
        heel, toe = sole_sites(ankles[f], toe_bases[f], foot_left, pitches[f], layout.toe_base_above_sole)
        positions[:, JOINT_INDEX[f"{side}_heel"]] = heel
        positions[:, JOINT_INDEX[f"{side}_toe"]] = toe
    positions[..., 2] -= _floor_height(positions, fps, notes)

    head_rotation, hand_rotations = _head_and_hand_rotations(world_rotations, layout, level)
    _note_implausible_jumps(positions, fps, notes)
    return MocapClip(name=path.stem, subject=cmu_subject(path), fps=fps, joint_names=JOINT_NAMES, positions=positions,
                     head_rotation=head_rotation, hand_rotations=hand_rotations, skeleton=layout.kind,
                     notes=tuple(notes))


def _first_captured_frame(bvh: BvhData, points: np.ndarray, fps: float, notes: list[str]) -> int:
    """Step 2 of `load_mocap`: the first frame that was captured rather than prepended (0, 1 or 2), with a note
    for each frame dropped. points: (T, P, 3) world positions of the named points.

    Frame 0 goes if it is a pose prepended to the capture (`_is_prepended_pose`): the rest pose, or a pose far
    from frame 1. The CC3 files 007_03 to 007_12 start with a T-pose 2.5-3 m away. The five raw CMU files here
    start with captured data (frame 0 -> 1 moves like any other step), so they keep their frame 0."""
    first = 0
    if _is_prepended_pose(bvh, points):
        jump = np.linalg.norm(points[1] - points[0], axis=-1).max()
        notes.append(f"dropped frame 0: a pose prepended to the capture (a point moves {jump:.2f} m to frame 1)")
        first = 1
    # A converter's T-pose that is not the exact rest pose (the Daz files' values are rounded) still jumps.
    while first < 2 and len(points) - first > 2 and (np.linalg.norm(
            points[first + 1] - points[first], axis=-1).max() * fps > IMPLAUSIBLE_SPEED):
        notes.append(f"dropped frame {first}: an implausible jump to the next frame")
        first += 1
    return first


def _levelling_rotation(toe_bases: np.ndarray, fps: float, notes: list[str]) -> np.ndarray:
    """Step 4 of `load_mocap`: (3, 3) the rotation that makes the slope fitted under the planted toe bases
    (T, 2, 3) (`floor_tilt`) horizontal, the identity when it tilts more than MAX_FLOOR_TILT (3 degrees) or
    cannot be fitted. The raw walk 02_01 climbs about 5 cm in 3.5 m."""
    up = floor_tilt(toe_bases, fps)
    if up is None:
        return np.eye(3)
    tilt = np.degrees(np.arccos(up[2]))
    if tilt > np.degrees(MAX_FLOOR_TILT):
        notes.append(f"floor under the feet tilts {tilt:.0f} degrees (uneven ground?): not levelled")
        return np.eye(3)
    if tilt > 0.1:
        notes.append(f"levelled a floor tilt of {tilt:.1f} degrees")
    return rotation_between(up, np.array([0.0, 0.0, 1.0]))


def _flat_foot_pitches(ankles: list[np.ndarray], toe_bases: list[np.ndarray], fps: float, default_pitch: float,
                       notes: list[str]) -> list[float]:
    """Step 5 of `load_mocap`: each foot's flat-foot pitch, radians (left, right), measured on the clip
    (`flat_foot_pitch`). A foot that is never still takes the other foot's pitch, or the skeleton's default; if
    the feet differ by more than MAX_FOOT_PITCH_DIFFERENCE, one of them stood mostly on its toes (a dancer's
    releve) and both take the smaller pitch."""
    measured = [flat_foot_pitch(ankles[f], toe_bases[f], fps) for f in range(2)]
    pitches = [next((p for p in (measured[f], measured[1 - f]) if p is not None), default_pitch)
               for f in range(2)]
    if measured[0] is None or measured[1] is None:
        notes.append(f"a foot is never still: flat-foot pitches taken as {np.degrees(pitches).round(0)} degrees")
    elif abs(pitches[0] - pitches[1]) > MAX_FOOT_PITCH_DIFFERENCE:
        notes.append(f"flat-foot pitches {np.degrees(pitches).round(0)} degrees differ: both set to the smaller")
        pitches = [min(pitches)] * 2
    return pitches


def _floor_height(positions: np.ndarray, fps: float, notes: list[str]) -> float:
    """Step 6 of `load_mocap`: the floor's height, metres, under the sole sites of positions (T, J, 3): the
    median height of the lowest of the four sole sites, over the frames where that site is still (planted; a
    foot held still in the air is never the lowest); if there are none, the FLOOR_PERCENTILE (10th) percentile
    over frames of the lowest site."""
    sites = positions[:, [JOINT_INDEX[n] for n in ("left_heel", "left_toe", "right_heel", "right_toe")]]
    lowest = np.argmin(sites[..., 2], axis=1)
    lowest_site = sites[np.arange(len(sites)), lowest]
    planted = _still(sites, fps)[np.arange(len(sites)), lowest]
    if planted.sum() >= MIN_STILL_SECONDS * fps:
        return float(np.median(lowest_site[planted, 2]))
    notes.append("feet never still: floor from the lowest sole sites")
    return float(np.percentile(sites[..., 2].min(axis=1), FLOOR_PERCENTILE))


def _head_and_hand_rotations(world_rotations: Callable[[str], np.ndarray], layout: _SkeletonLayout,
                             level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 3, 3) head and (T, 2, 3, 3) hand frames in the levelled world, from the BVH joints' rotations."""
    head_rotation = level @ _frame_from_axes(
        world_rotations(layout.points["head"]), layout.head_forward_local, layout.head_left_local
    )
    hand_rotations = np.stack(
        [
            level @ _frame_from_axes(world_rotations(hand), layout.hand_distal_local[h], layout.hand_thumb_local[h])
            for h, hand in enumerate(layout.hands)
        ],
        axis=1,
    )
    return head_rotation, hand_rotations


def _note_implausible_jumps(positions: np.ndarray, fps: float, notes: list[str]) -> None:
    speeds = np.linalg.norm(np.diff(positions, axis=0), axis=-1).max(axis=1) * fps
    glitches = np.flatnonzero(speeds > IMPLAUSIBLE_SPEED)
    if glitches.size:
        notes.append(
            f"{glitches.size} implausible jumps (> {IMPLAUSIBLE_SPEED:.0f} m/s) between frames, first after frame "
            f"{glitches[0]}"
        )


def body_scale(clip: MocapClip) -> float:
    """Size of the person relative to the reference adult: mean thigh + shank length / REFERENCE_LEG_LENGTH."""
    legs = [
        np.linalg.norm(clip.joint(f"{side}_knee") - clip.joint(f"{side}_hip"), axis=1)
        + np.linalg.norm(clip.joint(f"{side}_ankle") - clip.joint(f"{side}_knee"), axis=1)
        for side in ("left", "right")
    ]
    return float(np.mean(legs) / REFERENCE_LEG_LENGTH)


def standing_height(clip: MocapClip) -> float:
    """Estimated stature in metres: the 95th percentile over frames of the crown's height above the lowest sole site.

    The crown is REFERENCE_CROWN_ABOVE_HEAD_JOINT x body_scale above the head joint along the head's up axis.
    Measuring from the lowest sole site of the same frame keeps jumps and uneven ground out; the estimate holds
    for clips where the person stands upright at least 5 % of the time.
    """
    crown = clip.joint("head") + REFERENCE_CROWN_ABOVE_HEAD_JOINT * body_scale(clip) * clip.head_rotation[:, :, 2]
    sites = clip.positions[:, [JOINT_INDEX[n] for n in ("left_heel", "left_toe", "right_heel", "right_toe")], 2]
    return float(np.percentile(crown[:, 2] - sites.min(axis=1), 95))
