"""The character's motion on its own rig: every bone's rotation per frame (`rig_motion`), its joints' world
positions (`rig_positions`), and the files: BVH with the rig's hierarchy, names, offsets and channel orders
(`write_rig_bvh`), and, for a glTF character, the same glTF document with the animation added (`write_rig_glb`).

A bone's world rotation relative to its rest is Delta_j(t) = R_body(t) C_body^T (character.py); the root
(whatever bone that is) is placed so that the hip midpoint lands on the body model's pelvis. Rotations are
turned into the file's axes (A^T Delta A) and made local to the parent; in glTF the rest rotations of the nodes
(and of the nodes above the skeleton) are kept, so the animation starts from the file's own rest pose.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..body import kinematics as kin
from ..io.atomic import atomic_path, write_text
from .character import Character
from .rig import Rig

FLOAT, ANIMATION_NAME = 5126, "physmocap"


@dataclass
class RigMotion:
    """delta: (T, J, 3, 3) each joint's world rotation relative to its rest, world axes; root: (T, 3) the root
    joint's world position, metres."""

    delta: np.ndarray
    root: np.ndarray


def rig_motion(character: Character, qpos: np.ndarray) -> RigMotion:
    """The rig's motion that follows the body model's motion qpos (T, nq)."""
    pose = kin.forward_kinematics(character.body, qpos)
    R = pose.rotations[:, character.segment]  # (T, J, 3, 3)
    delta = R @ np.swapaxes(character.alignment[character.segment], 1, 2)[None]
    pelvis = character.body.body_index["pelvis"]
    bones = character.bones
    hips_mid = (character.rest[bones["left_hip"]] + character.rest[bones["right_hip"]]) / 2
    root = pose.origins[:, pelvis] + pose.rotations[:, pelvis] @ (character.rest[0] - hips_mid)
    return RigMotion(delta, root)


def rig_positions(character: Character, motion: RigMotion) -> np.ndarray:
    """(T, J, 3) world positions of every rig joint, metres: the rest offsets turned by the parents' rotations."""
    rest, parents = character.rest, character.rig.parents
    out = np.empty(motion.delta.shape[:2] + (3,))
    for j, parent in enumerate(parents):
        if parent < 0:
            out[:, j] = motion.root if j == 0 else motion.root + (rest[j] - rest[0])
        else:
            out[:, j] = out[:, parent] + motion.delta[:, parent] @ (rest[j] - rest[parent])
    return out


def _file_rotations(character: Character, motion: RigMotion) -> np.ndarray:
    """(T, J, 3, 3) Delta in the file's axes: A^T Delta A."""
    A = character.file_to_world
    return A.T @ motion.delta @ A


def continuous_euler_degrees(rotations: np.ndarray, sequence: str) -> np.ndarray:
    """(T, J, 3, 3) -> (T, J, 3) intrinsic Euler angles (`sequence`, e.g. "ZYX") in degrees, each frame choosing
    between a rotation's two triples (a, b, c) and (a + 180, 180 - b, c + 180), shifted by whole turns, the one
    nearest the previous frame's, so that the curves have no jumps."""
    T, J = rotations.shape[:2]
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        principal = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_euler(sequence, degrees=True)
    principal = principal.reshape(T, J, 3)
    alternate = principal * np.array([1.0, -1.0, 1.0]) + np.array([180.0, 180.0, 180.0])
    angles = np.empty_like(principal)
    angles[0] = principal[0]
    for t in range(1, T):
        candidates = np.stack([principal[t], alternate[t]])
        candidates -= 360.0 * np.round((candidates - angles[t - 1]) / 360.0)
        distance = np.abs(candidates - angles[t - 1]).sum(axis=-1)
        angles[t] = np.where((distance[1] < distance[0])[:, None], candidates[1], candidates[0])
    return angles


def _row(values) -> str:
    return " ".join(f"{v:.6f}" for v in np.round(np.asarray(values, float), 6) + 0.0)


def _bvh_offsets_and_channels(rig: Rig) -> tuple[np.ndarray, list[list[str]]]:
    """Each joint's OFFSET (J, 3) and CHANNELS in the file written: a BVH rig's own (less the non-root position
    channels' rest values), a glTF rig's rest offsets with Z-X-Y rotations; the root gets position channels."""
    J = len(rig.names)
    if rig.kind == "bvh":
        offsets = rig.rest_local[:, :3, 3].copy()
        channels = [list(c) for c in rig.channels]
        if rig.rest_frame is not None:  # with_rest_frame added non-root position channels to the offsets
            start = 0
            for j, names in enumerate(channels):
                for c, channel in enumerate(names):
                    if channel.endswith("position") and j > 0:
                        offsets[j, "XYZ".index(channel[0])] -= rig.rest_frame[start + c]
                start += len(names)
    else:
        rest_file = rig.rest_world()[:, :3, 3]
        offsets = np.array([rest_file[j] - (rest_file[p] if p >= 0 else 0.0) for j, p in enumerate(rig.parents)])
        channels = [["Zrotation", "Xrotation", "Yrotation"] for _ in range(J)]
    if not any(c.endswith("position") for c in channels[0]):
        channels[0] = ["Xposition", "Yposition", "Zposition"] + channels[0]
    return offsets, channels


