"""GLB export, read back with an independent glTF reader (pygltflib) and evaluated here with numpy: node transforms
from the animation channels, the skin's inverse bind matrices, and the skinned mannequin."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from physmocap.export import body_from_result
from physmocap.io.glb import write_glb
from test_export import synthetic_result

# glTF (X, Y, Z) = world (y, z, x): a glTF vector v is the world vector (v[2], v[0], v[1]).
GLTF_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# glTF node -> result.npz point at the node.
NODE_POINTS = {
    "Hips": "pelvis", "Spine": "spine", "Neck": "neck", "Head": "head",
    "LeftArm": "left_shoulder", "LeftForeArm": "left_elbow", "LeftHand": "left_wrist",
    "RightArm": "right_shoulder", "RightForeArm": "right_elbow", "RightHand": "right_wrist",
    "LeftUpLeg": "left_hip", "LeftLeg": "left_knee", "LeftFoot": "left_ankle", "LeftToeBase": "left_toe",
    "RightUpLeg": "right_hip", "RightLeg": "right_knee", "RightFoot": "right_ankle", "RightToeBase": "right_toe",
}
DTYPES = {5126: "<f4", 5123: "<u2", 5125: "<u4", 5121: "u1"}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def glb_json(data: bytes) -> tuple[dict, bytes]:
    """A GLB file's bytes -> its JSON document and the bytes after the JSON chunk (the binary chunk)."""
    size = int.from_bytes(data[12:16], "little")
    return json.loads(data[20:20 + size]), data[20 + size:]


def glb_with_json(document: dict, rest: bytes) -> bytes:
    """The GLB bytes of a JSON `document` followed by `rest` (as glb_json returned it), byte for byte otherwise:
    tests write documents pygltflib would refuse to save."""
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    chunks = len(text).to_bytes(4, "little") + b"JSON" + text + rest
    return b"glTF" + (2).to_bytes(4, "little") + (12 + len(chunks)).to_bytes(4, "little") + chunks


