"""Export a motion of the body model as a binary glTF 2.0 file (.glb): a skinned mannequin animated by the skeleton.

Written by hand with numpy and struct (the format is a JSON scene description plus one binary buffer, and no
runtime dependency is needed for it). Conventions of glTF: metres, +Y up, +Z forward, +X left. The world axes
map as (X, Y, Z)_gltf = (y, z, x)_world, the same proper rotation as the BVH export, so the character stands
along +Y, faces +Z and has its left side at +X.

Skeleton: the BVH export's joints (`bvh_hierarchy`), with the same Mixamo-style names (Hips, Spine, Neck, Head,
LeftArm, ..., LeftToeBase), plus one leaf node per BVH End Site named "<joint>_End" (the vertex above Head, the
knuckle midpoint beyond each hand, a point in front of each toe). Every node's rest translation is its offset from
the parent in the body model's T-pose; rest rotations are identity, so the rest pose is the T-pose standing on the
floor. The animation "motion" has one keyframe per video frame (time = frame / fps, LINEAR interpolation): the
root (Hips) translation, and the local rotation of every joint that moves (fixed marker joints and ends do not).

Mannequin: one ellipsoid per body segment, each rigidly skinned (weight 1) to the joint of its segment, in three
primitives coloured like the overlay (left side blue, right side orange, centre grey). The skin lists every
skeleton node; inverse bind matrices are the inverses of the nodes' rest transforms.
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

import physmocap

from ..body.kinematics import forward_kinematics
from ..body.model import BodyModel
from .atomic import atomic_path
from .bvh_export import WORLD_TO_BVH, BvhJoint, bvh_hierarchy, checked_motion, local_rotations

# glTF axes are the BVH export's axes (see the module docstring).
WORLD_TO_GLTF = WORLD_TO_BVH

GLB_MAGIC = 0x46546C67  # "glTF"
GLB_VERSION = 2
CHUNK_JSON = 0x4E4F534A  # "JSON"
CHUNK_BIN = 0x004E4942  # "BIN\0"

FLOAT = 5126
UNSIGNED_SHORT = 5123
UNSIGNED_INT = 5125
ARRAY_BUFFER = 34962
ELEMENT_ARRAY_BUFFER = 34963
COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}

# Overlay colours (sRGB 0-255), as linear RGBA base colours below.
SIDE_COLOURS_SRGB: dict[str, tuple[int, int, int]] = {
    "centre": (200, 200, 200), "left": (40, 150, 235), "right": (255, 140, 30),
}

ELLIPSOID_SEGMENTS = 16  # around the long axis
ELLIPSOID_RINGS = 10  # pole to pole


@dataclass(frozen=True)
class MannequinPart:
    """One ellipsoid of the mannequin at rest: centre (3,) and semi-axes (3,) along the world axes, metres.
    joint: the BVH joint name it is skinned to. side: "left", "right" or "centre"."""

    joint: str
    centre: np.ndarray
    radii: np.ndarray
    side: str


def mannequin_parts(body: BodyModel) -> list[MannequinPart]:
    """The mannequin's ellipsoids for `body` in its T-pose: x forward, y left, z up (world axes)."""
    rest = forward_kinematics(body, body.rest_qpos).points[0]

    def point(name: str) -> np.ndarray:
        return rest[body.point_index([name])[0]]

    L = body.lengths
    size = body.height / 1.7  # thicknesses are those of a 1.70 m adult, scaled with the height
    parts = [
        MannequinPart("Hips", (point("pelvis") + point("spine")) / 2,
                      np.array([0.10 * size, L.hip_width / 2 + 0.06 * size, L.spine_low / 2 + 0.06 * size]),
                      "centre"),
        MannequinPart("Spine", (point("spine") + point("neck")) / 2,
                      np.array([0.11 * size, 0.42 * L.shoulder_width, 0.55 * L.spine_up]), "centre"),
        MannequinPart("Neck", (point("neck") + point("head")) / 2,
                      np.array([0.05 * size, 0.05 * size, 0.5 * L.head_height]), "centre"),
        MannequinPart("Neck", point("head") + np.array([0.01, 0.0, 0.3 * L.head_top]),
                      np.array([0.11 * size, 0.5 * L.ear_width + 0.02 * size, 0.7 * L.head_top + 0.03 * size]),
                      "centre"),
    ]

    def limb(side: str, joint: str, start: str, end: str, thickness: float) -> MannequinPart:
        a, b = point(f"{side}_{start}"), point(f"{side}_{end}")
        along = np.abs(b - a) / 2 + 0.01 * size
        radii = np.where(along > 0.02 * size, along, thickness * size)
        return MannequinPart(f"{side.capitalize()}{joint}", (a + b) / 2, radii, side)

    for side in ("left", "right"):
        prefix = side.capitalize()
        parts += [
            limb(side, "Arm", "shoulder", "elbow", 0.05),
            limb(side, "ForeArm", "elbow", "wrist", 0.04),
            limb(side, "UpLeg", "hip", "knee", 0.075),
            limb(side, "Leg", "knee", "ankle", 0.055),
        ]
        knuckles = (point(f"{side}_index") + point(f"{side}_pinky")) / 2
        wrist = point(f"{side}_wrist")
        parts.append(MannequinPart(f"{prefix}Hand", (wrist + knuckles) / 2,
                                   np.array([0.8 * L.hand_width + 0.01 * size,
                                             np.abs(knuckles - wrist)[1] / 2 + 0.02 * size, 0.018 * size]), side))
        heel, toe = point(f"{side}_heel"), point(f"{side}_toe")
        parts.append(MannequinPart(f"{prefix}Foot", (heel + toe) / 2 + np.array([0.0, 0.0, L.ankle_height / 2]),
                                   np.array([np.abs(toe - heel)[0] / 2 + 0.03 * size, 0.045 * size,
                                             L.ankle_height / 2]), side))  # its bottom is the sole
    return parts


