"""Read a character's skeleton (its rig) from a BVH file or a skinned glTF/GLB file.

A `Rig` holds the hierarchy and rest pose in the file's own axes and units; `rest_world` gives every joint's rest
transform. BVH: the rest pose is every channel at zero (the OFFSETs), parsed by `mocap.bvh_reader.parse_bvh`,
End Sites kept as leaf joints. glTF: the skin's joints with their nodes' rest TRS (uniform scale only), plus the
constant transform of the non-joint nodes above them, and the mesh's rest vertices (for the soles and the crown).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import InputError
from ..mocap.bvh_reader import read_bvh


@dataclass(frozen=True)
class Rig:
    """A character's skeleton at rest. J joints, parents first.

    names: (J,) joint names (BVH End Sites: "<parent>_End"). parents: (J,) parent index, -1 for the root.
    rest_local: (J, 4, 4) each joint's rest transform relative to its parent (the root's relative to `base`),
        file axes and units. base: (4, 4) transform of the root's parent (glTF nodes above the skeleton).
    end_site: (J,) True for BVH End Sites (written back as End Sites, without channels).
    channels: per joint its BVH channel names (empty for glTF rigs and End Sites).
    units_to_metres: file length unit in metres (glTF: 1). kind: "bvh" or "gltf".
    nodes: (J,) glTF node index of each joint (empty for BVH). vertices: (V, 3) rest mesh vertices in file axes
        and units (glTF skinned meshes; None otherwise). humanoid: VRM humanoid bone -> joint index, if the file
        declares one. path: the file read. first_frame: (C,) a BVH file's first frame of channel values (None
        without frames); rest_frame: the channel values of the rest pose in use (None: all zero).
    """

    names: tuple[str, ...]
    parents: np.ndarray
    rest_local: np.ndarray
    base: np.ndarray
    end_site: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    units_to_metres: float
    kind: str
    path: str
    nodes: tuple[int, ...] = ()
    vertices: np.ndarray | None = None
    humanoid: dict | None = None
    first_frame: np.ndarray | None = None
    rest_frame: np.ndarray | None = None

    def rest_world(self) -> np.ndarray:
        """(J, 4, 4) every joint's rest transform in the file's world, file units."""
        world = np.empty_like(self.rest_local)
        for j, parent in enumerate(self.parents):
            world[j] = (self.base if parent < 0 else world[parent]) @ self.rest_local[j]
        return world

    def children(self, joint: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == joint)]

    def descendants(self, joint: int) -> list[int]:
        out, stack = [], self.children(joint)
        while stack:
            j = stack.pop()
            out.append(j)
            stack.extend(self.children(j))
        return out


def _translation(offset) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = offset
    return m


def read_bvh_rig(path: str | os.PathLike, units_to_metres: float | None = None) -> Rig:
    """The hierarchy and rest pose (all channels zero) of a BVH file; its motion is ignored.

    units_to_metres: the file's length unit; None guesses it from the legs (`guess_units`)."""
    bvh = read_bvh(path)
    names = tuple(j.name for j in bvh.joints)
    parents = np.array([j.parent for j in bvh.joints])
    rest_local = np.stack([_translation(j.offset) for j in bvh.joints])
    end_site = np.array([j.name.endswith("_End") and not j.channels and j.parent >= 0
                         and not any(k.parent == i for k in bvh.joints) for i, j in enumerate(bvh.joints)])
    rig = Rig(names, parents, rest_local, np.eye(4), end_site, tuple(j.channels for j in bvh.joints), 1.0, "bvh",
              str(path), first_frame=bvh.motion[0].copy() if len(bvh.motion) else None)
    return _with_units(rig, units_to_metres)


