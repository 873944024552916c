"""Retargeting onto the user's own character (issue 19): bone mapping by name for the common rig conventions and by
TOML, the character's body model and mass distribution, the motion on the character with physics, and its BVH and
GLB files read back by independent readers (the `bvh` package and pygltflib)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from bvh import Bvh
from scipy.spatial.transform import Rotation

from physmocap.body import kinematics as kin
from physmocap.body.model import CONTACT_POINTS, JOINT_NAMES, SkeletonLengths, build_body_model, template_lengths
from physmocap.body.rotations import quat_exp
from physmocap.contacts.flights import flight_support
from physmocap.errors import InputError
from physmocap.export import body_from_result
from physmocap.io.bvh_export import write_bvh
from physmocap.io.glb import write_glb
from physmocap.mocap.bvh_reader import forward_kinematics, read_bvh
from physmocap.result import RESULT_POINTS, load_result, save_result
from physmocap.retarget import retarget_result
from physmocap.retarget.character import build_character
from physmocap.retarget.mapping import load_character_config, map_bones, normalise
from physmocap.retarget.rig import read_accessor, read_rig
from physmocap.retarget.solve import flights_at_full_gravity, follow_planted_feet, retarget_qpos, solve_feet
from test_export import synthetic_result
from test_glb import glb_json, glb_with_json, issue_counts, khronos_issues

DATA = Path(__file__).parent / "data"
DAZ_RIG = DATA / "rig_daz_cgspeed.bvh"  # hierarchy of ../shared/data/mocap/cmu_daz_cgspeed (no motion)
CC3_RIG = DATA / "rig_cc3_iclone.bvh"  # hierarchy and T-pose frame of cmu_iclone_cc3_retarget/007_03

CARTOON = dict(hip_width=0.16, thigh=0.22, shank=0.20, ankle_height=0.05, heel_back=0.03, toe_front=0.12,
               spine_low=0.06, spine_up=0.30, shoulder_width=0.30, upper_arm=0.33, forearm=0.31, hand_length=0.09,
               hand_width=0.04, head_height=0.20, head_top=0.22, ear_width=0.16, nose_forward=0.14, nose_down=-0.02,
               eye_forward=0.11, eye_up=0.06, eye_width=0.04)


DEMO_CLIP = Path(__file__).resolve().parents[1] / "src" / "physmocap" / "data" / "demo" / "taiji_demo.mp4"

def stepping_result(frames: int = 60, fps: float = 30.0) -> dict[str, np.ndarray]:
    """The synthetic result of test_export with another motion: swaying side to side, crouching, lifting one foot
    and then the other (their heel and toe out of contact meanwhile), arms swinging; its feet planted by our own
    IK, as a capture's foot-lock leaves them."""
    result = synthetic_result(frames, fps)
    body = build_body_model(template_lengths(1.72), 68.0)
    time = np.arange(frames) / fps
    qpos = np.tile(body.rest_qpos, (frames, 1))
    qpos[:, 0] += 0.04 * np.sin(np.pi * time)
    qpos[:, 1] += 0.06 * np.sin(2 * np.pi * time / 2)
    qpos[:, 2] -= 0.04 * (1 - np.cos(2 * np.pi * time)) / 2
    contacts = np.ones((frames, 4), bool)
    for side, sign, start in (("left", 1.0, frames // 3), ("right", -1.0, 2 * frames // 3)):
        lift = np.zeros(frames)
        lift[start:start + frames // 5] = np.sin(np.linspace(0, np.pi, frames // 5))
        hip = body.qpos_address[body.joint_index[f"{side}_hip"]]
        knee = body.qpos_address[body.joint_index[f"{side}_knee"]]
        shoulder = body.qpos_address[body.joint_index[f"{side}_shoulder"]]
        qpos[:, hip:hip + 4] = np.stack([np.cos(-0.4 * lift), 0 * lift, np.sin(-0.4 * lift), 0 * lift], axis=1)
        qpos[:, knee] = 0.1 + 0.9 * lift
        swing = 0.6 + 0.2 * np.sin(2 * np.pi * time)
        qpos[:, shoulder:shoulder + 4] = np.stack([np.cos(swing), -sign * np.sin(swing), 0 * swing, 0 * swing], 1)
        contacts[lift > 0.05, 2 * (side == "right"):2 * (side == "right") + 2] = False
    qpos, _ = solve_feet(body, qpos, contacts, fps)
    points = kin.forward_kinematics(body, qpos).points[:, body.point_index(RESULT_POINTS)]
    result.update(qpos=qpos, qpos_kinematic=qpos, joints_world=points, joints_world_kinematic=points,
                  contacts=contacts, contacts_predicted=contacts)
    return result


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("source") / "result.npz"
    save_result(path, stepping_result())
    return path


def mixamo_rig(path: Path, lengths: SkeletonLengths | None = None, prefix: str = "") -> Path:
    """A Mixamo-named rig in centimetres: our own motion.bvh export of a body at rest (optionally 'mixamorig:')."""
    body = build_body_model(lengths or template_lengths(1.62), 60.0)
    write_bvh(path, body, body.rest_qpos[None], 30.0, units="cm")
    if prefix:
        text = path.read_text()
        for word in ("ROOT ", "JOINT "):
            text = text.replace(word, word + prefix)
        path.write_text(text)
    return path


# ---- mapping ----------------------------------------------------------------------------------------------------

CONVENTIONS = {  # convention -> role -> bone name (left side; right side by the convention's own rule)
    "mixamo": ("mixamorig:Hips", "mixamorig:Spine", "mixamorig:Neck", "mixamorig:Head", "mixamorig:LeftUpLeg",
               "mixamorig:LeftLeg", "mixamorig:LeftFoot", "mixamorig:LeftToeBase", "mixamorig:LeftShoulder",
               "mixamorig:LeftArm", "mixamorig:LeftForeArm", "mixamorig:LeftHand"),
    "cmu": ("Hips", "LowerBack", "Neck", "Head", "LeftUpLeg", "LeftLeg", "LeftFoot", "LeftToeBase", "LeftShoulder",
            "LeftArm", "LeftForeArm", "LeftHand"),
    "daz": ("hip", "abdomen", "neck", "head", "lThigh", "lShin", "lFoot", "lToe", "lCollar", "lShldr", "lForeArm",
            "lHand"),
    "cc3": ("CC_Base_Pelvis", "CC_Base_Waist", "CC_Base_NeckTwist01", "CC_Base_Head", "CC_Base_L_Thigh",
            "CC_Base_L_Calf", "CC_Base_L_Foot", "CC_Base_L_ToeBase", "CC_Base_L_Clavicle", "CC_Base_L_Upperarm",
            "CC_Base_L_Forearm", "CC_Base_L_Hand"),
    "rigify": ("DEF-spine", "DEF-spine.001", "DEF-spine.004", "DEF-spine.006", "DEF-thigh.L", "DEF-shin.L",
               "DEF-foot.L", "DEF-toe.L", "DEF-shoulder.L", "DEF-upper_arm.L", "DEF-forearm.L", "DEF-hand.L"),
    "unreal": ("pelvis", "spine_01", "neck_01", "head", "thigh_l", "calf_l", "foot_l", "ball_l", "clavicle_l",
               "upperarm_l", "lowerarm_l", "hand_l"),
    "vroid": ("J_Bip_C_Hips", "J_Bip_C_Spine", "J_Bip_C_Neck", "J_Bip_C_Head", "J_Bip_L_UpperLeg",
              "J_Bip_L_LowerLeg", "J_Bip_L_Foot", "J_Bip_L_ToeBase", "J_Bip_L_Shoulder", "J_Bip_L_UpperArm",
              "J_Bip_L_LowerArm", "J_Bip_L_Hand"),
    "vrm": ("hips", "spine", "neck", "head", "leftUpperLeg", "leftLowerLeg", "leftFoot", "leftToes",
            "leftShoulder", "leftUpperArm", "leftLowerArm", "leftHand"),
}
RIGHT = {"mixamo": ("Left", "Right"), "cmu": ("Left", "Right"), "daz": ("l", "r"), "cc3": ("_L_", "_R_"),
         "rigify": (".L", ".R"), "unreal": ("_l", "_r"), "vroid": ("_L_", "_R_"), "vrm": ("left", "right")}


def convention_rig(path: Path, convention: str) -> Path:
    """A T-posed BVH (centimetres, Y up, facing +Z) named after a convention, with an extra chest bone and a
    finger so that the trunk and hands have the usual depth."""
    hips, spine, neck, head, thigh, shin, foot, toe, clavicle, arm, forearm, hand = CONVENTIONS[convention]
    a, b = RIGHT[convention]
    right = (lambda n: b + n[len(a):]) if convention in ("daz", "vrm") else (lambda n: n.replace(a, b))

    def joint(name, offset, children=(), depth=1, kind="JOINT"):
        pad = "  " * depth
        inner = "".join(children) or f"{pad}  End Site\n{pad}  {{\n{pad}    OFFSET 0 0 5\n{pad}  }}\n"
        return (f"{pad}{kind} {name}\n{pad}{{\n{pad}  OFFSET {offset[0]} {offset[1]} {offset[2]}\n"
                f"{pad}  CHANNELS 3 Zrotation Xrotation Yrotation\n{inner}{pad}}}\n")

    def leg(s, name):
        return joint(name(thigh), (s * 9, -3, 0), [joint(name(shin), (0, -42, 0), [joint(name(foot), (0, -42, 0), [
            joint(name(toe), (0, -6, 12), depth=5)], 4)], 3)], 2)

    def arm_chain(s, name):
        return joint(name(clavicle), (s * 3, 8, 0), [joint(name(arm), (s * 14, 0, 0), [joint(name(forearm), (
            s * 28, 0, 0), [joint(name(hand), (s * 25, 0, 0), [joint(name(hand) + "Mid1", (s * 9, 0, 0), depth=7)],
                               6)], 5)], 4)], 3)

    same = lambda n: n  # noqa: E731
    chest = joint("Chest_extra", (0, 20, 0), [arm_chain(1, same), arm_chain(-1, right),
                                                 joint(neck, (0, 12, 0), [joint(head, (0, 10, 0), depth=4)], 3)], 2)
    text = ("HIERARCHY\n" + joint(hips, (0, 95, 0), [leg(1, same), leg(-1, right), joint(spine, (0, 10, 0), [chest])],
                                  0, "ROOT").replace("CHANNELS 3 Zrotation", "CHANNELS 6 Xposition Yposition "
                                                     "Zposition Zrotation", 1))
    count = text.count("CHANNELS 3") * 3 + 6
    path.write_text(text + f"MOTION\nFrames: 1\nFrame Time: 0.0333333\n{' '.join(['0'] * count)}\n")
    return path


@pytest.mark.parametrize("convention", sorted(CONVENTIONS))
def test_bones_are_mapped_by_name_for_each_convention(tmp_path, convention):
    rig = read_rig(convention_rig(tmp_path / f"{convention}.bvh", convention))
    bones = {role: rig.names[j] for role, j in map_bones(rig).items()}
    hips, spine, neck, head, thigh, shin, foot, toe, _, arm, forearm, hand = CONVENTIONS[convention]
    expected = dict(pelvis=hips, spine=spine, neck=neck, head=head, left_hip=thigh, left_knee=shin, left_ankle=foot,
                    left_toe=toe, left_shoulder=arm, left_elbow=forearm, left_wrist=hand)
    assert {k: bones[k] for k in expected} == expected
    assert bones["right_hip"] != bones["left_hip"] and normalise(bones["right_shoulder"]) != normalise(arm)
    character = build_character(rig)
    assert character.units_to_metres == 0.01
    assert 1.4 < character.body.height < 2.0  # the rig stands about 1.5 m tall to its head joint


def test_unmapped_bones_are_listed_in_one_sentence_and_a_toml_map_fixes_them(tmp_path):
    path = convention_rig(tmp_path / "odd.bvh", "mixamo")
    path.write_text(path.read_text().replace("mixamorig:LeftLeg", "Knee_Of_Left").replace("mixamorig:RightLeg",
                                                                                           "Knee_Of_Right"))
    rig = read_rig(path)
    with pytest.raises(InputError) as error:
        map_bones(rig)
    message = str(error.value)
    assert "left_knee, right_knee" in message and "--character-map" in message and "\n" not in message
    toml = tmp_path / "map.toml"
    toml.write_text('[bones]\nleft_knee = "Knee_Of_Left"\nright_knee = "Knee_Of_Right"\n')
    bones = map_bones(rig, load_character_config(toml))
    assert rig.names[bones["left_knee"]] == "Knee_Of_Left"


@pytest.mark.parametrize("text, words", [
    ('[bones]\nleft_elbowz = "X"\n', "left_elbowz"),
    ('[mass]\ntotal = -3\n', "mass.total"),
    ('[mass.fractions]\nhead = 0.7\narms = 0.5\n', "mass.fractions"),
    ('[mass.fractions]\nbelly = 0.2\n', "belly"),
    ('units_to_metres = "cm"\n', "units_to_metres"),
    ('units_to_metres = inf\n', "units_to_metres"),
    ('units_to_metres = true\n', "units_to_metres"),
    ('[mass]\ntotal = true\n', "mass.total"),
    ('bones = 3\n', "bones must be a table"),
    ('mass = 70\n', "mass must be a table"),
    ('[mass]\nfractions = 0.3\n', "mass.fractions must be a table"),
    ('[mass.fractions]\nhead = 1e-320\n', "mass.fractions"),
    ('[mass.fractions]\nhead = 0.9999999\n', "mass.fractions"),
    ('[bones]\nhead = 5\n', "bone's name in quotes"),
    ('[bones\n', "not a valid TOML"),
])
def test_bad_character_maps_fail_with_one_sentence(tmp_path, text, words):
    path = tmp_path / "map.toml"
    path.write_text(text)
    with pytest.raises(InputError, match=words.replace(".", r"\.").replace("[", r"\[")):
        load_character_config(path)


def test_a_map_naming_one_bone_for_two_roles_is_an_input_error(tmp_path):
    """On Character Creator's rig, whose pelvis is a branch of its own, before the trunk is sought."""
    rig = read_rig(Path(__file__).parent / "data" / "rig_cc3_iclone.bvh")
    toml = tmp_path / "map.toml"
    toml.write_text('[bones]\nleft_hip = "CC_Base_Pelvis"\nright_shoulder = "CC_Base_Pelvis"\n')
    with pytest.raises(InputError, match="matches both"):
        map_bones(rig, load_character_config(toml))


def test_a_map_naming_a_missing_bone_is_an_input_error(tmp_path):
    rig = read_rig(mixamo_rig(tmp_path / "m.bvh"))
    toml = tmp_path / "map.toml"
    toml.write_text('[bones]\nhead = "Skull"\n')
    with pytest.raises(InputError, match="Skull"):
        map_bones(rig, load_character_config(toml))


def test_unreadable_characters_fail_cleanly(tmp_path):
    (tmp_path / "x.fbx").write_text("binary")
    with pytest.raises(InputError, match="must be a"):
        read_rig(tmp_path / "x.fbx")
    (tmp_path / "x.glb").write_bytes(b"not a glb at all")
    with pytest.raises(InputError, match="x.glb"):
        read_rig(tmp_path / "x.glb")
    lying = convention_rig(tmp_path / "lying.bvh", "cmu")  # legs pointing up in the zero pose, no frame to use
    text = lying.read_text().replace("OFFSET 0 -42 0", "OFFSET 0 42 0")
    lying.write_text(text.split("MOTION")[0] + "MOTION\nFrames: 0\nFrame Time: 0.03\n")
    with pytest.raises(InputError, match="does not stand"):
        build_character(read_rig(lying))


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace("OFFSET 0 -42 0", "OFFSET 0 nan 0", 1), "OFFSET of .* is not finite"),
    (lambda t: t.replace("JOINT RightShoulder", "JOINT LeftShoulder", 1), "two joints are named LeftShoulder"),
    (lambda t: t.rstrip()[:-1] + "inf\n", "not a finite number"),
    (lambda t: t.replace("Frame Time: 0.0333333", "Frame Time: 1e400"), "Frame Time is inf"),
    (lambda t: t.replace("OFFSET 0 -6 12", "OFFSET 0 -1e7 12", 1), "stands .* tall"),
    (lambda t: t.replace("OFFSET 9 0 0", "OFFSET 1e30 0 0", 1), "hand_length measures"),
])
def test_characters_with_numbers_out_of_range_fail_in_one_sentence(tmp_path, edit, words):
    """Numbers another program may write (NaN, infinity, an overflowing or absurd length) stop at the reader or at
    the character's proportions, before the body model sees an infinite mass."""
    path = convention_rig(tmp_path / "c.bvh", "cmu")
    text = path.read_text()
    path.write_text(edit(text))
    assert path.read_text() != text
    with pytest.raises(InputError, match=words):
        build_character(read_rig(path))


