"""Foot-contact stage: label rules, input representation, networks, prediction, baselines, training."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import physmocap  # noqa: F401 - single-threaded BLAS
from physmocap.contacts.baselines import always_contact, velocity_2d, velocity_3d
from physmocap.contacts.dataset import MIRRORED_CONTACT_COLUMNS, SyntheticSettings, split_by_subject
from physmocap.contacts.features import (
    CAUSAL_WINDOW,
    CENTRED_WINDOW,
    FEATURE_INDICES,
    mirror_keypoints,
    normalise_windows,
    select_keypoints,
    window_indices,
    window_inputs,
)
from physmocap.contacts.labels import (
    LabelSettings,
    contact_labels,
    hard_frames,
    motion_labels,
    point_speed,
    seconds_to_label_change,
    stationary_labels,
    without_short_phases,
)
from physmocap.contacts.networks import (
    FRAME_CHANNELS,
    NUM_OUTPUTS,
    CausalNetSpec,
    CentredNetSpec,
    causal_forward,
    centred_forward,
    ensemble_members,
    stack_members,
)
from physmocap.contacts.predict import (
    LOWEST_TRAINED_FPS,
    interpolated_frames,
    load_weights,
    network_probabilities,
    predict_contacts,
)
from physmocap.landmarks import LANDMARK_INDEX, MIRRORED
from physmocap.motion import Observations

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
needs_shared = pytest.mark.skipif(not (SHARED_DATA / "mocap").is_dir(), reason="../shared/data is not here")


# ---------------------------------------------------------------------------------------------------------------
# Labels


def sites_track(fps: float, seconds: float, height: float, speed: float) -> np.ndarray:
    """(T, 4, 3): four sites at `height` m, moving along x at `speed` m/s."""
    t = np.arange(int(round(seconds * fps))) / fps
    sites = np.zeros((len(t), 4, 3))
    sites[..., 0] = speed * t[:, None]
    sites[..., 2] = height
    return sites


@pytest.mark.parametrize("fps", [12.0, 30.0, 120.0])
def test_contact_rule_on_hand_made_cases(fps):
    assert contact_labels(sites_track(fps, 1.0, 0.0, 0.0), fps).all()  # planted
    assert contact_labels(sites_track(fps, 1.0, 0.01, 0.3), fps).all()  # rolling, under 1 m/s and 5 cm
    assert not contact_labels(sites_track(fps, 1.0, 0.10, 0.0), fps).any()  # held still in the air
    assert not contact_labels(sites_track(fps, 1.0, 0.0, 1.5), fps).any()  # sliding fast along the floor


def test_a_slow_slide_is_a_contact_unlike_in_rempes_rule():
    """A foot sliding at 0.8 m/s on the floor bears weight (a landing's glide): in contact by default, not by
    Rempe's 2 cm per 30 fps frame (0.6 m/s)."""
    sites = sites_track(30.0, 1.0, 0.0, 0.8)
    assert contact_labels(sites, 30.0).all()
    assert not contact_labels(sites, 30.0, LabelSettings(contact_max_speed=0.6)).any()


def test_hard_frames_are_raised_heels_and_skimming_feet():
    fps = 30.0
    flat = sites_track(fps, 1.0, 0.0, 0.0)
    raised = flat.copy()
    raised[:, 0, 2] = 0.08  # left heel 8 cm up and still, its toe planted: on the ball of the foot
    skimming = flat.copy()
    skimming[:, 3] = sites_track(fps, 1.0, 0.02, 2.0)[:, 3]  # right toe 2 cm up at 2 m/s
    lifted = flat.copy()
    lifted[:, :2, 2] = 0.08  # the whole left foot held up: neither
    for sites, expected in ((flat, False), (raised, True), (skimming, True), (lifted, False)):
        hard = hard_frames(sites, fps, contact_labels(sites, fps))
        assert hard.shape == (len(sites),) and hard[1:].all() == expected and hard[1:].any() == expected


def test_contact_rule_thresholds_are_settings():
    sites = sites_track(60.0, 1.0, 0.06, 0.0)
    assert not contact_labels(sites, 60.0).any()
    assert contact_labels(sites, 60.0, LabelSettings(contact_max_height=0.08)).all()


def test_contact_labels_agree_across_frame_rates():
    """A foot that stops for 0.5 s, labelled at 30 and 120 fps, gets the same labels at the same instants."""
    def foot(fps: float) -> np.ndarray:
        t = np.arange(int(2.0 * fps)) / fps
        x = np.where(t < 0.75, 2.0 * t, np.where(t < 1.25, 1.5, 1.5 + 2.0 * (t - 1.25)))
        sites = np.zeros((len(t), 4, 3))
        sites[..., 0] = x[:, None]
        return sites

    slow, fast = contact_labels(foot(30.0), 30.0), contact_labels(foot(120.0), 120.0)
    assert np.mean(slow[:, 0] == fast[::4, 0]) > 0.95
    assert slow[:, 0].sum() == pytest.approx(15, abs=2)  # 0.5 s at 30 fps


def test_short_phases_merge_into_their_neighbours():
    flags = np.array([1, 0, 1, 1, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1], dtype=bool)[:, None]
    expected = np.array([1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 1, 1], dtype=bool)[:, None]
    assert np.array_equal(without_short_phases(flags, 3), expected)  # 1-frame gap filled, 1-frame contact dropped
    assert np.array_equal(without_short_phases(flags, 1), flags)


def test_a_one_frame_flicker_is_not_a_contact_change():
    """A planted foot whose measured speed crosses the threshold for one frame stays in contact."""
    fps = 60.0
    sites = sites_track(fps, 1.0, 0.0, 0.0)
    sites[30:, :, 0] += 0.05  # a 5 cm jump between two frames: 1.5 m/s over the 1/30 s of frames 30 and 31
    assert contact_labels(sites, fps).all()
    assert not contact_labels(sites, fps, LabelSettings(min_phase_seconds=0.0, rest_on_either_side=False))[30:32].all()


def test_a_site_is_in_contact_from_the_frame_it_lands_in_to_the_last_it_rests_in():
    """A foot gliding in at 2 m/s rests from frame 10 to frame 20, then leaves: contact at 10-20. Judged only
    over the interval before each frame (Rempe's reading), the landing frame still carries the approach."""
    fps = 30.0
    x = np.concatenate([2.0 * (np.arange(11) - 10) / fps, np.zeros(10), 2.0 * np.arange(1, 11) / fps])
    sites = np.zeros((len(x), 4, 3))
    sites[..., 0] = x[:, None]
    settings = LabelSettings(min_phase_seconds=0.0)
    assert np.array_equal(np.flatnonzero(contact_labels(sites, fps, settings)[:, 0]), np.arange(10, 21))
    backward = contact_labels(sites, fps, LabelSettings(min_phase_seconds=0.0, rest_on_either_side=False))
    assert np.array_equal(np.flatnonzero(backward[:, 0]), np.arange(11, 21))


def test_point_speed_and_stationary():
    fps = 50.0
    t = np.arange(100) / fps
    root = np.stack([0.1 * t, np.zeros_like(t), np.full_like(t, 0.9)], axis=1)
    assert np.allclose(point_speed(root, fps, 0.2, centred=True), 0.1)
    assert np.allclose(point_speed(root, fps, 1 / 30, centred=False), 0.1)
    assert stationary_labels(root, fps).all()
    assert not stationary_labels(10 * root, fps).any()  # 1 m/s walk


# ---------------------------------------------------------------------------------------------------------------
# Input representation


def person_keypoints(num_frames: int, rng: np.random.Generator, offset=(400.0, 300.0), scale=100.0) -> np.ndarray:
    """(T, 33, 3) a rough upright person: random points around a body shape, confidences 0.9."""
    template = rng.uniform(-0.3, 0.3, (33, 2))
    for name, xy in {"left_shoulder": (0.2, -0.5), "right_shoulder": (-0.2, -0.5), "left_hip": (0.1, 0.0),
                     "right_hip": (-0.1, 0.0), "left_knee": (0.1, 0.45), "right_knee": (-0.1, 0.45),
                     "left_ankle": (0.1, 0.9), "right_ankle": (-0.1, 0.9)}.items():
        template[LANDMARK_INDEX[name]] = xy
    xy = scale * (template + 0.01 * rng.standard_normal((num_frames, 33, 2))) + np.asarray(offset)
    return np.concatenate([xy, np.full((num_frames, 33, 1), 0.9)], axis=2)


def test_window_shapes_and_clamping():
    assert CAUSAL_WINDOW.input_size == 7 * 12 * 4 + 1
    assert CENTRED_WINDOW.input_size == 9 * 12 * 4 + 1
    indices = window_indices(5, np.array([0, 4]), CENTRED_WINDOW)
    assert indices.shape == (2, 9)
    assert indices[0].tolist() == [0, 0, 0, 0, 0, 1, 2, 3, 4]
    assert window_indices(5, np.array([2]), CAUSAL_WINDOW)[0].tolist() == [0, 0, 0, 0, 0, 1, 2]
    points = select_keypoints(person_keypoints(20, np.random.default_rng(0)), np.ones(20, bool))
    inputs = window_inputs(points, 30.0, np.arange(20), CAUSAL_WINDOW)
    assert inputs.shape == (20, CAUSAL_WINDOW.input_size) and inputs.dtype == np.float32
    assert np.allclose(inputs[:, -1], 1.0)  # 30 fps: one reference frame interval
    frames = inputs[:, :-1].reshape(20, 7, 12, 4)
    assert np.allclose(frames[0, :, :, 2], 0.0)  # the first frame repeats: no motion
    speeds = np.linalg.norm(np.diff(frames[10, :, :, :2], axis=0), axis=-1)
    assert np.allclose(frames[10, 1:, :, 2], speeds, atol=1e-6)
    slower = window_inputs(points, 60.0, np.arange(20), CAUSAL_WINDOW).reshape(20, -1)
    assert np.allclose(slower[:, -1], 0.5)


def test_normalisation_is_root_centred_and_scale_free():
    rng = np.random.default_rng(1)
    keypoints = person_keypoints(9, rng)
    points = select_keypoints(keypoints, np.ones(9, bool))[None]
    normalised = normalise_windows(points, 4)
    hips = normalised[0, 4, 2:4, :2].mean(axis=0)
    assert np.allclose(hips, 0.0, atol=1e-6)
    moved = points.copy()
    moved[..., :2] = 3.0 * moved[..., :2] + np.array([250.0, -80.0])
    assert np.allclose(normalise_windows(moved, 4), normalised, atol=1e-5)
    assert np.abs(normalised[..., :2]).max() < 2.0


def test_invalid_frames_are_filled_with_zero_confidence():
    keypoints = person_keypoints(6, np.random.default_rng(2))
    valid = np.array([True, False, False, True, True, False])
    keypoints[~valid] = 0.0
    points = select_keypoints(keypoints, valid)
    assert np.array_equal(points[1, :, :2], points[0, :, :2]) and np.array_equal(points[2, :, :2], points[3, :, :2])
    assert np.array_equal(points[5, :, :2], points[4, :, :2])
    assert (points[~valid, :, 2] == 0).all() and (points[valid, :, 2] > 0).all()


def test_mirroring_swaps_sides():
    keypoints = person_keypoints(3, np.random.default_rng(3))
    mirrored = mirror_keypoints(keypoints, 1000)
    left, right = LANDMARK_INDEX["left_heel"], LANDMARK_INDEX["right_heel"]
    assert np.allclose(mirrored[:, left, 0], 999 - keypoints[:, right, 0])
    assert np.allclose(mirror_keypoints(mirrored, 1000), keypoints)
    assert MIRRORED_CONTACT_COLUMNS == (2, 3, 0, 1)
    assert all(MIRRORED[MIRRORED[i]] == i for i in FEATURE_INDICES)


# ---------------------------------------------------------------------------------------------------------------
# Networks and prediction


def random_params(spec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Random parameters with the layout of networks.py."""
    if isinstance(spec, CausalNetSpec):
        params, channels = {}, FRAME_CHANNELS + 1
        for i, out in enumerate(spec.channels):
            params[f"conv{i}.weight"] = rng.normal(0, 0.1, (spec.kernel, channels, out)).astype(np.float32)
            params[f"conv{i}.bias"] = rng.normal(0, 0.1, out).astype(np.float32)
            channels = out
        params["fc.weight"] = rng.normal(0, 0.1, (channels, NUM_OUTPUTS)).astype(np.float32)
        params["fc.bias"] = np.zeros(NUM_OUTPUTS, np.float32)
        return params
    sizes = (spec.window.input_size,) + spec.hidden + (spec.window.outputs * NUM_OUTPUTS,)
    return {key: rng.normal(0, 0.05, shape).astype(np.float32)
            for i in range(len(sizes) - 1)
            for key, shape in ((f"linear{i}.weight", (sizes[i], sizes[i + 1])), (f"linear{i}.bias", (sizes[i + 1],)))}


def test_numpy_forward_shapes():
    rng = np.random.default_rng(4)
    causal = random_params(CausalNetSpec(channels=(8, 8, 8)), rng)
    centred = random_params(CentredNetSpec(hidden=(16, 8)), rng)
    assert causal_forward(causal, rng.normal(size=(5, CAUSAL_WINDOW.input_size)).astype(np.float32)).shape == (5, 5)
    centred_inputs = rng.normal(size=(5, CENTRED_WINDOW.input_size)).astype(np.float32)
    assert centred_forward(centred, centred_inputs).shape == (5, 5, 5)


@pytest.mark.parametrize("mode", ["causal", "centred"])
def test_an_ensemble_predicts_the_mean_of_its_members_probabilities(mode):
    rng = np.random.default_rng(8)
    spec = CausalNetSpec(channels=(8, 8, 8)) if mode == "causal" else CentredNetSpec(hidden=(16, 8))
    members = [random_params(spec, rng) for _ in range(3)]
    ensemble = stack_members(members)
    assert all(value.shape[0] == 3 for value in ensemble.values())
    assert all(np.array_equal(a[key], b[key]) for a, b in zip(ensemble_members(ensemble), members, strict=True)
               for key in a)
    assert ensemble_members(members[0]) == [members[0]]
    keypoints, valid = person_keypoints(20, rng), np.ones(20, bool)
    alone = [network_probabilities(keypoints, valid, 30.0, m, mode, mirror=False)[0] for m in members]
    together, _ = network_probabilities(keypoints, valid, 30.0, ensemble, mode, mirror=False)
    assert np.allclose(together, np.mean(alone, axis=0), atol=1e-6)
    assert not np.allclose(alone[0], alone[1], atol=1e-3)  # the members differ, so the mean is a real test


@pytest.mark.slow
def test_numpy_inference_matches_torch():
    torch = pytest.importorskip("torch")
    from physmocap.contacts.train import TorchCausalNet, TorchCentredNet

    torch.manual_seed(0)
    for model, size in ((TorchCausalNet(CausalNetSpec()), CAUSAL_WINDOW.input_size),
                        (TorchCentredNet(CentredNetSpec(hidden=(64, 32, 16, 8))), CENTRED_WINDOW.input_size)):
        for module in model.modules():
            if isinstance(module, torch.nn.BatchNorm1d):  # non-trivial statistics to fold
                module.running_mean.uniform_(-1, 1)
                module.running_var.uniform_(0.5, 2)
                module.weight.data.uniform_(0.5, 1.5)
                module.bias.data.uniform_(-0.5, 0.5)
        model.eval()
        inputs = torch.randn(32, size)
        with torch.no_grad():
            expected = model(inputs).numpy()
        forward = causal_forward if isinstance(model, TorchCausalNet) else centred_forward
        assert np.allclose(forward(model.export(), inputs.numpy()).reshape(expected.shape), expected, atol=1e-4)


@pytest.mark.parametrize("mode", ["causal", "centred"])
def test_predict_contacts_with_shipped_weights(mode):
    rng = np.random.default_rng(5)
    keypoints = person_keypoints(40, rng)
    valid = np.ones(40, bool)
    valid[[10, 11, 30]] = False
    keypoints[~valid] = 0.0
    obs = Observations(keypoints_2d=keypoints, landmarks_3d=np.zeros((40, 33, 3)), fps=30.0, image_size=(800, 600),
                       valid=valid)
    contacts, stationary, probabilities = predict_contacts(obs, mode)
    assert contacts.shape == (40, 4) and contacts.dtype == bool
    assert stationary.shape == (40,) and probabilities.shape == (40, 5)
    assert not contacts[~valid].any() and not stationary[~valid].any() and (probabilities[~valid] == 0).all()
    assert ((probabilities >= 0) & (probabilities <= 1)).all()


@pytest.mark.parametrize("mode", ["causal", "centred"])
def test_mirrored_votes_make_predictions_mirror_symmetric(mode):
    """With the mirrored input's votes, a mirrored video gets the mirrored flags: its left columns are the
    original's right ones. Without them the network alone decides, which is not symmetric."""
    rng = np.random.default_rng(7)
    keypoints = person_keypoints(30, rng)
    mirrored = mirror_keypoints(keypoints, 800)
    params = load_weights(mode)
    valid = np.ones(30, bool)
    swap = [2, 3, 0, 1, 4]
    probabilities, flags = network_probabilities(keypoints, valid, 30.0, params, mode, mirror=True)
    mirror_probabilities, mirror_flags = network_probabilities(mirrored, valid, 30.0, params, mode, mirror=True)
    assert np.allclose(mirror_probabilities[:, swap], probabilities, atol=1e-5)
    assert np.array_equal(mirror_flags[:, swap], flags)
    plain, _ = network_probabilities(keypoints, valid, 30.0, params, mode, mirror=False)
    plain_mirrored, _ = network_probabilities(mirrored, valid, 30.0, params, mode, mirror=False)
    assert not np.allclose(plain_mirrored[:, swap], plain, atol=1e-5)


@pytest.mark.parametrize("fps", [30.0, 10.0])  # 10 fps: read at 20 fps, interpolated
def test_causal_predictions_ignore_the_future(fps):
    rng = np.random.default_rng(6)
    keypoints = person_keypoints(30, rng)
    params = load_weights("causal")
    before, _ = network_probabilities(keypoints, np.ones(30, bool), fps, params, "causal")
    changed = keypoints.copy()
    changed[20:, :, :2] += rng.normal(0, 30, changed[20:, :, :2].shape)
    after, _ = network_probabilities(changed, np.ones(30, bool), fps, params, "causal")
    assert np.array_equal(before[:20], after[:20]) and not np.array_equal(before[20:], after[20:])


def test_a_video_slower_than_the_training_rates_is_read_at_a_multiple_of_its_rate():
    """Below the training videos' lowest rate the networks see frames put linearly between the video's and
    predict each video frame on its own interpolated neighbourhood: at 10 fps, exactly the 20 fps prediction of
    the interpolated video at the video's frames. An in-between frame is valid only where both of its frames are."""
    assert LOWEST_TRAINED_FPS == SyntheticSettings().fps_range[0]
    rng = np.random.default_rng(8)
    keypoints = person_keypoints(20, rng)
    valid = np.ones(20, bool)
    valid[7] = False
    dense, dense_valid = interpolated_frames(keypoints, valid, 2)
    assert dense.shape == (39, 33, 3) and np.allclose(dense[::2], keypoints)
    assert np.allclose(dense[1], (keypoints[0] + keypoints[1]) / 2)
    assert np.array_equal(dense_valid[::2], valid) and not dense_valid[[13, 15]].any() and dense_valid[17]
    params = load_weights("centred")
    slow, slow_flags = network_probabilities(keypoints, valid, 10.0, params, "centred")
    read, read_flags = network_probabilities(dense, dense_valid, 20.0, params, "centred")
    assert np.array_equal(slow, read[::2]) and np.array_equal(slow_flags, read_flags[::2])


# ---------------------------------------------------------------------------------------------------------------
# Baselines


def test_baselines_on_a_planted_and_a_swinging_foot():
    rng = np.random.default_rng(7)
    keypoints = person_keypoints(30, rng)
    keypoints[:, :, :2] = np.round(keypoints[0, :, :2])  # a still person
    swinging = [LANDMARK_INDEX[name] for name in ("right_heel", "right_foot_index")]
    keypoints[:, swinging, 0] += 40.0 * np.arange(30)[:, None]  # 40 px a frame: 12 person sizes per second
    valid = np.ones(30, bool)
    valid[5] = False
    contacts, stationary = velocity_2d(keypoints, valid, 30.0)
    assert contacts[10:, :2].all() and not contacts[10:, 2:].any() and stationary[10:].all()
    assert not contacts[5].any() and not stationary[5]
    landmarks = np.zeros((30, 33, 3))
    landmarks[:, swinging, 0] = 0.1 * np.arange(30)[:, None]  # 3 m/s
    assert velocity_3d(landmarks, valid, 30.0)[10:].tolist() == [[True, True, False, False]] * 20
    always, still = always_contact(30, valid)
    assert always.sum() == 4 * 29 and still.sum() == 29


# ---------------------------------------------------------------------------------------------------------------
# Data and training (need ../shared/data)


def test_split_by_subject_never_shares_a_subject():
    files = [Path(name) for name in ("02_01.bvh", "002_05.bvh", "006_01.bvh", "131_02.bvh", "007_01.bvh")]
    train, test = split_by_subject(files, ("6", "131"))
    assert [f.name for f in test] == ["006_01.bvh", "131_02.bvh"]
    assert [f.name for f in train] == ["02_01.bvh", "002_05.bvh", "007_01.bvh"]


def _flat_stance_foot(clip) -> np.ndarray:
    """Medians over a clip's flat-stance foot-frames (heel and toe labelled in contact and still): heel minus toe
    height, ankle height above the heel site, horizontal heel-ankle and ankle-toe distances, metres."""
    from physmocap.mocap.bvh_reader import STILL_SPEED

    contacts, _ = motion_labels(clip.positions, clip.fps)
    rows = []
    for f, side in enumerate(("left", "right")):
        ankle, heel, toe = (clip.joint(f"{side}_{part}") for part in ("ankle", "heel", "toe"))
        still = [np.linalg.norm(np.gradient(p, axis=0), axis=1) * clip.fps < STILL_SPEED for p in (heel, toe)]
        flat = contacts[:, 2 * f] & contacts[:, 2 * f + 1] & still[0] & still[1]
        rows.append(np.stack([heel[flat, 2] - toe[flat, 2], ankle[flat, 2] - heel[flat, 2],
                              np.linalg.norm((ankle - heel)[flat, :2], axis=1),
                              np.linalg.norm((toe - ankle)[flat, :2], axis=1)], axis=1))
    rows = np.concatenate(rows)
    assert len(rows) >= 30  # each walk has at least a few flat stances on each skeleton
    return np.median(rows, axis=0)


@needs_shared
@pytest.mark.parametrize("daz_name, cc3_name", [("02_01", "002_01"), ("07_03", "007_03")])
def test_daz_flat_stance_foot_matches_the_cc3_avatar_in_the_same_walk(daz_name, cc3_name):
    from physmocap.mocap.bvh_reader import load_mocap

    mocap = SHARED_DATA / "mocap"
    daz = _flat_stance_foot(load_mocap(mocap / "cmu_daz_cgspeed" / f"{daz_name}.bvh"))
    cc3 = _flat_stance_foot(load_mocap(mocap / "cmu_iclone_cc3_retarget" / f"{cc3_name}.bvh"))
    assert abs(daz[0]) < 0.005 and abs(daz[0] - cc3[0]) < 0.005  # heel and toe sites level, as on CC3
    assert abs(daz[1] - cc3[1]) < 0.006  # ankle height above the sole (DAZ_TOE_BASE_ABOVE_SOLE 0.20 gave 1.0 cm)
    assert abs(daz[2] - cc3[2]) < 0.005 and abs(daz[3] - cc3[3]) < 0.015  # heel behind, toe ahead of the ankle


@needs_shared
def test_synthetic_sequences_are_deterministic_and_labelled():
    from physmocap.contacts.dataset import SyntheticSettings, load_clips, make_sequences

    clips = load_clips([SHARED_DATA / "mocap" / "cmu_iclone_cc3_retarget" / "007_01.bvh"])
    settings = SyntheticSettings(variants_per_clip=3)
    first, again = make_sequences(clips, 5, settings), make_sequences(clips, 5, settings)
    assert all(np.array_equal(a.keypoints_2d, b.keypoints_2d) and np.array_equal(a.contacts, b.contacts)
               for a, b in zip(first, again, strict=True))
    for sequence in first:
        assert 12 <= sequence.fps <= 60
        assert sequence.contacts.shape == (sequence.num_frames, 4)
        assert sequence.stationary.shape == (sequence.num_frames,)
        assert 0.3 < sequence.contacts.mean() < 0.8  # a walk: each site down about half the time
        assert not sequence.stationary.any()


@needs_shared
def test_mediapipe_foot_keypoints_change_only_the_heel_and_foot_index_keypoints():
    from physmocap.contacts.dataset import SyntheticSettings, load_clips, make_sequences
    from physmocap.landmarks import LANDMARK_INDEX

    clips = load_clips([SHARED_DATA / "mocap" / "cmu_iclone_cc3_retarget" / "007_01.bvh"])
    sole = make_sequences(clips, 5, SyntheticSettings(variants_per_clip=2, foot_keypoints="sole"))
    placed = make_sequences(clips, 5, SyntheticSettings(variants_per_clip=2, foot_keypoints="mediapipe"))
    feet = [LANDMARK_INDEX[f"{side}_{part}"] for side in ("left", "right") for part in ("heel", "foot_index")]
    others = [k for k in range(sole[0].keypoints_2d.shape[1]) if k not in feet]
    for a, b in zip(sole, placed, strict=True):
        # Same camera, rate, body and noise draws, same labels; only the foot keypoints move.
        np.testing.assert_array_equal(a.keypoints_2d[:, others], b.keypoints_2d[:, others])
        np.testing.assert_array_equal(a.contacts, b.contacts)
        assert np.abs(a.keypoints_2d[:, feet, :2] - b.keypoints_2d[:, feet, :2]).max() > 1.0  # pixels


@pytest.mark.slow
@needs_shared
def test_training_runs_a_few_steps(tmp_path):
    pytest.importorskip("torch")
    from physmocap.contacts.dataset import SyntheticSettings
    from physmocap.contacts.train import ContactTrainingSettings, TrainSettings, train_contacts

    settings = ContactTrainingSettings(
        synthetic=SyntheticSettings(variants_per_clip=1), optimisation=TrainSettings(max_steps=3, batch_size=64),
        causal=CausalNetSpec(channels=(16, 16, 16)), centred=CentredNetSpec(hidden=(32, 16)), test_variants_per_clip=1)
    metadata = train_contacts(SHARED_DATA, tmp_path, seed=3, settings=settings, max_clips=1, log=lambda _: None)
    assert metadata["causal"]["members"][0]["steps"] == 3
    assert set(metadata["test_subjects"]).isdisjoint(metadata["train_subjects"])
    assert (np.array([5e-324]) * 1.0)[0] != 0  # training flushed subnormal floats only while it ran
    assert len(metadata["data_sha256"]) == 64 and metadata["git_revision"]
    first = {mode: dict(np.load(tmp_path / f"{mode}.npz")) for mode in ("causal", "centred")}
    members = CausalNetSpec().members  # the causal ensemble's members, stacked on a leading axis
    assert first["causal"]["fc.bias"].shape == (members, 5) and len(metadata["causal"]["members"]) == members
    assert first["centred"]["linear0.bias"].shape == (CentredNetSpec().members, 32)  # on their own draws
    single = dataclasses.replace(settings, centred=dataclasses.replace(settings.centred, members=1))
    train_contacts(SHARED_DATA, tmp_path / "single", seed=3, settings=single, max_clips=1, log=lambda _: None,
                   modes=("centred",))
    alone_member = dict(np.load(tmp_path / "single" / "centred.npz"))  # member 0: the shared draw, as one network
    assert all(np.array_equal(first["centred"][k][0], v) for k, v in alone_member.items())
    assert not np.array_equal(first["centred"]["linear0.bias"][1], first["centred"]["linear0.bias"][2])
    train_contacts(SHARED_DATA, tmp_path, seed=3, settings=settings, max_clips=1, log=lambda _: None)
    for mode, params in first.items():
        again = load_weights(mode, tmp_path)
        assert params.keys() == again.keys() and all(np.array_equal(params[k], again[k]) for k in params)
    alone = train_contacts(SHARED_DATA, tmp_path / "centred", seed=3, settings=settings, max_clips=1,
                           log=lambda _: None, modes=("centred",))
    assert "causal" not in alone and not (tmp_path / "centred" / "causal.npz").exists()
    assert all(np.array_equal(first["centred"][k], v) for k, v in np.load(tmp_path / "centred" / "centred.npz").items())


@pytest.mark.slow
@pytest.mark.parametrize("weight", [1.0, 9.0])
def test_hard_frame_weight_oversamples_hard_targets(weight):
    pytest.importorskip("torch")
    from physmocap.contacts.train import FrameTable, TorchCentredNet, TrainSettings, train_network

    frames = 2000
    rng = np.random.default_rng(0)
    hard = np.arange(frames) < frames // 10
    targets = []

    class Recording(FrameTable):
        def batch(self, chosen, *args):
            targets.append(chosen)
            return super().batch(chosen, *args)

    table = Recording(points=rng.random((frames, 12, 3), dtype=np.float32), interval=np.ones(frames, np.float32),
                      labels=np.zeros((frames, 5), np.float32), sequence_start=np.zeros(frames, int),
                      sequence_length=np.full(frames, frames), hard=hard)
    spec = CentredNetSpec(hidden=(8, 8))
    settings = TrainSettings(epochs=1, batch_size=100, hard_frame_weight=weight)
    result = train_network(TorchCentredNet(spec), table, spec.window, settings, 0, log=lambda _: None)
    chosen = np.concatenate(targets)
    assert result["steps"] == 20 and len(chosen) == frames  # the same number of steps and targets
    share = hard[chosen].mean()
    if weight == 1.0:
        assert np.array_equal(np.sort(chosen), np.arange(frames)) and share == 0.1
    else:
        assert 0.45 < share < 0.55  # 200 x 9 against 1800 x 1


@pytest.mark.slow
@needs_shared
def test_shipped_weights_beat_the_heuristics_on_held_out_subjects():
    from physmocap.contacts.dataset import held_out_settings, load_clips, make_sequences

    mocap = SHARED_DATA / "mocap" / "cmu_iclone_cc3_retarget"
    clips = load_clips([mocap / name for name in ("006_01.bvh", "006_15.bvh")])
    sequences = make_sequences(clips, 11, held_out_settings(), variants=2)
    truth = np.concatenate([s.contacts for s in sequences])
    accuracy = {}
    for mode in ("causal", "centred"):
        params = load_weights(mode)
        predicted = np.concatenate([network_probabilities(s.keypoints_2d, s.valid, s.fps, params, mode)[1][:, :4]
                                    for s in sequences])
        accuracy[mode] = np.mean(predicted == truth)
    always = truth.mean()
    velocity = np.mean(np.concatenate([velocity_2d(s.keypoints_2d, s.valid, s.fps)[0] for s in sequences]) == truth)
    velocity_3d_flags = np.concatenate([velocity_3d(s.landmarks_3d, s.valid, s.fps) for s in sequences])
    velocity_3d_accuracy = np.mean(velocity_3d_flags == truth)
    for mode, value in accuracy.items():
        assert value > max(always, velocity, velocity_3d_accuracy) + 0.03, (mode, accuracy, always, velocity)


def test_seconds_to_a_label_change_count_half_a_frame_beside_it():
    contacts = np.zeros((6, 4), bool)
    contacts[3:, 0] = True  # site 0 lands between frames 2 and 3; the others never change
    distance = seconds_to_label_change(contacts, 30.0)
    assert np.allclose(distance[:, 0] * 30.0, [2.5, 1.5, 0.5, 0.5, 1.5, 2.5])
    assert np.isinf(distance[:, 1:]).all()