def with_rest_frame(rig: Rig, values: np.ndarray) -> Rig:
    """A BVH rig whose rest pose is the pose of one frame of channel values (C,) instead of all zeros (some
    exporters, e.g. Character Creator's, put every bone along +Y at zero and the T-pose in the first frame)."""
    from dataclasses import replace

    rest_local = rig.rest_local.copy()
    start = 0
    for j, channels in enumerate(rig.channels):
        rotation = np.eye(3)
        for c, channel in enumerate(channels):
            value = values[start + c]
            if channel.endswith("position"):
                if j > 0:  # the root's place comes from the motion; its rest is where its OFFSET puts it
                    rest_local[j, "XYZ".index(channel[0]), 3] += value
            else:
                rotation = rotation @ Rotation.from_euler(channel[0].lower(), value, degrees=True).as_matrix()
        rest_local[j, :3, :3] = rotation
        start += len(channels)
    return replace(rig, rest_local=rest_local, rest_frame=np.asarray(values, float).copy())


def guess_units(leg_length: float) -> float:
    """A BVH file cannot say its unit: legs (hip to ankle) of 0.2-3 units read as metres, of 20-300 as
    centimetres, of 200-3000 as millimetres; anything else must be given (the TOML map's units_to_metres)."""
    for unit, low, high in ((1.0, 0.2, 3.0), (0.01, 20.0, 300.0), (0.001, 200.0, 3000.0)):
        if low <= leg_length <= high:
            return unit
    return float("nan")


def _with_units(rig: Rig, units_to_metres: float | None) -> Rig:
    from dataclasses import replace

    if units_to_metres is not None:
        return replace(rig, units_to_metres=float(units_to_metres))
    return replace(rig, units_to_metres=float("nan"))  # decided once the legs are known (character.py)


# ---- glTF -------------------------------------------------------------------------------------------------------

def _node_matrix(node) -> np.ndarray:
    if node.matrix is not None and len(node.matrix) == 16:
        return np.array(node.matrix, dtype=float).reshape(4, 4).T  # column-major
    m = np.eye(4)
    scale = np.array(node.scale if node.scale is not None else [1.0, 1.0, 1.0], dtype=float)
    if node.rotation is not None:
        m[:3, :3] = Rotation.from_quat(node.rotation).as_matrix()
    m[:3, :3] = m[:3, :3] * scale
    if node.translation is not None:
        m[:3, 3] = node.translation
    return m


def read_accessor(gltf, index: int) -> np.ndarray:
    """(count, components) float array of a glTF accessor (tightly packed or strided, normalised ints as is)."""
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
    dtypes = {5126: "<f4", 5123: "<u2", 5125: "<u4", 5121: "u1", 5122: "<i2", 5120: "i1"}
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    blob = gltf.binary_blob()
    width = widths[accessor.type]
    dtype = np.dtype(dtypes[accessor.componentType])
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    stride = view.byteStride or width * dtype.itemsize
    rows = [np.frombuffer(blob, dtype, width, start + i * stride) for i in range(accessor.count)] \
        if view.byteStride else [np.frombuffer(blob, dtype, width * accessor.count, start).reshape(-1, width)]
    return np.vstack(rows).astype(float)


def load_gltf(path: str | os.PathLike):
    """The pygltflib document of a .glb or .gltf file with its buffers as one binary blob; InputError if
    unreadable."""
    import pygltflib

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such character file.")
    try:
        gltf = pygltflib.GLTF2().load(str(path))
        if gltf is None:
            raise ValueError("empty file")
        if path.suffix.lower() == ".gltf":
            gltf.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
        gltf.to_json(allow_nan=False)  # RFC 8259 JSON: a NaN anywhere would stop the writer, so stop here
    except Exception as exc:  # pygltflib raises whatever its JSON and struct parsing raise
        raise InputError(f"{path}: not a readable glTF/GLB file ({type(exc).__name__}: {exc}).") from None
    _check_views(gltf, path)
    return gltf


