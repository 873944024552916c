"""BVH export, read back with an independent parser (the `bvh` package) and our own BVH forward kinematics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from bvh import Bvh
from scipy.spatial.transform import Rotation

from physmocap.body.kinematics import forward_kinematics, integrate
from physmocap.body.model import build_body_model, template_lengths
from physmocap.io.bvh_export import write_bvh

# BVH (X, Y, Z) = world (y, z, x): a BVH vector v is the world vector (v[2], v[0], v[1]).
BVH_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# BVH joint -> body model point at the joint's centre.
JOINT_POINTS = {
    "Hips": "pelvis", "Spine": "spine", "Neck": "neck", "Head": "head",
    "LeftArm": "left_shoulder", "LeftForeArm": "left_elbow", "LeftHand": "left_wrist",
    "RightArm": "right_shoulder", "RightForeArm": "right_elbow", "RightHand": "right_wrist",
    "LeftUpLeg": "left_hip", "LeftLeg": "left_knee", "LeftFoot": "left_ankle", "LeftToeBase": "left_toe",
    "RightUpLeg": "right_hip", "RightLeg": "right_knee", "RightFoot": "right_ankle", "RightToeBase": "right_toe",
}


def elementary_rotation(axis: str, degrees: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations about the BVH axis "X", "Y" or "Z"."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    rows = {
        "X": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "Y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "Z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis]
    return np.moveaxis(np.array(rows), 2, 0)


def bvh_world_positions(path: Path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], Bvh]:
    """Joint and End Site world positions (T, 3) in BVH axes and file units, from the parsed file.

    Channels apply in the order listed (R = R_first @ R_second @ ...); position channels add to the OFFSET.
    End Sites are keyed by their parent joint's name."""
    mocap = Bvh(path.read_text())
    T = mocap.nframes
    rotation: dict[str, np.ndarray] = {}
    position: dict[str, np.ndarray] = {}
    end_sites: dict[str, np.ndarray] = {}
    for joint in mocap.get_joints():  # parents come before their children
        name = joint.name
        channels = mocap.joint_channels(name)
        values = np.array(mocap.frames_joint_channels(name, channels)).reshape(T, len(channels))
        local_position = np.tile(np.array(mocap.joint_offset(name)), (T, 1))
        local_rotation = np.tile(np.eye(3), (T, 1, 1))
        for k, channel in enumerate(channels):
            if channel.endswith("position"):
                local_position[:, "XYZ".index(channel[0])] += values[:, k]
            else:
                local_rotation = local_rotation @ elementary_rotation(channel[0], values[:, k])
        parent_index = mocap.joint_parent_index(name)
        if parent_index < 0:
            position[name], rotation[name] = local_position, local_rotation
        else:
            parent = mocap.get_joints()[parent_index].name
            position[name] = position[parent] + np.einsum("tij,tj->ti", rotation[parent], local_position)
            rotation[name] = rotation[parent] @ local_rotation
        for end in joint.filter("End"):
            offset = np.array([float(v) for v in end["OFFSET"]])
            end_sites[name] = position[name] + rotation[name] @ offset
    return position, end_sites, mocap


@pytest.fixture(scope="module")
def body():
    return build_body_model(template_lengths(1.7), 70)


def random_motion(body, frames: int, seed: int) -> np.ndarray:
    """(frames, nq) poses: random rotations of every joint (about 0.8 rad) and a wandering root."""
    rng = np.random.default_rng(seed)
    dv = rng.normal(scale=0.8, size=(frames, body.nv))
    dv[:, 0:3] = rng.normal(scale=0.5, size=(frames, 3))
    return integrate(body, np.tile(body.rest_qpos, (frames, 1)), dv)


def test_joint_positions_match_forward_kinematics(body, tmp_path):
    qpos = random_motion(body, 10, seed=1)
    path = tmp_path / "motion.bvh"
    write_bvh(path, body, qpos, fps=30.0)

    positions, end_sites, mocap = bvh_world_positions(path)
    pose = forward_kinematics(body, qpos)
    assert mocap.nframes == 10
    assert mocap.frame_time == pytest.approx(1 / 30, abs=1e-8)
    assert set(positions) == set(JOINT_POINTS)
    for joint, point in JOINT_POINTS.items():
        expected = pose.points[:, body.point_index([point])[0]]
        np.testing.assert_allclose(positions[joint] @ BVH_TO_WORLD.T, expected, atol=1e-4, err_msg=joint)

    def point(name: str) -> np.ndarray:
        return pose.points[:, body.point_index([name])[0]]

    for side in ("Left", "Right"):
        knuckles = (point(f"{side.lower()}_index") + point(f"{side.lower()}_pinky")) / 2
        np.testing.assert_allclose(end_sites[f"{side}Hand"] @ BVH_TO_WORLD.T, knuckles, atol=1e-4)
    head_axis = pose.rotations[:, body.body_index["head"], :, 2]  # the head's up axis in the world
    vertex = point("head") + body.lengths.head_top * head_axis
    np.testing.assert_allclose(end_sites["Head"] @ BVH_TO_WORLD.T, vertex, atol=1e-4)


