"""Export a motion of the body model as a BVH file (Y up, Mixamo-style joint names).

The BVH axes are the world's axes permuted cyclically, (X, Y, Z)_bvh = (y, z, x)_world: a proper rotation, so the
character stands along +Y, faces +Z and has its left side at +X, as Mixamo and Blender expect. The rest pose
(all channels zero) is the body model's T-pose, so every OFFSET is the model's rest offset in BVH axes.

Joints: one per body of the model (Hips, Spine, Neck, LeftArm, LeftForeArm, LeftHand, LeftUpLeg, LeftLeg,
LeftFoot and the right-hand counterparts) plus two kinds of fixed joints that only mark points: Head at the head
centre (ear midpoint) under Neck, and LeftToeBase / RightToeBase at the toe contact points under the feet. Fixed
joints carry rotation channels that stay zero, since some BVH readers reject a JOINT without channels. End Sites
sit at the vertex above Head, at the midpoint of the index and little-finger knuckles beyond each hand, and a little
in front of each toe point.

Channels: the root has "Xposition Yposition Zposition Zrotation Xrotation Yrotation", every other joint
"Zrotation Xrotation Yrotation", in degrees. A joint's rotation is R = Rz(a) Rx(b) Ry(c) for its channel values
(a, b, c), and a point p in the joint's frame lies at R p + OFFSET in its parent's frame; the root's position
channels add to its OFFSET, which is zero.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..body.kinematics import forward_kinematics
from ..body.model import BodyModel
from .atomic import write_text
from .finite import finite_frames

# Body model body name -> BVH joint name.
BVH_JOINT_NAMES: dict[str, str] = {
    "pelvis": "Hips",
    "torso": "Spine",
    "head": "Neck",
    "left_upper_arm": "LeftArm",
    "left_forearm": "LeftForeArm",
    "left_hand": "LeftHand",
    "right_upper_arm": "RightArm",
    "right_forearm": "RightForeArm",
    "right_hand": "RightHand",
    "left_thigh": "LeftUpLeg",
    "left_shin": "LeftLeg",
    "left_foot": "LeftFoot",
    "right_thigh": "RightUpLeg",
    "right_shin": "RightLeg",
    "right_foot": "RightFoot",
}

# World (x, y, z) -> BVH (X, Y, Z) = (y, z, x): rows pick the world axis for each BVH axis. det = +1.
WORLD_TO_BVH = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

UNIT_SCALE: dict[str, float] = {"m": 1.0, "cm": 100.0}

# The toe End Site lies this fraction of SkeletonLengths.toe_front (ankle to toe) in front of the toe point.
TOE_END_FRACTION = 0.25

ROOT_CHANNELS = "Xposition Yposition Zposition Zrotation Xrotation Yrotation"
ROTATION_CHANNELS = "Zrotation Xrotation Yrotation"
EULER_SEQUENCE = "ZXY"  # scipy's intrinsic sequence matching ROTATION_CHANNELS


@dataclass(frozen=True)
class BvhJoint:
    """One joint of the exported hierarchy, in world axes at rest.

    name: BVH joint name. parent: index in the joint list, -1 for the root.
    offset: (3,) from the parent joint's centre at rest, world axes, metres.
    body: the model body whose orientation the joint follows; for a fixed joint, the body it is attached to.
    fixed: True for a joint that only marks a point (its channels stay zero).
    end_site: (3,) End Site offset from this joint, world axes, metres; None where the joint has children.
    """

    name: str
    parent: int
    offset: np.ndarray
    body: int
    fixed: bool
    end_site: np.ndarray | None


def bvh_hierarchy(body: BodyModel) -> list[BvhJoint]:
    """The exported joints in depth-first order (the order of the BVH file and its channels)."""
    L = body.lengths
    up = np.array([0.0, 0.0, 1.0])
    forward = np.array([1.0, 0.0, 0.0])
    joints: list[BvhJoint] = []
    joint_of_body: dict[int, int] = {}

    def add(name: str, parent: int, offset: np.ndarray, body_index: int, fixed: bool,
            end_site: np.ndarray | None = None) -> int:
        joints.append(BvhJoint(name, parent, np.asarray(offset, float), body_index, fixed, end_site))
        return len(joints) - 1

    def point_offset(name: str) -> np.ndarray:
        return body.points[int(body.point_index([name])[0])].offset

    def visit(body_index: int) -> None:
        model_body = body.bodies[body_index]
        parent = -1 if model_body.parent < 0 else joint_of_body[model_body.parent]
        offset = np.zeros(3) if parent < 0 else model_body.offset
        children = [i for i, b in enumerate(body.bodies) if b.parent == body_index]
        end_site = None
        if model_body.name.endswith("_hand"):
            side = model_body.name.removesuffix("_hand")
            end_site = (point_offset(f"{side}_index") + point_offset(f"{side}_pinky")) / 2
        index = add(BVH_JOINT_NAMES[model_body.name], parent, offset, body_index, False, end_site)
        joint_of_body[body_index] = index
        if model_body.name == "head":
            add("Head", index, point_offset("head"), body_index, True, end_site=up * L.head_top)
        if model_body.name.endswith("_foot"):
            side = model_body.name.removesuffix("_foot")
            add(f"{side.capitalize()}ToeBase", index, point_offset(f"{side}_toe"), body_index, True,
                end_site=forward * TOE_END_FRACTION * L.toe_front)
        for child in children:
            visit(child)

    roots = [i for i, b in enumerate(body.bodies) if b.parent < 0]
    if len(roots) != 1:
        raise ValueError(f"the body model must have exactly one root body, found {len(roots)}.")
    visit(roots[0])
    return joints


def local_rotations(body: BodyModel, joints: list[BvhJoint], qpos: np.ndarray) -> np.ndarray:
    """(T, J, 3, 3) joint rotations relative to their parents, in BVH axes; the root's is its world rotation."""
    world = forward_kinematics(body, qpos).rotations  # (T, B, 3, 3)
    T = len(world)
    local = np.tile(np.eye(3), (T, len(joints), 1, 1))
    for j, joint in enumerate(joints):
        if joint.fixed:
            continue
        parent_body = body.bodies[joint.body].parent
        child = world[:, joint.body]
        local[:, j] = child if parent_body < 0 else np.swapaxes(world[:, parent_body], 1, 2) @ child
    return WORLD_TO_BVH @ local @ WORLD_TO_BVH.T