def _glb_edited(path: Path, edit) -> Path:
    """A skinned GLB of the template body whose JSON chunk `edit` changes in place, written back byte for byte
    otherwise (pygltflib would refuse to save some of these documents)."""
    body = build_body_model(template_lengths(1.7), 70.0)
    write_glb(path, body, body.rest_qpos[None], 30.0)
    document, rest = glb_json(path.read_bytes())
    edit(document)
    path.write_bytes(glb_with_json(document, rest))
    return path


def _first_child(document: dict) -> tuple[int, int]:
    parent = next(i for i, n in enumerate(document["nodes"]) if n.get("children"))
    return parent, document["nodes"][parent]["children"][0]


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["nodes"][_first_child(d)[1]].setdefault("children", []).append(_first_child(d)[0]), "cycle"),
    (lambda d: d["nodes"][0].setdefault("children", []).append(_first_child(d)[1]), "two parents"),
    (lambda d: d["bufferViews"][0].update(byteLength=10**9), "buffer view 0 does not lie inside"),
    (lambda d: d["buffers"][0].update(byteLength=10**9), "bytes it declares"),
    (lambda d: d["buffers"].append(dict(d["buffers"][0])), "holds 2 buffers"),
    (lambda d: d["accessors"][0].update(bufferView=999), "accessor 0 names buffer view 999"),
    (lambda d: d["accessors"][0].update(count=1e308), "accessor 0 has a count"),
    (lambda d: d["nodes"][d["skins"][0]["joints"][1]].update(translation=[0.0, float("nan"), 0.0]), "JSON compliant"),
    (lambda d: [d["nodes"][j].update(scale=[1e200] * 3) for j in d["skins"][0]["joints"][:3]], "not finite"),
    (lambda d: d["skins"][0]["joints"].append(d["skins"][0]["joints"][0]), "twice"),
    (lambda d: d["accessors"][d["skins"][0]["inverseBindMatrices"]].update(type="MAT5"), "malformed glTF"),
    (lambda d: d["materials"][0]["pbrMetallicRoughness"].update(metallicFactor=float("nan")), "not JSON compliant"),
])
def test_gltf_characters_that_break_the_format_fail_in_one_sentence(tmp_path, edit, words):
    """Documents another program may write that break glTF's rules: a node hierarchy with a cycle (which would
    loop forever) or two parents, views outside the buffer, indices that do not exist, numbers that are not
    finite. The writer, which copies every view into character.glb, relies on the same checks."""
    path = _glb_edited(tmp_path / "c.glb", edit)
    with pytest.raises(InputError, match=words):
        build_character(read_rig(path))