def test_rest_pose_is_upright_facing_plus_z(body, tmp_path):
    path = tmp_path / "rest.bvh"
    write_bvh(path, body, body.rest_qpos[None], fps=25.0)
    positions, _, mocap = bvh_world_positions(path)

    pelvis_height = forward_kinematics(body, body.rest_qpos).points[0, body.point_index(["pelvis"])[0], 2]
    assert mocap.frame_joint_channel(0, "Hips", "Yposition") == pytest.approx(pelvis_height, abs=1e-6)
    assert np.allclose([float(v) for v in mocap.frames[0][3:]], 0.0)  # the rest pose has no rotation
    hips, head = positions["Hips"][0], positions["Head"][0]
    assert head[1] - hips[1] > 0.5  # Y up
    assert positions["LeftArm"][0, 0] > 0.1 > -0.1 > positions["RightArm"][0, 0]  # left at +X
    toe_forward = positions["LeftToeBase"][0] - positions["LeftFoot"][0]
    assert toe_forward[2] > 0.05 and abs(toe_forward[0]) < 1e-6  # facing +Z


def test_centimetres_scale_by_100(body, tmp_path):
    qpos = random_motion(body, 4, seed=2)
    write_bvh(tmp_path / "m.bvh", body, qpos, fps=30.0, units="m")
    write_bvh(tmp_path / "cm.bvh", body, qpos, fps=30.0, units="cm")
    metres, _, m_file = bvh_world_positions(tmp_path / "m.bvh")
    centimetres, _, cm_file = bvh_world_positions(tmp_path / "cm.bvh")
    for joint in JOINT_POINTS:
        np.testing.assert_allclose(centimetres[joint], 100 * metres[joint], atol=1e-3)
    assert np.allclose(cm_file.joint_offset("LeftLeg"), 100 * np.array(m_file.joint_offset("LeftLeg")))


def test_root_at_origin_starts_at_the_origin(body, tmp_path):
    qpos = random_motion(body, 5, seed=3)
    qpos[:, 0:2] += [3.0, -2.0]
    path = tmp_path / "origin.bvh"
    write_bvh(path, body, qpos, fps=30.0, root_at_origin=True)
    mocap = Bvh(path.read_text())
    root = np.array(mocap.frames_joint_channels("Hips", ["Xposition", "Yposition", "Zposition"]))
    assert root[0, 0] == pytest.approx(0.0, abs=1e-9) and root[0, 2] == pytest.approx(0.0, abs=1e-9)
    assert root[0, 1] == pytest.approx(qpos[0, 2], abs=1e-6)  # the height is kept
    # Later frames move by the world displacement: world x -> BVH Z, world y -> BVH X.
    np.testing.assert_allclose(root[:, 2], qpos[:, 0] - qpos[0, 0], atol=1e-6)
    np.testing.assert_allclose(root[:, 0], qpos[:, 1] - qpos[0, 1], atol=1e-6)


def test_channels_are_continuous_through_turns_and_gimbal_lock(body, tmp_path):
    """Two full turns about the vertical, then a forward pitch through 90 degrees: no jumps in any channel."""
    turn = np.concatenate([np.arange(0.0, 720.0, 7.0), np.full(25, 720.0)])
    pitch = np.concatenate([np.zeros(len(turn) - 25), np.arange(0.0, 175.0, 7.0)])
    # Intrinsic: turn about the vertical, then pitch forward about the turned pelvis's y axis.
    xyzw = Rotation.from_euler("ZY", np.stack([turn, pitch], axis=1), degrees=True).as_quat()
    qpos = np.tile(body.rest_qpos, (len(turn), 1))
    qpos[:, 3:7] = np.roll(xyzw, 1, axis=1)  # MuJoCo's w, x, y, z
    path = tmp_path / "turns.bvh"
    write_bvh(path, body, qpos, fps=30.0)

    mocap = Bvh(path.read_text())
    channels = np.array([[float(v) for v in frame] for frame in mocap.frames])
    assert np.abs(np.diff(channels[:, 3:], axis=0)).max() < 10.0
    positions, _, _ = bvh_world_positions(path)
    pose = forward_kinematics(body, qpos)
    np.testing.assert_allclose(positions["Head"] @ BVH_TO_WORLD.T, pose.points[:, body.point_index(["head"])[0]],
                               atol=1e-4)