def _is_index(value, size: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < size


def _check_views(gltf, path: Path) -> None:
    """InputError unless every buffer view lies inside its buffer and every accessor names a view that exists
    (the reader reads them, and the writer copies every view when it adds the animation)."""
    if len(gltf.buffers) > 1:  # pygltflib reads one binary buffer
        raise InputError(f"{path}: the file holds {len(gltf.buffers)} buffers; export the character as one .glb.")
    blob_size = len(gltf.binary_blob() or b"")
    declared = gltf.buffers[0].byteLength if gltf.buffers else 0
    if isinstance(declared, int) and blob_size < declared:
        raise InputError(f"{path}: its buffer holds {blob_size} of the {declared} bytes it declares (its data file is "
                         "missing or unreadable, or the file is cut short).")
    for i, view in enumerate(gltf.bufferViews):
        offset, length = view.byteOffset or 0, view.byteLength
        if not (_is_index(view.buffer, len(gltf.buffers)) and _is_index(offset, blob_size + 1)
                and _is_index(length, blob_size + 1) and offset + length <= blob_size):
            raise InputError(f"{path}: buffer view {i} does not lie inside its buffer ({blob_size} bytes).")
    for i, accessor in enumerate(gltf.accessors):
        if accessor.bufferView is not None and not _is_index(accessor.bufferView, len(gltf.bufferViews)):
            raise InputError(f"{path}: accessor {i} names buffer view {accessor.bufferView}, which does not exist.")
        if not (_is_index(accessor.count, blob_size + 1) and _is_index(accessor.byteOffset or 0, blob_size + 1)):
            raise InputError(f"{path}: accessor {i} has a count or offset its buffer cannot hold.")


def read_gltf_rig(path: str | os.PathLike) -> Rig:
    """The first skin of a glTF/GLB file as a rig: its joints' rest TRS, the nodes above them, and the rest
    vertices of the meshes it skins (each vertex by its most weighted joint). InputError naming the file for a
    document that breaks the glTF rules it relies on (indices out of range, short buffers, a node hierarchy that
    is not a forest, numbers that are not finite)."""
    gltf = load_gltf(path)
    if not gltf.skins:
        raise InputError(f"{path}: the glTF file has no skin (a rigged character is needed).")
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # _skin_rig refuses what is not finite, in one sentence
            rig = _skin_rig(gltf, path)
    except InputError:
        raise
    except (IndexError, KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:  # indexing a broken one
        raise InputError(f"{path}: a malformed glTF file ({type(exc).__name__}: {exc}).") from None
    return rig


def _node_parents(gltf, path) -> dict[int, int]:
    """Each node's parent; InputError unless the nodes form trees (glTF 2.0, 3.5.3: one parent at most, no cycle)."""
    node_parent: dict[int, int] = {}
    for i, node in enumerate(gltf.nodes):
        for child in node.children or []:
            if not 0 <= child < len(gltf.nodes) or child in node_parent:
                raise InputError(f"{path}: node {i} lists child {child}, which is out of range or has two parents.")
            node_parent[child] = i
    for start in node_parent:
        seen, node = {start}, node_parent.get(start)
        while node is not None:
            if node in seen:
                raise InputError(f"{path}: the node hierarchy has a cycle through node {node}.")
            seen.add(node)
            node = node_parent.get(node)
    return node_parent


def _skin_rig(gltf, path) -> Rig:
    """read_gltf_rig's work on the loaded document; may raise what indexing a broken document raises."""
    skin = gltf.skins[0]
    joints = list(skin.joints)
    if len(set(joints)) != len(joints):
        raise InputError(f"{path}: the skin lists a joint node twice.")
    node_parent = _node_parents(gltf, path)
    joint_set = set(joints)

    def joint_parent(node: int) -> int:
        p = node_parent.get(node)
        while p is not None and p not in joint_set:
            p = node_parent.get(p)
        return -1 if p is None else p

    def world(node: int | None) -> np.ndarray:
        m = np.eye(4)
        while node is not None:
            m = _node_matrix(gltf.nodes[node]) @ m
            node = node_parent.get(node)
        return m

    # Parents first.
    ordered: list[int] = []

    def depth(node: int) -> int:
        d, p = 0, joint_parent(node)
        while p >= 0:
            d, p = d + 1, joint_parent(p)
        return d

    ordered = sorted(joints, key=lambda n: (depth(n), joints.index(n)))
    roots = [n for n in ordered if joint_parent(n) < 0]
    if len(roots) != 1:
        raise InputError(f"{path}: the skin's joints form {len(roots)} trees; one skeleton is needed.")
    index = {n: i for i, n in enumerate(ordered)}
    parents = np.array([index[joint_parent(n)] if joint_parent(n) >= 0 else -1 for n in ordered])
    rest_local = np.stack([_node_matrix(gltf.nodes[n]) for n in ordered])
    base = world(node_parent.get(roots[0]))
    names = tuple(gltf.nodes[n].name or f"node{n}" for n in ordered)
    rig = Rig(names, parents, rest_local, base, np.zeros(len(ordered), bool), tuple(() for _ in ordered), 1.0,
              "gltf", str(path), tuple(ordered), _rest_vertices(gltf, skin, ordered, rest_local, parents, base),
              _vrm_humanoid(gltf, index))
    arrays = (rig.rest_local, rig.base) + (() if rig.vertices is None else (rig.vertices,))
    if not all(np.isfinite(a).all() for a in arrays):
        raise InputError(f"{path}: the skeleton's rest transforms or vertices hold numbers that are not finite.")
    scales = [np.cbrt(abs(np.linalg.det(m[:3, :3]))) for m in rig.rest_world()]
    frames = [m[:3, :3] / s for m, s in zip(rig.rest_world(), scales, strict=True)]
    if any(not np.allclose(f @ f.T, np.eye(3), atol=1e-4) for f in frames):
        raise InputError(f"{path}: the skeleton has non-uniform scale, which retargeting does not handle.")
    return rig


def _rest_vertices(gltf, skin, ordered, rest_local, parents, base) -> np.ndarray | None:
    """(V, 3) rest vertices of the meshes skinned by `skin`, file axes (each by its most weighted joint)."""
    world = np.empty_like(rest_local)
    for j, p in enumerate(parents):
        world[j] = (base if p < 0 else world[p]) @ rest_local[j]
    by_node = {n: world[i] for i, n in enumerate(ordered)}
    inverse_bind = (read_accessor(gltf, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
                    if skin.inverseBindMatrices is not None else np.tile(np.eye(4), (len(skin.joints), 1, 1)))
    out = []
    for node in gltf.nodes:
        if node.mesh is None or node.skin != 0:
            continue
        for primitive in gltf.meshes[node.mesh].primitives:
            attributes = primitive.attributes
            if attributes.POSITION is None or attributes.JOINTS_0 is None or attributes.WEIGHTS_0 is None:
                continue
            positions = read_accessor(gltf, attributes.POSITION)
            joint_ids = read_accessor(gltf, attributes.JOINTS_0).astype(int)
            weights = read_accessor(gltf, attributes.WEIGHTS_0)
            top = joint_ids[np.arange(len(joint_ids)), np.argmax(weights, axis=1)]
            skinning = np.stack([by_node[skin.joints[k]] @ inverse_bind[k] for k in range(len(skin.joints))])
            homogeneous = np.c_[positions, np.ones(len(positions))]
            out.append(np.einsum("vij,vj->vi", skinning[top], homogeneous)[:, :3])
    return np.concatenate(out) if out else None


def _vrm_humanoid(gltf, index: dict[int, int]) -> dict | None:
    """VRM 0.x (extensions.VRM.humanoid.humanBones list) or VRM 1.0 (VRMC_vrm.humanoid.humanBones dict): VRM
    bone name -> joint index."""
    extensions = gltf.extensions or {}
    bones: dict[str, int] = {}
    if "VRM" in extensions:
        for entry in extensions["VRM"].get("humanoid", {}).get("humanBones", []):
            bones[entry.get("bone")] = entry.get("node")
    if "VRMC_vrm" in extensions:
        for bone, entry in extensions["VRMC_vrm"].get("humanoid", {}).get("humanBones", {}).items():
            bones[bone] = entry.get("node")
    found = {bone: index[node] for bone, node in bones.items() if node in index}
    return found or None


def read_rig(path: str | os.PathLike, units_to_metres: float | None = None) -> Rig:
    """A BVH (.bvh) or glTF (.glb, .gltf, .vrm) character; InputError for anything else."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        return read_bvh_rig(path, units_to_metres)
    if suffix in (".glb", ".gltf", ".vrm"):
        rig = read_gltf_rig(path)
        return rig if units_to_metres is None else _with_units(rig, units_to_metres)
    raise InputError(f"{path}: a character must be a .bvh, .glb, .gltf or .vrm file.")