def test_a_gltf_whose_data_file_is_missing_fails_in_one_sentence(tmp_path):
    glb = _glb_edited(tmp_path / "c.glb", lambda d: None)
    document = pygltflib.GLTF2().load(str(glb))
    document.convert_buffers(pygltflib.BufferFormat.DATAURI)
    document.buffers[0].uri = "c.bin"  # never written
    document.save(str(tmp_path / "c.gltf"))
    with pytest.raises(InputError, match="c.gltf: its buffer holds 0 of the"):
        read_rig(tmp_path / "c.gltf")


# ---- the character's body model ----------------------------------------------------------------------------------

def test_body_model_has_the_rigs_lengths_and_the_mass_distribution_asked_for(tmp_path):
    lengths = SkeletonLengths(**CARTOON)
    rig = read_rig(mixamo_rig(tmp_path / "cartoon.bvh", lengths))
    toml = tmp_path / "cartoon.toml"
    toml.write_text("[mass]\ntotal = 36.5\n[mass.fractions]\nhead = 0.40\n")
    character = build_character(rig, load_character_config(toml))
    body = character.body
    for name in ("thigh", "shank", "upper_arm", "forearm", "hip_width", "shoulder_width", "toe_front"):
        assert getattr(body.lengths, name) == pytest.approx(CARTOON[name], abs=1e-5), name
    assert body.lengths.ankle_height == pytest.approx(CARTOON["ankle_height"], abs=1e-5)
    masses = {b.name: b.mass for b in body.bodies}
    assert sum(masses.values()) == pytest.approx(36.5)
    assert masses["head"] == pytest.approx(0.40 * 36.5)
    human = build_body_model(lengths, 36.5)  # de Leva: the other groups keep their proportions
    human_masses = {b.name: b.mass for b in human.bodies}
    assert (masses["left_thigh"] / masses["pelvis"]
            == pytest.approx(human_masses["left_thigh"] / human_masses["pelvis"]))
    head = body.body_index["head"]
    assert body.bodies[head].inertia == pytest.approx(
        human.bodies[head].inertia * masses["head"] / human_masses["head"])