def _bvh_local_rotations(character: Character, motion: RigMotion) -> np.ndarray:
    """(T, J, 3, 3) each joint's rotation in the BVH written, relative to its parent in the file's axes."""
    rig = character.rig
    if rig.kind == "bvh":
        return local_rotations(character, motion)
    # the BVH's zero pose is the glTF rest pose: rotations relative to it, without the nodes' rest frames
    delta = _file_rotations(character, motion)
    local = delta.copy()
    for j, parent in enumerate(rig.parents):
        if parent >= 0:
            local[:, j] = np.swapaxes(delta[:, parent], 1, 2) @ delta[:, j]
    return local


def _depth_first(rig: Rig) -> list[int]:
    """The joints in depth-first order, as the hierarchy is written; the MOTION channels follow it."""
    order: list[int] = []
    stack = [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(rig.children(j)))
    return order


def _bvh_motion(character: Character, motion: RigMotion, offsets: np.ndarray, channels: list[list[str]]) -> np.ndarray:
    """(T, channels) the MOTION rows: the root's position less its OFFSET, a BVH rig's other position channels at
    their rest values, and continuous Euler angles in each joint's own rotation order, degrees."""
    rig = character.rig
    local = _bvh_local_rotations(character, motion)
    rest_values = np.zeros(sum(len(c) for c in rig.channels)) if rig.rest_frame is None else rig.rest_frame
    rest_starts = np.concatenate([[0], np.cumsum([len(c) for c in rig.channels])]).astype(int)
    root_file = character.to_file(motion.root)  # (T, 3)
    T = len(local)
    columns = []
    for j in _depth_first(rig):
        rotation_channels = [c for c in channels[j] if c.endswith("rotation")]
        euler = np.zeros((T, 0))
        if rotation_channels:
            sequence = "".join(c[0] for c in rotation_channels)
            if len(set(sequence)) != 3:
                raise ValueError(f"joint {rig.names[j]} has rotation channels {sequence}, not three distinct axes")
            euler = continuous_euler_degrees(local[:, j:j + 1], sequence)[:, 0]
        used = 0
        for channel in channels[j]:
            axis = "XYZ".index(channel[0])
            if channel.endswith("position"):
                kept = rest_values[rest_starts[j] + list(rig.channels[j]).index(channel)] \
                    if rig.kind == "bvh" and channel in rig.channels[j] else 0.0
                columns.append(root_file[:, axis] - offsets[0][axis] if j == 0 else np.full(T, kept))
            else:
                columns.append(euler[:, used])
                used += 1
    return np.stack(columns, axis=1) if columns else np.zeros((T, 0))


def _bvh_hierarchy(rig: Rig, offsets: np.ndarray, channels: list[list[str]]) -> list[str]:
    """The HIERARCHY section's lines: the rig's joints (spaces in names as underscores), End Sites, tab-indented."""
    lines = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "\t" * depth
        if rig.end_site[j]:
            lines.extend([f"{pad}End Site", f"{pad}{{", f"{pad}\tOFFSET {_row(offsets[j])}", f"{pad}}}"])
            return
        lines.append(f"{pad}{'ROOT' if rig.parents[j] < 0 else 'JOINT'} {rig.names[j].replace(' ', '_')}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {_row(offsets[j])}")
        lines.append(f"{pad}\tCHANNELS {len(channels[j])} {' '.join(channels[j])}")
        for child in rig.children(j):
            emit(child, depth + 1)
        lines.append(f"{pad}}}")

    emit(0, 0)
    return lines