def ellipsoid_mesh(centre: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A UV ellipsoid: positions (V, 3), unit normals (V, 3) and triangles (F, 3) counter-clockwise seen from
    outside. centre, radii: (3,) metres."""
    polar = np.linspace(0.0, np.pi, ELLIPSOID_RINGS + 1)
    azimuth = np.linspace(0.0, 2 * np.pi, ELLIPSOID_SEGMENTS + 1)
    p, a = np.meshgrid(polar, azimuth, indexing="ij")
    unit = np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], axis=-1).reshape(-1, 3)
    positions = centre + unit * radii
    normals = unit / radii
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    columns = ELLIPSOID_SEGMENTS + 1
    ring, segment = np.meshgrid(np.arange(ELLIPSOID_RINGS), np.arange(ELLIPSOID_SEGMENTS), indexing="ij")
    top_left = (ring * columns + segment).ravel()
    top_right, bottom_left, bottom_right = top_left + 1, top_left + columns, top_left + columns + 1
    ring = ring.ravel()
    # Each quad is two triangles; at the poles one of them has two corners on the pole and is left out.
    lower = np.stack([top_left, bottom_left, bottom_right], axis=1)[ring < ELLIPSOID_RINGS - 1]
    upper = np.stack([top_left, bottom_right, top_right], axis=1)[ring > 0]
    return positions, normals, np.concatenate([lower, upper])


class _BinaryBuffer:
    """Accumulates the binary chunk, one bufferView and one accessor per array."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.buffer_views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, array: np.ndarray, accessor_type: str, component_type: int = FLOAT, target: int | None = None,
            bounds: bool = False) -> int:
        """Append `array` (count, components) and return its accessor index. bounds: write min and max."""
        dtype = {FLOAT: "<f4", UNSIGNED_SHORT: "<u2", UNSIGNED_INT: "<u4"}[component_type]
        packed = np.ascontiguousarray(array, dtype=dtype)
        count = packed.shape[0]
        packed = packed.reshape(count, COMPONENTS[accessor_type])
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": packed.nbytes}
        if target is not None:
            view["target"] = target
        self.data += packed.tobytes()
        self.data += b"\0" * (-len(self.data) % 4)
        self.buffer_views.append(view)
        accessor = {"bufferView": len(self.buffer_views) - 1, "componentType": component_type, "count": count,
                    "type": accessor_type}
        if bounds:
            accessor["min"] = packed.min(axis=0).tolist()
            accessor["max"] = packed.max(axis=0).tolist()
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def _linear_rgba(srgb: tuple[int, int, int]) -> list[float]:
    """An sRGB 0-255 colour as glTF's linear baseColorFactor (RGBA)."""
    c = np.asarray(srgb, dtype=float) / 255.0
    linear = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return [round(float(v), 4) for v in linear] + [1.0]