def test_default_mass_scales_with_the_cube_of_the_height(tmp_path):
    rig = read_rig(mixamo_rig(tmp_path / "m.bvh", template_lengths(1.40)))
    character = build_character(rig, None, default_mass=70.0, default_height=1.75)
    assert character.body.mass == pytest.approx(70.0 * (character.body.height / 1.75) ** 3)


# ---- retargeting -------------------------------------------------------------------------------------------------

def _rigs(tmp_path: Path) -> dict[str, Path]:
    return {"mixamo": mixamo_rig(tmp_path / "mixamo.bvh", template_lengths(1.60), prefix="mixamorig:"),
            "daz": DAZ_RIG, "cc3": CC3_RIG,
            "cartoon": mixamo_rig(tmp_path / "cartoon.bvh", SkeletonLengths(**CARTOON))}


def test_feet_stay_planted_while_the_source_slides_and_the_pose_stays_the_sources():
    """A monocular capture's body drifting 3 cm a frame while both feet are labelled in contact (its depth drifts):
    the character's feet stay on their spots and the whole body stays with them, its pose the source's."""
    body = build_body_model(template_lengths(1.70), 65.0)
    frames = 40
    qpos = np.tile(body.rest_qpos, (frames, 1))
    qpos[:, 0] += 0.03 * np.arange(frames)
    contacts = np.ones((frames, 4), bool)
    solved, spots = solve_feet(body, qpos, contacts, 30.0)
    points = kin.forward_kinematics(body, solved).points
    feet = points[:, body.point_index(CONTACT_POINTS)]
    assert np.abs(np.diff(feet, axis=0)).max() < 1e-3
    assert np.allclose(feet[..., :2], spots[..., :2], atol=1e-3)
    joints = points[:, body.point_index(JOINT_NAMES)]
    source = kin.forward_kinematics(body, qpos).points[:, body.point_index(JOINT_NAMES)]
    assert np.allclose(joints - joints[:, :1], source - source[:, :1], atol=1e-3)


def test_no_foot_is_held_through_frames_without_a_person(tmp_path):
    """The person is lost for half a second while the capture's interpolated body walks 0.9 m and its labels keep
    the feet in contact there: the character walks on with the source instead of staying on the old spots."""
    result = stepping_result()
    body = body_from_result(result)
    qpos = result["qpos"].copy()
    qpos[20:, 0] += np.clip((np.arange(40) + 1) / 15, 0, 1) * 0.9
    valid = np.ones(60, bool)
    valid[20:35] = False
    points = kin.forward_kinematics(body, qpos).points[:, body.point_index(RESULT_POINTS)]
    result.update(qpos=qpos, joints_world=points, valid=valid)
    save_result(tmp_path / "result.npz", result)
    report = retarget_result(tmp_path / "result.npz", mixamo_rig(tmp_path / "rig.bvh"), tmp_path / "out",
                             physics="none")
    assert report.metrics["path_departure_mean_m"] < 0.05, report.metrics