def write_rig_bvh(path: str | os.PathLike, character: Character, motion: RigMotion, fps: float) -> None:
    """The motion as a BVH file with the rig's hierarchy. A BVH rig keeps its names, OFFSETs, End Sites and
    channel orders (a root without position channels gets them, since the character moves); a glTF rig becomes
    a BVH in its glTF axes and units whose zero pose is its rest pose (every joint a JOINT, channels "Xposition
    Yposition Zposition" on the root and "Zrotation Xrotation Yrotation"). Written atomically."""
    offsets, channels = _bvh_offsets_and_channels(character.rig)
    motion_rows = _bvh_motion(character, motion, offsets, channels)
    lines = _bvh_hierarchy(character.rig, offsets, channels)
    lines += ["MOTION", f"Frames: {len(motion_rows)}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [_row(row) for row in motion_rows]
    write_text(path, "\n".join(lines) + "\n")


def local_rotations(character: Character, motion: RigMotion) -> np.ndarray:
    """(T, J, 3, 3) each joint's rotation relative to its parent in the file's axes: the parent's rest frame F_p
    turned by the relative motion, F_p^T (Delta_p^T Delta_j) F_p, times the joint's own rest rotation (identity
    for a BVH rig at its zero pose)."""
    rig = character.rig
    world = rig.rest_world()
    scale = np.cbrt(np.abs(np.linalg.det(world[:, :3, :3])))
    frames = world[:, :3, :3] / scale[:, None, None]  # rest world rotations
    base_scale = np.cbrt(abs(np.linalg.det(rig.base[:3, :3])))
    base_frame = rig.base[:3, :3] / base_scale
    local_rest = rig.rest_local[:, :3, :3] / np.cbrt(np.abs(np.linalg.det(rig.rest_local[:, :3, :3])))[:, None, None]
    delta = _file_rotations(character, motion)
    T, J = delta.shape[:2]
    local = np.empty((T, J, 3, 3))
    for j, parent in enumerate(rig.parents):
        if parent < 0:
            relative, frame = delta[:, j], base_frame
        else:
            relative, frame = np.swapaxes(delta[:, parent], 1, 2) @ delta[:, j], frames[parent]
        local[:, j] = frame.T @ relative @ frame @ local_rest[j]
    return local


def gltf_animation(character: Character, motion: RigMotion) -> tuple[np.ndarray, np.ndarray]:
    """Local node rotations (T, J, 4) as glTF quaternions (x, y, z, w) and the root node's translation (T, 3)."""
    rig = character.rig
    local = local_rotations(character, motion)
    T, J = local.shape[:2]
    quats = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_quat().reshape(T, J, 4)
    flips = np.ones((T, J))
    flips[1:] = np.where(np.einsum("tjk,tjk->tj", quats[1:], quats[:-1]) < 0.0, -1.0, 1.0)
    quats = quats * np.cumprod(flips, axis=0)[..., None]
    root_file = character.to_file(motion.root)
    inverse_base = np.linalg.inv(rig.base)
    translation = root_file @ inverse_base[:3, :3].T + inverse_base[:3, 3]
    return quats, translation


def write_rig_glb(path: str | os.PathLike, character: Character, motion: RigMotion, fps: float) -> None:
    """The character's glTF document (mesh, skin, materials, nodes and any earlier animations unchanged) with one
    more animation, "physmocap": the root node's translation and every joint node's rotation per frame (LINEAR).
    Written as a binary .glb, atomically."""
    import pygltflib

    from .rig import load_gltf

    gltf = load_gltf(character.rig.path)
    quats, translation = gltf_animation(character, motion)
    T = len(quats)
    blob = bytearray(gltf.binary_blob() or b"")
    blob += b"\0" * (-len(blob) % 4)

    def add(array: np.ndarray, kind: str, bounds: bool = False) -> int:
        packed = np.ascontiguousarray(array, dtype="<f4")
        gltf.bufferViews.append(pygltflib.BufferView(buffer=0, byteOffset=len(blob), byteLength=packed.nbytes))
        blob.extend(packed.tobytes())
        blob.extend(b"\0" * (-len(blob) % 4))
        accessor = pygltflib.Accessor(bufferView=len(gltf.bufferViews) - 1, componentType=FLOAT, count=len(packed),
                                      type=kind)
        if bounds:
            accessor.min, accessor.max = packed.min(axis=0).tolist(), packed.max(axis=0).tolist()
        gltf.accessors.append(accessor)
        return len(gltf.accessors) - 1

    times = add((np.arange(T) / fps).reshape(-1, 1), "SCALAR", bounds=True)
    samplers = [pygltflib.AnimationSampler(input=times, output=add(translation, "VEC3"), interpolation="LINEAR")]
    channels = [pygltflib.AnimationChannel(sampler=0, target=pygltflib.AnimationChannelTarget(
        node=character.rig.nodes[0], path="translation"))]
    for j, node in enumerate(character.rig.nodes):
        samplers.append(pygltflib.AnimationSampler(input=times, output=add(quats[:, j], "VEC4"),
                                                   interpolation="LINEAR"))
        channels.append(pygltflib.AnimationChannel(sampler=len(samplers) - 1, target=pygltflib.AnimationChannelTarget(
            node=node, path="rotation")))
    gltf.animations.append(pygltflib.Animation(name=ANIMATION_NAME, samplers=samplers, channels=channels))
    if not gltf.buffers:
        gltf.buffers.append(pygltflib.Buffer(byteLength=0))
    gltf.buffers[0].byteLength = len(blob)
    gltf.buffers[0].uri = None
    gltf.set_binary_blob(bytes(blob))
    with atomic_path(path) as tmp:
        gltf.save_binary(str(tmp))