def continuous_euler_degrees(rotations: np.ndarray) -> np.ndarray:
    """(T, J, 3, 3) rotations -> (T, J, 3) intrinsic ZXY Euler angles in degrees that change smoothly over time.

    Each rotation has two Euler triples, (a, b, c) and (a + 180, 180 - b, c + 180); of these, shifted by whole
    turns, each frame takes the one nearest the previous frame's angles, so the curves have no 360-degree jumps and
    do not flip between the two solutions when the middle angle passes +-90 degrees.
    """
    T, J = rotations.shape[:2]
    with warnings.catch_warnings():
        # At b = +-90 degrees only a +- c is defined; scipy then sets c = 0 and warns. The triple is still exact.
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        principal = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_euler(EULER_SEQUENCE, degrees=True)
    principal = principal.reshape(T, J, 3)
    alternate = principal * np.array([1.0, -1.0, 1.0]) + 180.0
    angles = np.empty_like(principal)
    angles[0] = principal[0]
    for t in range(1, T):
        candidates = np.stack([principal[t], alternate[t]])  # (2, J, 3)
        candidates -= 360.0 * np.round((candidates - angles[t - 1]) / 360.0)
        distance = np.abs(candidates - angles[t - 1]).sum(axis=-1)  # (2, J)
        angles[t] = np.where((distance[1] < distance[0])[:, None], candidates[1], candidates[0])
    return angles


def _format_row(values: np.ndarray) -> str:
    """Numbers with six decimals; adding 0.0 turns the -0.0 of rounded tiny negatives into 0.0."""
    return " ".join(f"{v:.6f}" for v in np.round(values, 6) + 0.0)


def checked_motion(body: BodyModel, qpos, fps: float, file_format: str, path=None) -> np.ndarray:
    """qpos as a (T >= 1, nq) float array, its non-finite frames held at the last finite one (a warning names
    them and the file `path`); ValueError for a bad frame rate or shape."""
    if not np.isfinite(fps) or fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}.")
    qpos = np.atleast_2d(np.asarray(qpos, dtype=float))
    if qpos.ndim != 2 or qpos.shape[1] != body.nq or len(qpos) == 0:
        raise ValueError(f"qpos must have shape (T >= 1, {body.nq}), got {qpos.shape}.")
    return finite_frames(qpos, f"{file_format} {path or ''}".rstrip(), body.rest_qpos)


def write_bvh(
    path: str | os.PathLike,
    body: BodyModel,
    qpos: np.ndarray,
    fps: float,
    *,
    units: str = "m",
    root_at_origin: bool = False,
) -> None:
    """Write the motion `qpos` (T, nq) of `body` at `fps` frames per second to the BVH file `path`.

    units: "m" or "cm", for every OFFSET and position channel (the file itself cannot say which; BVH has no
    comments). Rotations are in degrees. root_at_origin: shift the motion horizontally so that the root starts
    above the origin (BVH X = Z = 0 in the first frame); its height is kept. The file is written atomically.
    """
    if units not in UNIT_SCALE:
        raise ValueError(f"units must be one of {sorted(UNIT_SCALE)}, got {units!r}.")
    qpos = checked_motion(body, qpos, fps, "BVH", path)
    scale = UNIT_SCALE[units]

    joints = bvh_hierarchy(body)
    root_position = qpos[:, 0:3] @ WORLD_TO_BVH.T  # (T, 3) BVH axes, metres
    if root_at_origin:
        root_position = root_position - root_position[0] * np.array([1.0, 0.0, 1.0])
    rotations = local_rotations(body, joints, qpos)  # (T, J, 3, 3)
    euler = continuous_euler_degrees(rotations)  # (T, J, 3)
    motion = np.concatenate([root_position * scale, euler.reshape(len(qpos), -1)], axis=1)

    lines = ["HIERARCHY"]

    def emit(index: int, depth: int) -> None:
        joint = joints[index]
        pad = "\t" * depth
        lines.append(f"{pad}{'ROOT' if joint.parent < 0 else 'JOINT'} {joint.name}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {_format_row(WORLD_TO_BVH @ joint.offset * scale)}")
        channels = ROOT_CHANNELS if joint.parent < 0 else ROTATION_CHANNELS
        lines.append(f"{pad}\tCHANNELS {len(channels.split())} {channels}")
        for child in (i for i, j in enumerate(joints) if j.parent == index):
            emit(child, depth + 1)
        if joint.end_site is not None:
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{",
                          f"{pad}\t\tOFFSET {_format_row(WORLD_TO_BVH @ joint.end_site * scale)}", f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {len(motion)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [_format_row(row) for row in motion]
    write_text(path, "\n".join(lines) + "\n")