def test_a_foot_held_off_its_reach_stays_out_of_the_floor():
    """Both feet held while the source's right leg swings 1.5 degrees a frame: the held right foot cannot both stay
    on its spot and follow the pose, and whatever the IK gives up, it is not the floor (a wall)."""
    body = build_body_model(template_lengths(1.70), 65.0)
    frames = 30
    qpos = np.tile(body.rest_qpos, (frames, 1))
    hip = kin.tables(body).qadr[body.body_index["right_thigh"]]
    angle = -np.radians(1.5) * np.arange(frames)
    qpos[:, hip:hip + 4] = quat_exp(np.stack([0 * angle, angle, 0 * angle], axis=1))  # about the y axis
    solved, spots = solve_feet(body, qpos, np.ones((frames, 4), bool), 30.0)
    source_feet = kin.forward_kinematics(body, qpos).points[:, body.point_index(CONTACT_POINTS)]
    assert np.nanmax(np.linalg.norm(source_feet - spots, axis=-1)) > 0.1  # the pose pulls the foot off its spot
    feet = kin.forward_kinematics(body, solved).points[:, body.point_index(CONTACT_POINTS)]
    assert feet[..., 2].min() > -0.002


def test_a_source_on_another_level_is_followed_there_not_lifted_onto_the_floor(tmp_path):
    """The capture's person stands on the floor, then on ground 1.3 m below it (stepped off the box the floor was
    found on; the source's physics flags those frames and keeps them kinematic). The character stays with the
    source down there instead of standing on the box's plane, and its feet there are not counted as penetrating
    the floor."""
    from physmocap.retarget.solve import on_another_level
    from physmocap.retarget.stage import follows_gap, retarget_metrics
    from physmocap.retarget.writers import rig_motion, rig_positions

    body = build_body_model(template_lengths(1.70), 65.0)
    frames = 40
    qpos = np.tile(body.rest_qpos, (frames, 1))
    qpos[20:, 2] -= 1.3
    other_level = on_another_level(body, qpos, np.zeros((frames, 4), bool))
    assert not other_level[:20].any() and other_level[20:].all()
    solved, _ = solve_feet(body, qpos, np.zeros((frames, 4), bool), 30.0, other_level)
    assert np.allclose(solved[:, 2], qpos[:, 2], atol=0.01)
    lifted, _ = solve_feet(body, qpos, np.zeros((frames, 4), bool), 30.0)
    assert lifted[20:, 2].min() > qpos[20:, 2].max() + 1.0  # as every frame sunk into the floor is
    character = build_character(read_rig(_rigs(tmp_path)["mixamo"]))
    rig_body = character.body
    rig_qpos = np.tile(rig_body.rest_qpos, (frames, 1))
    rig_qpos[20:, 2] -= 1.3
    points = kin.forward_kinematics(rig_body, rig_qpos).points[:, rig_body.point_index(RESULT_POINTS)]
    m = retarget_metrics(character, points, rig_qpos, rig_positions(character, rig_motion(character, rig_qpos)),
                         np.zeros((frames, 4), bool), 30.0, None, follows_gap(np.ones(frames, bool)),
                         other_level=other_level)
    assert m["penetration_percent"] == 0.0 and m["another_level_frames"] == 20


def test_a_foot_touching_down_heel_after_toe_keeps_its_own_shape():
    """The toe held while the body drifts, then the heel touches down: the heel's spot is placed from the toe's, so
    the two spots lie as far apart as the foot's points do (a foot is rigid), not where the body's offset says."""
    frames = 10
    points = np.zeros((frames, 4, 3))
    points[:, :, 0] = [[-0.05, 0.15, -0.05, 0.15]] * frames  # heel, toe of each foot along x
    points[:, :2, 0] += 0.05 * np.arange(frames)[:, None]  # the left foot slides with the body
    contacts = np.zeros((frames, 4), bool)
    contacts[:, 1] = True  # left toe from the start
    contacts[5:, 0] = True  # left heel from frame 5
    contacts[:, 3] = True  # right toe, not sliding: the body's offset is the mean of both toes
    _, spots = follow_planted_feet(points, contacts, step_adjustment=0.0)
    assert spots[7, 1, 0] - spots[7, 0, 0] == pytest.approx(0.20)