def continuous_quaternions(rotations: np.ndarray) -> np.ndarray:
    """(T, J, 3, 3) rotations -> (T, J, 4) glTF quaternions (x, y, z, w), each frame's on the same hemisphere as
    the previous frame's, so that interpolation between keyframes takes the short way."""
    T, J = rotations.shape[:2]
    quats = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(T, J, 4)
    flips = np.ones((T, J))
    flips[1:] = np.where(np.einsum("tjk,tjk->tj", quats[1:], quats[:-1]) < 0.0, -1.0, 1.0)
    return quats * np.cumprod(flips, axis=0)[..., None]


def _skeleton_nodes(body: BodyModel, joints: list[BvhJoint]) -> tuple[list[dict], np.ndarray]:
    """The skeleton's nodes (the joints, then one "<joint>_End" leaf per End Site) with their rest translations
    and children, and each node's rest position (N, 3) in glTF axes."""
    names = [j.name for j in joints]
    ends = [(index, j) for index, j in enumerate(joints) if j.end_site is not None]
    node_count = len(joints) + len(ends)
    rest_root = WORLD_TO_GLTF @ body.rest_qpos[0:3]
    translations = [rest_root if j.parent < 0 else WORLD_TO_GLTF @ j.offset for j in joints]
    translations += [WORLD_TO_GLTF @ j.end_site for _, j in ends]
    parents = [j.parent for j in joints] + [index for index, _ in ends]
    rest_world = np.zeros((node_count, 3))
    for node in range(node_count):  # parents precede their children
        rest_world[node] = translations[node] + (rest_world[parents[node]] if parents[node] >= 0 else 0.0)

    nodes: list[dict] = []
    for node in range(node_count):
        name = names[node] if node < len(joints) else f"{joints[parents[node]].name}_End"
        entry: dict = {"name": name, "translation": [float(v) for v in translations[node]]}
        children = [child for child in range(node_count) if parents[child] == node]
        if children:
            entry["children"] = children
        nodes.append(entry)
    return nodes, rest_world


def _mannequin_mesh(buffer: _BinaryBuffer, body: BodyModel, names: list[str]) -> tuple[list[dict], list[dict]]:
    """The mannequin's primitives, one per side colour, each ellipsoid skinned to its joint (index into
    `names`), and their materials; their arrays go into `buffer`."""
    primitives: list[dict] = []
    materials: list[dict] = []
    parts = mannequin_parts(body)
    for side, colour in SIDE_COLOURS_SRGB.items():
        chosen = [p for p in parts if p.side == side]
        meshes = [ellipsoid_mesh(p.centre, p.radii) for p in chosen]
        offsets = np.cumsum([0] + [len(m[0]) for m in meshes])
        positions = np.concatenate([m[0] for m in meshes]) @ WORLD_TO_GLTF.T
        normals = np.concatenate([m[1] for m in meshes]) @ WORLD_TO_GLTF.T
        triangles = np.concatenate([m[2] + offset for m, offset in zip(meshes, offsets[:-1], strict=True)])
        joint_ids = np.concatenate([np.full(len(m[0]), names.index(p.joint))
                                    for m, p in zip(meshes, chosen, strict=True)])
        joints_attribute = np.zeros((len(joint_ids), 4), dtype=np.uint16)
        joints_attribute[:, 0] = joint_ids
        weights = np.zeros((len(joint_ids), 4))
        weights[:, 0] = 1.0
        primitives.append({
            "attributes": {
                "POSITION": buffer.add(positions, "VEC3", target=ARRAY_BUFFER, bounds=True),
                "NORMAL": buffer.add(normals, "VEC3", target=ARRAY_BUFFER),
                "JOINTS_0": buffer.add(joints_attribute, "VEC4", UNSIGNED_SHORT, target=ARRAY_BUFFER),
                "WEIGHTS_0": buffer.add(weights, "VEC4", target=ARRAY_BUFFER),
            },
            "indices": buffer.add(triangles.reshape(-1), "SCALAR", UNSIGNED_INT, target=ELEMENT_ARRAY_BUFFER),
            "material": len(materials),
        })
        materials.append({"name": f"mannequin_{side}", "pbrMetallicRoughness": {
            "baseColorFactor": _linear_rgba(colour), "metallicFactor": 0.0, "roughnessFactor": 0.7}})
    return primitives, materials