def read_accessor(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    """(count, components) array of accessor `index`, tightly packed as the glTF spec allows without byteStride."""
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    assert view.byteStride in (None, 0)
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    width = WIDTHS[accessor.type]
    data = np.frombuffer(gltf.binary_blob(), dtype=DTYPES[accessor.componentType], count=accessor.count * width,
                         offset=start)
    return data.reshape(accessor.count, width).astype(float)


def node_world_matrices(gltf: pygltflib.GLTF2) -> np.ndarray:
    """(T, N, 4, 4) world matrices of every node at every keyframe of the first animation (T = keyframes)."""
    animation = gltf.animations[0]
    times = read_accessor(gltf, animation.samplers[0].input)[:, 0]
    T, N = len(times), len(gltf.nodes)
    translation = np.array([n.translation or [0.0, 0.0, 0.0] for n in gltf.nodes])[None].repeat(T, 0)
    rotation = np.array([n.rotation or [0.0, 0.0, 0.0, 1.0] for n in gltf.nodes])[None].repeat(T, 0)
    for channel in animation.channels:
        sampler = animation.samplers[channel.sampler]
        assert sampler.interpolation == "LINEAR"
        np.testing.assert_array_equal(read_accessor(gltf, sampler.input)[:, 0], times)
        values = read_accessor(gltf, sampler.output)
        {"translation": translation, "rotation": rotation}[channel.target.path][:, channel.target.node] = values
    local = np.tile(np.eye(4), (T, N, 1, 1))
    local[..., :3, :3] = Rotation.from_quat(rotation.reshape(-1, 4)).as_matrix().reshape(T, N, 3, 3)
    local[..., :3, 3] = translation
    world = local.copy()
    parent = {child: index for index, node in enumerate(gltf.nodes) for child in (node.children or [])}

    def resolve(node: int) -> np.ndarray:
        if node in parent and not resolved[node]:
            world[:, node] = resolve(parent[node]) @ local[:, node]
        resolved[node] = True
        return world[:, node]

    resolved = [False] * N
    for node in range(N):
        resolve(node)
    return world


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    result = synthetic_result(frames=45)
    path = tmp_path_factory.mktemp("glb") / "motion.glb"
    write_glb(path, body_from_result(result), result["qpos"], float(result["fps"]))
    return result, path, pygltflib.GLTF2().load(str(path))


def test_file_is_glb_2(exported):
    _, path, gltf = exported
    header = Path(path).read_bytes()[:12]
    assert header[:4] == b"glTF" and int.from_bytes(header[4:8], "little") == 2
    assert int.from_bytes(header[8:12], "little") == Path(path).stat().st_size
    assert gltf.asset.version == "2.0"
    names = [n.name for n in gltf.nodes]
    assert set(NODE_POINTS) <= set(names) and names[0] == "Hips"
    assert gltf.skins[0].skeleton == 0 and len(gltf.meshes) == 1


def test_joint_positions_match_result_within_1mm(exported):
    result, _, gltf = exported
    world = node_world_matrices(gltf)
    names = [n.name for n in gltf.nodes]
    points = list(result["joint_names"])
    assert len(world) == len(result["joints_world"])
    for node, point in NODE_POINTS.items():
        position = world[:, names.index(node), :3, 3] @ GLTF_TO_WORLD.T
        error = np.linalg.norm(position - result["joints_world"][:, points.index(point)], axis=1)
        assert error.max() < 1e-3, (node, error.max())
    times = read_accessor(gltf, gltf.animations[0].samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(len(times)) / float(result["fps"]), atol=1e-6)


def test_hand_ends_sit_at_the_knuckles(exported):
    result, _, gltf = exported
    world = node_world_matrices(gltf)
    names = [n.name for n in gltf.nodes]
    points = list(result["joint_names"])
    for side in ("left", "right"):
        knuckles = (result["joints_world"][:, points.index(f"{side}_index")]
                    + result["joints_world"][:, points.index(f"{side}_pinky")]) / 2
        end = world[:, names.index(f"{side.capitalize()}Hand_End"), :3, 3] @ GLTF_TO_WORLD.T
        assert np.linalg.norm(end - knuckles, axis=1).max() < 1e-3


def test_rest_pose_is_the_bind_pose_standing_upright(exported):
    _, _, gltf = exported
    skin = gltf.skins[0]
    inverse_bind = read_accessor(gltf, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    rest_world = np.tile(np.eye(4), (len(gltf.nodes), 1, 1))
    for index, node in enumerate(gltf.nodes):  # rest: node translations only (parents come first)
        rest_world[index, :3, 3] = node.translation or [0.0, 0.0, 0.0]
        for parent, candidate in enumerate(gltf.nodes):
            if index in (candidate.children or []):
                rest_world[index, :3, 3] += rest_world[parent, :3, 3]
    for joint, matrix in zip(skin.joints, inverse_bind, strict=True):
        np.testing.assert_allclose(rest_world[joint] @ matrix, np.eye(4), atol=1e-6)
    names = [n.name for n in gltf.nodes]
    head, hips = rest_world[names.index("Head"), :3, 3], rest_world[names.index("Hips"), :3, 3]
    assert head[1] - hips[1] > 0.5  # Y up
    assert rest_world[names.index("LeftArm"), 0, 3] > 0.1 > -0.1 > rest_world[names.index("RightArm"), 0, 3]
    toe = rest_world[names.index("LeftToeBase"), :3, 3] - rest_world[names.index("LeftFoot"), :3, 3]
    assert toe[2] > 0.05  # facing +Z


def test_skinned_mannequin_follows_the_feet_to_the_floor(exported):
    """Skin the mesh at every frame: its lowest point follows the lowest foot point of the result (the soles
    carry the mannequin's feet) and the mesh moves with the root."""
    result, _, gltf = exported
    world = node_world_matrices(gltf)
    inverse_bind = read_accessor(gltf, gltf.skins[0].inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
    skinning = world[:, gltf.skins[0].joints] @ inverse_bind  # (T, N, 4, 4)
    lowest, centre = [], []
    for primitive in gltf.meshes[0].primitives:
        positions = read_accessor(gltf, primitive.attributes.POSITION)
        joints = read_accessor(gltf, primitive.attributes.JOINTS_0).astype(int)
        weights = read_accessor(gltf, primitive.attributes.WEIGHTS_0)
        np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-6)
        homogeneous = np.append(positions, np.ones((len(positions), 1)), axis=1)
        skinned = np.einsum("vk,tvkij,vj->tvi", weights, skinning[:, joints], homogeneous)[..., :3]
        lowest.append(skinned[..., 1].min(axis=1))
        centre.append(skinned.mean(axis=1))
        accessor = gltf.accessors[primitive.attributes.POSITION]
        np.testing.assert_allclose(accessor.min, positions.min(axis=0), atol=1e-6)
    points = list(result["joint_names"])
    soles = result["joints_world"][:, [points.index(n) for n in ("left_heel", "left_toe", "right_heel",
                                                                 "right_toe")], 2]
    assert np.abs(np.min(lowest, axis=0) - soles.min(axis=1)).max() < 0.02
    travelled = np.mean(centre, axis=0)[-1] - np.mean(centre, axis=0)[0]
    root = result["qpos"][-1, 0:3] - result["qpos"][0, 0:3]
    assert travelled[2] == pytest.approx(root[0], abs=0.05)  # world x is glTF Z


def test_root_at_origin_starts_above_the_origin(tmp_path):
    result = synthetic_result(frames=5)
    path = tmp_path / "origin.glb"
    write_glb(path, body_from_result(result), result["qpos"], 30.0, root_at_origin=True)
    world = node_world_matrices(pygltflib.GLTF2().load(str(path)))
    hips = world[:, 0, :3, 3]
    assert hips[0, 0] == pytest.approx(0.0, abs=1e-6) and hips[0, 2] == pytest.approx(0.0, abs=1e-6)
    assert hips[0, 1] == pytest.approx(result["qpos"][0, 2], abs=1e-6)


def test_rejects_bad_input_and_holds_non_finite_frames(tmp_path, caplog):
    result = synthetic_result(frames=3)
    body = body_from_result(result)
    with pytest.raises(ValueError, match="fps"):
        write_glb(tmp_path / "fps.glb", body, result["qpos"], 0.0)
    assert not list(tmp_path.iterdir())
    qpos = result["qpos"].copy()
    qpos[1, 5] = np.nan
    write_glb(tmp_path / "nan.glb", body, qpos, 30.0)
    assert "frames 1 hold non-finite values" in caplog.text and "nan.glb" in caplog.text
    held = qpos.copy()
    held[1] = held[0]
    write_glb(tmp_path / "held.glb", body, held, 30.0)
    assert (tmp_path / "nan.glb").read_bytes() == (tmp_path / "held.glb").read_bytes()


# The Khronos glTF-Validator (npm package gltf-validator), found by node's own module resolution: installed
# globally, or with NODE_PATH naming the node_modules folder it was installed into (README, "Checking a GLB").
VALIDATE_JS = """
const validator = require("gltf-validator");
const fs = require("fs");
Promise.all(process.argv.slice(1).map((path) => validator.validateBytes(new Uint8Array(fs.readFileSync(path)))))
    .then((reports) => console.log(JSON.stringify(reports.map((report) => report.issues))));
"""


def khronos_issues(*paths: Path) -> list[dict]:
    """The validator's `issues` of each file (numErrors, numWarnings, numInfos, numHints, messages); skips the
    calling test when node or the package is not found."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node is not installed: the Khronos glTF validator runs on it")
    found = subprocess.run([node, "-e", 'require.resolve("gltf-validator")'], capture_output=True, timeout=60)
    if found.returncode != 0:
        pytest.skip("the Khronos glTF validator is not installed (npm install --prefix DIR gltf-validator, then "
                    "NODE_PATH=DIR/node_modules; README, 'Checking a GLB')")
    output = subprocess.run([node, "-e", VALIDATE_JS, *map(str, paths)], capture_output=True, text=True, timeout=120,
                            check=True).stdout
    return json.loads(output)


def issue_counts(issues: dict) -> tuple[int, int, int, int]:
    return issues["numErrors"], issues["numWarnings"], issues["numInfos"], issues["numHints"]


def test_khronos_validator_finds_no_issue(exported, tmp_path):
    """Our GLB, with and without the root at the origin, and with frames held over non-finite values: no error,
    warning, info or hint."""
    _, path, _ = exported
    result = synthetic_result(frames=20)
    body = body_from_result(result)
    write_glb(tmp_path / "origin.glb", body, result["qpos"], 30.0, root_at_origin=True)
    held = result["qpos"].copy()
    held[3] = np.nan
    write_glb(tmp_path / "held.glb", body, held, 30.0)
    for file, issues in zip((path, tmp_path / "origin.glb", tmp_path / "held.glb"),
                            khronos_issues(path, tmp_path / "origin.glb", tmp_path / "held.glb"), strict=True):
        assert issue_counts(issues) == (0, 0, 0, 0), (file.name, issues["messages"])