def test_the_offset_a_sliding_contact_leaves_returns_over_the_next_steps():
    """After a contact that slid 0.48 m, each new footstep lands at most step_adjustment nearer the source's own
    footprint, until the body is back on the source's path."""
    points = np.zeros((60, 4, 3))
    points[:25, :, 0] = 0.02 * np.arange(25)[:, None]  # both feet 'held' while they slide 0.48 m with the body
    points[25:, :, 0] = points[24, :, 0]  # then stepping on the spot
    contacts = np.zeros((60, 4), bool)
    contacts[0:25, :] = True
    for start in range(25, 60, 5):  # one foot, then the other, a frame without contact between
        side = slice(0, 2) if (start // 5) % 2 else slice(2, 4)
        contacts[start + 1:start + 5, side] = True
    offsets, _ = follow_planted_feet(points, contacts, step_adjustment=0.1)
    assert np.linalg.norm(offsets[24]) == pytest.approx(0.48)
    distances = np.linalg.norm(offsets[25:], axis=1)
    assert np.all(np.diff(distances) <= 1e-9)  # never away from the source's path
    assert np.all(np.diff(distances) >= -0.1 - 1e-9)  # at most one adjustment a step
    assert distances[-1] < 1e-9


def jump_heights(fps: float = 30.0) -> tuple[np.ndarray, np.ndarray, slice]:
    """Root heights (T,) m of a standing jump at `fps`: 0.9 m, a 0.3 s flight falling at g, 0.9 m; its contacts
    (T, 4) bool, and the flight's frames."""
    t = np.arange(45) / fps
    take_off, flight = 0.5, 0.3
    in_flight = (t > take_off) & (t < take_off + flight)
    heights = 0.9 + np.where(in_flight, 9.81 / 2 * (t - take_off) * (take_off + flight - t), 0.0)
    contacts = np.repeat(~in_flight[:, None], 4, axis=1)
    frames = np.flatnonzero(in_flight)
    return heights, contacts, slice(frames[0], frames[-1] + 1)


def test_a_jump_scaled_to_a_smaller_character_still_falls_at_g():
    """Scaling the root's path by 0.5 would make the flight fall at g / 2; the flight keeps its rise above the
    chord unscaled, so its second differences (the fall) are the source's, and stances are only scaled."""
    fps = 30.0
    heights, contacts, flight = jump_heights(fps)
    valid = np.ones(len(heights), bool)
    scaled = flights_at_full_gravity(heights, contacts, valid, fps, 0.5)
    fall = np.diff(scaled, 2)[flight.start:flight.stop - 2] * fps ** 2
    assert fall == pytest.approx(np.full(len(fall), -9.81), abs=1e-9)
    stance = contacts.any(axis=1)
    assert scaled[stance] == pytest.approx(0.5 * heights[stance])


def test_flights_without_both_ends_or_held_up_are_only_scaled():
    """A flight beside a frame without a person or at the clip's end has no measured extent, and a labelled flight
    whose body does not fall (held up: the labels' error) is no flight: each is scaled like the rest."""
    fps = 30.0
    heights, contacts, flight = jump_heights(fps)
    valid = np.ones(len(heights), bool)
    valid[flight.stop] = False
    assert flights_at_full_gravity(heights, contacts, valid, fps, 0.5) == pytest.approx(0.5 * heights)
    cut = flight.stop - 2
    assert flights_at_full_gravity(heights[:cut], contacts[:cut], valid[:cut], fps, 0.5) == pytest.approx(
        0.5 * heights[:cut])
    held = 0.9 + (heights - 0.9) * 0.2  # an arc at g / 5: a body held up needing 0.8 body weights
    assert flights_at_full_gravity(held, contacts, np.ones(len(held), bool), fps, 0.5) == pytest.approx(0.5 * held)


def test_a_character_half_the_size_needs_no_support_in_the_sources_flight():
    """The whole retargeting of a jump onto a body with half the leg length: the character's centre of mass
    falls through the flight as the source's does (flight_support near 0, not the 0.5 body weights that scaling
    alone leaves, the bar above which physics takes a flight for a labelling error)."""
    fps = 30.0
    heights, contacts, flight = jump_heights(fps)
    source = build_body_model(template_lengths(1.70), 65.0)
    lengths = template_lengths(1.70)
    small = build_body_model(SkeletonLengths(**{**lengths.__dict__, "thigh": lengths.thigh / 2,
                                                "shank": lengths.shank / 2}), 30.0)
    qpos = np.tile(source.rest_qpos, (len(heights), 1))
    qpos[:, 2] = heights
    retargeted = retarget_qpos(small, qpos, source.lengths, contacts, fps)
    com = kin.center_of_mass(small, kin.forward_kinematics(small, retargeted.qpos))
    times = np.arange(len(heights)) / fps
    assert flight_support(com[:, 2], times, flight.start, flight.stop, 9.81) == pytest.approx(0.0, abs=0.05)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["mixamo", "daz", "cc3", "cartoon"])
def test_motion_on_each_rig_meets_the_targets_and_reads_back(tmp_path, source, name):
    rig_path = _rigs(tmp_path)[name]
    report = retarget_result(source, rig_path, tmp_path / "out", physics="physcap")
    m = report.metrics
    assert m["skate_percent"] <= 2.0 and m["penetration_percent"] <= 0.3, m
    assert m["bone_cosine_rig"] >= 0.95 and m["bone_cosine_body"] >= 0.95, m
    assert m["contact_frames_kept"] >= 0.95, m
    assert m["bone_length_error_m"] < 1e-9
    assert 80.0 < m["grf_mean_percent_bw"] < 120.0, m
    assert m["unexplained_frames"] == int(load_result(report.files["result"])["physics_unexplained"][
        load_result(report.files["result"])["valid"]].sum())  # the character's own flags

    # The `bvh` package reads the hierarchy back unchanged: names, parents, offsets.
    original = Bvh(Path(rig_path).read_text())
    written = Bvh(Path(report.files["bvh"]).read_text())
    names = original.get_joints_names()
    assert written.get_joints_names() == names
    for joint in names:
        assert written.joint_offset(joint) == pytest.approx(original.joint_offset(joint), abs=1e-5)
        parent = original.joint_parent(joint)
        assert (written.joint_parent(joint).name if parent else None) == (parent.name if parent else None)
    assert written.nframes == 60
    # Its motion puts the joints where result.npz says (forward kinematics of the written channels).
    result = load_result(report.files["result"])
    character = build_character(read_rig(rig_path))
    positions, _ = forward_kinematics(read_bvh(report.files["bvh"]), character.units_to_metres)
    world = positions @ character.file_to_world.T - character.origin
    assert np.allclose(world, result["rig_joints_world"], atol=2e-4)
    assert result["body_mass"] == pytest.approx(report.character["mass_kg"], abs=1e-3)
    assert set(json.loads(str(result["body_segment_masses"]))) >= {"head", "pelvis"}


@pytest.mark.slow
def test_cartoon_with_a_heavy_head_moves_its_centre_of_mass_differently(tmp_path, source):
    rigs = _rigs(tmp_path)
    toml = tmp_path / "cartoon.toml"
    toml.write_text("[mass]\ntotal = 36.5\n[mass.fractions]\nhead = 0.40\n")
    human = retarget_result(source, rigs["mixamo"], tmp_path / "human", physics="physcap")
    cartoon = retarget_result(source, rigs["cartoon"], tmp_path / "cartoon", character_map=toml, physics="physcap")
    assert 95.0 <= cartoon.metrics["grf_mean_percent_bw"] <= 105.0
    com_human = load_result(human.files["result"])["center_of_mass"]
    com_cartoon = load_result(cartoon.files["result"])["center_of_mass"]
    # Relative to the hip height, the heavy head lifts the cartoon's centre of mass well above the human's.
    hip_human = load_result(human.files["result"])["joints_world"][:, 10, 2].mean()
    hip_cartoon = load_result(cartoon.files["result"])["joints_world"][:, 10, 2].mean()
    assert com_cartoon[:, 2].mean() / hip_cartoon > com_human[:, 2].mean() / hip_human + 0.2