def _skin(buffer: _BinaryBuffer, rest_world: np.ndarray) -> dict:
    """The skin of every node, its inverse bind matrices (the inverse rest translations) put into `buffer`."""
    node_count = len(rest_world)
    inverse_bind = np.tile(np.eye(4), (node_count, 1, 1))
    inverse_bind[:, :3, 3] = -rest_world
    return {"name": "skeleton", "joints": list(range(node_count)), "skeleton": 0,
            "inverseBindMatrices": buffer.add(np.transpose(inverse_bind, (0, 2, 1)).reshape(node_count, 16),
                                              "MAT4")}  # column-major


def _animation(buffer: _BinaryBuffer, body: BodyModel, joints: list[BvhJoint], qpos: np.ndarray, fps: float,
               root_at_origin: bool) -> dict:
    """The animation "motion": the root's translation and every moving joint's rotation, one keyframe a frame."""
    T = len(qpos)
    times = buffer.add(np.arange(T) / fps, "SCALAR", bounds=True)
    root = qpos[:, 0:3] @ WORLD_TO_GLTF.T
    if root_at_origin:
        root = root - root[0] * np.array([1.0, 0.0, 1.0])  # glTF X and Z are horizontal
    samplers = [{"input": times, "output": buffer.add(root, "VEC3"), "interpolation": "LINEAR"}]
    channels = [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]
    quaternions = continuous_quaternions(local_rotations(body, joints, qpos))
    for index, joint in enumerate(joints):
        if joint.fixed:
            continue
        samplers.append({"input": times, "output": buffer.add(quaternions[:, index], "VEC4"),
                         "interpolation": "LINEAR"})
        channels.append({"sampler": len(samplers) - 1, "target": {"node": index, "path": "rotation"}})
    return {"name": "motion", "samplers": samplers, "channels": channels}


def glb_document(body: BodyModel, qpos: np.ndarray, fps: float, *,
                 root_at_origin: bool = False) -> tuple[dict, bytes]:
    """The glTF JSON and its binary buffer for the motion qpos (T, nq) of `body` at `fps` (see the module)."""
    joints: list[BvhJoint] = bvh_hierarchy(body)
    nodes, rest_world = _skeleton_nodes(body, joints)
    mesh_node = len(nodes)
    nodes.append({"name": "Mannequin", "mesh": 0, "skin": 0})
    buffer = _BinaryBuffer()  # the mesh's arrays first, then the skin's, then the animation's
    primitives, materials = _mannequin_mesh(buffer, body, [j.name for j in joints])
    skin = _skin(buffer, rest_world)
    animation = _animation(buffer, body, joints, qpos, fps, root_at_origin)
    document = {
        "asset": {"version": "2.0", "generator": f"physmocap {physmocap.__version__}"},
        "scene": 0,
        "scenes": [{"name": "physmocap", "nodes": [0, mesh_node]}],
        "nodes": nodes,
        "meshes": [{"name": "Mannequin", "primitives": primitives}],
        "materials": materials,
        "skins": [skin],
        "animations": [animation],
        "buffers": [{"byteLength": len(buffer.data)}],
        "bufferViews": buffer.buffer_views,
        "accessors": buffer.accessors,
    }
    return document, bytes(buffer.data)


def glb_bytes(document: dict, binary: bytes) -> bytes:
    """The GLB container: 12-byte header, the JSON chunk (space padded) and the BIN chunk (zero padded)."""
    text = json.dumps(document, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    length = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<III", GLB_MAGIC, GLB_VERSION, length),
                     struct.pack("<II", len(text), CHUNK_JSON), text,
                     struct.pack("<II", len(binary), CHUNK_BIN), binary])


def write_glb(path: str | os.PathLike, body: BodyModel, qpos: np.ndarray, fps: float, *,
              root_at_origin: bool = False) -> None:
    """Write the motion `qpos` (T, nq) of `body` at `fps` frames per second to the GLB file `path`.

    Metres, Y up (see the module docstring). root_at_origin: shift the motion horizontally so that the root starts
    above the origin; its height is kept. The file is written atomically.
    """
    qpos = checked_motion(body, qpos, fps, "glTF animation", path)
    document, binary = glb_document(body, qpos, fps, root_at_origin=root_at_origin)
    with atomic_path(path) as tmp:
        tmp.write_bytes(glb_bytes(document, binary))