@pytest.mark.slow
def test_glb_character_gets_its_animation_added_and_reads_back(tmp_path, source):
    body = build_body_model(template_lengths(1.58), 55.0)
    character_file = tmp_path / "mannequin.glb"
    write_glb(character_file, body, body.rest_qpos[None], 30.0)  # a mesh of ellipsoids skinned to 18 bones
    report = retarget_result(source, character_file, tmp_path / "out", physics="none")
    assert report.metrics["skate_percent"] <= 2.0 and report.metrics["penetration_percent"] <= 0.3
    before = pygltflib.GLTF2().load(str(character_file))
    after = pygltflib.GLTF2().load(report.files["glb"])
    assert [n.name for n in after.nodes] == [n.name for n in before.nodes]
    assert [n.children for n in after.nodes] == [n.children for n in before.nodes]
    assert after.skins[0].joints == before.skins[0].joints and len(after.meshes) == len(before.meshes)
    assert np.array_equal(read_accessor(after, after.meshes[0].primitives[0].attributes.POSITION),
                          read_accessor(before, before.meshes[0].primitives[0].attributes.POSITION))
    animation = after.animations[-1]
    assert animation.name == "physmocap" and len(after.animations) == len(before.animations) + 1
    # Evaluate frame 30 of the animation: node transforms from its channels, then world positions of the joints.
    frame = 30
    local = {}
    for i, node in enumerate(after.nodes):
        local[i] = [np.array(node.translation or [0, 0, 0], float), np.array(node.rotation or [0, 0, 0, 1], float)]
    for channel in animation.channels:
        values = read_accessor(after, animation.samplers[channel.sampler].output)
        local[channel.target.node][0 if channel.target.path == "translation" else 1] = values[frame]
    parent = {c: i for i, n in enumerate(after.nodes) for c in (n.children or [])}
    world = {}

    def place(i):
        if i not in world:
            t, q = local[i]
            R = Rotation.from_quat(q).as_matrix()
            if i in parent:
                pt, pR = place(parent[i])
                world[i] = (pt + pR @ t, pR @ R)
            else:
                world[i] = (t, R)
        return world[i]

    result = load_result(report.files["result"])
    character = build_character(read_rig(character_file))
    for k, node in enumerate(character.rig.nodes):
        position = place(node)[0] @ character.file_to_world.T - character.origin
        assert np.allclose(position, result["rig_joints_world"][frame, k], atol=1e-4), after.nodes[node].name


@pytest.mark.slow
def test_retarget_command_line(tmp_path, source):
    rig = mixamo_rig(tmp_path / "m.bvh")
    run = subprocess.run([sys.executable, "-m", "physmocap.cli", "retarget", str(source), "--character", str(rig),
                          "-o", str(tmp_path / "c"), "--physics", "none"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "foot skate" in run.stdout
    assert {p.name for p in (tmp_path / "c").iterdir()} == {"character.bvh", "result.npz", "retarget.json"}
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT A\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n}\nMOTION\n"
                   "Frames: 1\nFrame Time: 0.1\n0 0 0\n")
    for args in (["retarget", str(source), "--character", str(bad)],
                 ["capture", str(DEMO_CLIP), "-o", str(tmp_path / "cap"), "--character", str(bad)]):
        run = subprocess.run([sys.executable, "-m", "physmocap.cli", *args], capture_output=True, text=True,
                             timeout=300)
        assert run.returncode == 2 and "Traceback" not in run.stderr
        assert "bad.bvh" in run.stderr and "no bone found for left_hip" in run.stderr


@pytest.mark.slow
def test_trajectory_optimisation_runs_on_the_characters_body(tmp_path, source):
    toml = tmp_path / "cartoon.toml"
    toml.write_text("[mass]\ntotal = 36.5\n[mass.fractions]\nhead = 0.40\n")
    report = retarget_result(source, _rigs(tmp_path)["cartoon"], tmp_path / "t", character_map=toml,
                             physics="trajopt")
    result = load_result(report.files["result"])
    assert str(result["physics"]) == "trajopt" and not result["physics_fallback"].any(), report.notes
    assert 95.0 <= report.metrics["grf_mean_percent_bw"] <= 105.0
    assert report.metrics["skate_percent"] <= 2.0 and report.metrics["contact_frames_kept"] >= 0.95
    assert result["body_mass"] == pytest.approx(36.5)


def _node_matrix(translation, rotation, scale) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(rotation).as_matrix() * np.asarray(scale, float)
    m[:3, 3] = translation
    return m


def blender_like_glb(folder: Path) -> tuple[Path, Path]:
    """Our mannequin (plain.glb) as Blender exports a character (blender_like.glb): the skeleton under a rotated,
    scaled Armature node, bones with rest rotations, no animation (the accessors of the removed one left behind).
    """
    body = build_body_model(template_lengths(1.58), 55.0)
    plain = folder / "plain.glb"
    write_glb(plain, body, body.rest_qpos[None], 30.0)
    gltf = pygltflib.GLTF2().load(str(plain))
    skin = gltf.skins[0]
    # Armature: a quarter turn about Y and half scale; every bone a rest rotation of its own. The joints keep their
    # places in the file's world: local transforms are recomputed from the chosen world rotations.
    places = read_rig(plain).rest_world()[:, :3, 3]
    order = list(read_rig(plain).nodes)
    turn = Rotation.from_euler("y", 90, degrees=True)
    rng = np.random.default_rng(3)
    frames = {node: Rotation.from_rotvec(rng.normal(scale=0.6, size=3)) for node in skin.joints}
    node_parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}
    for node in skin.joints:
        up = node_parent.get(node)
        up_frame, up_place = (turn, np.zeros(3)) if up is None else (frames[up], places[order.index(up)])
        gltf.nodes[node].rotation = (up_frame.inv() * frames[node]).as_quat().tolist()
        gltf.nodes[node].translation = (up_frame.inv().apply(places[order.index(node)] - up_place) * 2).tolist()
    root = skin.joints[0]
    gltf.nodes.append(pygltflib.Node(name="Armature", children=[root], rotation=turn.as_quat().tolist(),
                                     scale=[0.5, 0.5, 0.5]))
    gltf.scenes[0].nodes = [len(gltf.nodes) - 1 if n == root else n for n in gltf.scenes[0].nodes]
    parent = {c: i for i, n in enumerate(gltf.nodes) for c in (n.children or [])}

    def world(i):
        n = gltf.nodes[i]
        m = _node_matrix(n.translation or [0, 0, 0], n.rotation or [0, 0, 0, 1], n.scale or [1, 1, 1])
        return world(parent[i]) @ m if i in parent else m

    inverse_bind = np.stack([np.linalg.inv(world(j)).T.reshape(16) for j in skin.joints]).astype("<f4")
    view = gltf.bufferViews[gltf.accessors[skin.inverseBindMatrices].bufferView]
    blob = bytearray(gltf.binary_blob())
    blob[view.byteOffset:view.byteOffset + inverse_bind.nbytes] = inverse_bind.tobytes()
    gltf.set_binary_blob(bytes(blob))
    gltf.animations = []
    character_file = folder / "blender_like.glb"
    gltf.save_binary(str(character_file))
    return character_file, plain


@pytest.mark.slow
def test_glb_with_an_armature_node_and_rest_rotations_moves_its_joints_where_the_result_says(tmp_path, source):
    """As exported by Blender: the skeleton under a rotated, scaled Armature node, bones with rest rotations."""
    character_file, plain = blender_like_glb(tmp_path)
    places = read_rig(plain).rest_world()[:, :3, 3]
    rig = read_rig(character_file)
    assert rig.names == read_rig(plain).names
    assert np.allclose(rig.rest_world()[:, :3, 3], places, atol=1e-5)  # the same rest places in the file's world
    character = build_character(rig)
    assert np.allclose(character.rest, build_character(read_rig(plain)).rest, atol=1e-5)

    report = retarget_result(source, character_file, tmp_path / "out", physics="none")
    after = pygltflib.GLTF2().load(report.files["glb"])
    animation = after.animations[-1]
    frame = 40
    trs = {i: [n.translation or [0, 0, 0], n.rotation or [0, 0, 0, 1], n.scale or [1, 1, 1]]
           for i, n in enumerate(after.nodes)}
    for channel in animation.channels:
        values = read_accessor(after, animation.samplers[channel.sampler].output)
        trs[channel.target.node][0 if channel.target.path == "translation" else 1] = values[frame]
    after_parent = {c: i for i, n in enumerate(after.nodes) for c in (n.children or [])}

    def animated(i):
        m = _node_matrix(*trs[i])
        return animated(after_parent[i]) @ m if i in after_parent else m

    result = load_result(report.files["result"])
    for k, node in enumerate(character.rig.nodes):
        position = animated(node)[:3, 3] @ character.file_to_world.T - character.origin
        assert np.allclose(position, result["rig_joints_world"][frame, k], atol=1e-4), after.nodes[node].name
    assert report.metrics["bone_cosine_rig"] >= 0.95
    # The BVH written for a glTF character: the same joints, its zero pose the rest pose, the same motion.
    bvh = read_bvh(report.files["bvh"])  # joints in depth-first order
    assert sorted(bvh.joint_names) == sorted(character.rig.names)
    positions, _ = forward_kinematics(bvh)
    order = [bvh.joint_names.index(name) for name in character.rig.names]
    error = np.abs(positions[:, order] @ character.file_to_world.T - character.origin - result["rig_joints_world"])
    worst = error.max(axis=(0, 2))
    assert error.max() < 2e-4, [(n, e) for n, e in zip(character.rig.names, worst, strict=True) if e > 2e-4]


@pytest.mark.slow
def test_khronos_validator_finds_no_new_issue_in_the_characters_glb(tmp_path, source):
    """The Khronos glTF validator on the GLB the retargeting writes (after PhysCap on the character): our skinned
    mannequin has no issue before or after; the Blender-like file has after exactly the issues it had before (the
    unused accessors of its removed animation), none of them an error or a warning."""
    body = build_body_model(template_lengths(1.58), 55.0)
    mannequin = tmp_path / "mannequin.glb"
    write_glb(mannequin, body, body.rest_qpos[None], 30.0)
    blender_like, _ = blender_like_glb(tmp_path)
    written = [retarget_result(source, character, tmp_path / character.stem, physics="physcap").files["glb"]
               for character in (mannequin, blender_like)]
    clean_in, clean_out, blender_in, blender_out = khronos_issues(mannequin, written[0], blender_like, written[1])
    assert issue_counts(clean_in) == issue_counts(clean_out) == (0, 0, 0, 0), clean_out["messages"]
    assert blender_out["messages"] == blender_in["messages"]
    assert issue_counts(blender_out)[:2] == (0, 0)


def test_vertical_force_over_the_explained_frames_leaves_the_flagged_ones_out(tmp_path):
    """Frames the character's physics flags (handed back as kinematic motion, no contact force claimed) would
    pull the mean vertical force below the weight; the explained figure reads only the frames it explains."""
    from physmocap.retarget.stage import follows_gap, retarget_metrics
    from physmocap.retarget.writers import rig_motion, rig_positions

    character = build_character(read_rig(_rigs(tmp_path)["mixamo"]))
    body, n = character.body, 12
    qpos = np.repeat(body.rest_qpos[None], n, axis=0)
    points = kin.forward_kinematics(body, qpos).points[:, body.point_index(RESULT_POINTS)]
    weight = body.mass * 9.81
    grf = np.zeros((n, 4, 3))
    grf[:, :, 2] = weight / 4  # the four points carry the weight ...
    flagged = np.zeros(n, bool)
    flagged[8:] = True
    grf[flagged] = 0.0  # ... except on the flagged frames
    every = np.ones(n, bool)
    m = retarget_metrics(character, points, qpos, rig_positions(character, rig_motion(character, qpos)),
                         np.ones((n, 4), bool), 30.0, grf, follows_gap(every), flagged)
    assert m["grf_vertical_mean_percent_bw"] == pytest.approx(100.0 * 8 / 12, abs=0.1)
    assert m["grf_vertical_explained_mean_percent_bw"] == pytest.approx(100.0, abs=0.1)
    assert m["grf_explained_mean_percent_bw"] == pytest.approx(100.0, abs=0.1)
    assert m["grf_mean_percent_bw"] == pytest.approx(100.0 * 8 / 12, abs=0.1)
    unflagged = retarget_metrics(character, points, qpos, rig_positions(character, rig_motion(character, qpos)),
                                 np.ones((n, 4), bool), 30.0, grf, follows_gap(every))
    assert unflagged["grf_vertical_explained_mean_percent_bw"] == unflagged["grf_vertical_mean_percent_bw"]
