"""Synthetic training and test data for the contact networks: detector-like 2D keypoints from motion capture,
labelled automatically, split by CMU subject.

Every sequence is one clip of `../shared/data/mocap` (or a segment of a long one), played forwards or backwards
at its own speed, with its own body proportions (`vary_proportions`), frame rate (resampled, 12-60 fps), static
camera (Rempe A.1 via `random_camera`, random focal length, landscape or portrait image), left/right mirroring,
and MediaPipe-like errors (`noise.TRAINING_NOISE`). The labels come from the played motion at its own frame
rate, before the body and the camera change (`labels.motion_labels`), and are carried to each resampled frame
from the nearest original frame, so they do not depend on the rendering.

Everything is deterministic given the seed: each sequence draws from its own generator seeded by (seed, clip
name, variant), so adding clips or variants does not change the others.
"""

from __future__ import annotations

import os
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..landmarks import MIRRORED
from ..mocap.bvh_reader import JOINT_INDEX, MocapClip, cmu_subject, load_mocap
from ..mocap.synthetic import NoiseModel, make_observations, random_camera, resample
from .features import mirror_keypoints
from .labels import CONTACT_SITE_INDICES, LabelSettings, hard_frames, motion_labels, point_speed
from .noise import TRAINING_NOISE

TEST_SUBJECTS: tuple[str, ...] = ("6", "9", "94", "131")
"""CMU subjects held out for testing: basketball and walks (6), runs (9), Indian dance (94, the acRNN clips),
start-walk-stop and hops (131). Subjects 1 and 7 are the validation subjects for choosing settings; every other
subject trains."""
ISSUE3_FOLDERS: tuple[str, ...] = ("cmu_iclone_cc3_retarget", "cmu_raw_cgspeed")
"""The folders of ../shared/data/mocap the contact weights shipped before issue 18 were trained on (the shipped ones
train on every folder, `ContactTrainingSettings.folders`)."""

HOVER_SPEED = 0.3  # m/s
MAX_SINK = 0.03  # m below the floor
MAX_IMPLAUSIBLE_FRACTION = 0.05
# Contact columns (l heel, l toe, r heel, r toe) after a left/right mirror.
MIRRORED_CONTACT_COLUMNS = (2, 3, 0, 1)
_UPPER_BODY = tuple(JOINT_INDEX[n] for n in ("spine", "neck", "head", "left_shoulder", "left_elbow", "left_wrist",
                                              "right_shoulder", "right_elbow", "right_wrist"))
_ARMS = {side: tuple(JOINT_INDEX[f"{side}_{part}"] for part in ("elbow", "wrist")) for side in ("left", "right")}


@dataclass(frozen=True)
class SyntheticSettings:
    """How synthetic sequences are made.

    variants_per_clip: sequences made from each clip (different cameras, rates, bodies, noise). Variety is what
        the few training subjects lack: with subjects 1 and 7 held out for validation (centred network, the same
        number of steps), 48 variants scored 0.943 on them, 96 0.947, 192 0.951; 8, 24 and 48 variants at 4 epochs
        0.871, 0.930 and 0.943 (the 4-epoch runs with labels whose short runs were not merged yet;
        scripts/contact_validation.py). The causal network, 2 epochs, shipped labels: 48 against 256 variants
        0.933 / 0.954 with 1 and 7 held out, 0.891 / 0.892 with 2 and 5 (real frames 0.936 / 0.930 and 0.867 /
        0.895). Those figures are for the four subjects of issue 3; the shipped weights train on every folder (ten
        times the motion) with 32 variants, 955,087 frames against the 1.26 million of 256 variants of those
        four (docs/decisions/contact-training-data.md).
    fps_range: frames per second, uniform (issue 3: 12-60).
    max_seconds: longer clips are cut to a random segment of this length, s (a static camera must keep the
        whole segment in view; 8 s keeps the person large in the frame).
    reverse_probability: chance of playing the motion backwards: a walk played backwards is a backward walk
        with the same contacts. The training subjects hardly step backwards or sideways, the held-out basketball
        subject and real videos do; in the experiments it changed the held-out accuracy by less than 0.03.
    playback_speed_range: the motion is played this much faster, uniform (slow and brisk versions of every
        motion); the labels are computed after this, so a foot that moves too fast is not in contact. 0.7-1.6
        (the held-out subjects dribble and hop with quicker, shorter steps than the training ones walk) scored
        better on validation subjects 1 and 7 (played at 0.8-1.25; 48 variants, 2 epochs, seeds 0-2: centred
        0.946 / 0.945 / 0.946 against 0.941 / 0.942 / 0.940, causal 0.937 / 0.934 / 0.938 against 0.934 / 0.937 /
        0.933, real frames unchanged), but weights retrained with it scored the same on the test subjects (centred
        0.888 / 0.914, causal 0.862 / 0.892 against 0.863 / 0.893; real 0.901 / 0.891 against 0.901 / 0.888), and
        their contacts took trajopt's body error on the synthetic set from +4.5% to +10.5% over its input (131_03
        seed 0: 40.5 -> 56.7 mm), so the shipped weights keep 0.8-1.25. 0.6-2.0 lost on the real frames (centred,
        seed 0: 0.896 against 0.907). Held-out sets use 0.8-1.25 whatever the training range
        (`held_out_settings`): the motion at about its own speed.
    mirror_probability: chance of mirroring a sequence left/right.
    stature_scale_range: the whole body scaled about the floor by this factor, uniform (0.85-1.12 turns the
        CMU actors into people of about 1.45-1.95 m).
    upper_body_scale_range: trunk, head and arms scaled about the pelvis, uniform (trunk-to-leg ratio).
    arm_scale_range: elbows and wrists scaled about the shoulders, uniform.
    portrait_probability: chance of a 1080 x 1920 portrait image instead of 1280 x 720 (phone videos).
    noise: the detector's errors.
    foot_keypoints: where the heel and foot_index keypoints sit on the foot (`synthetic.FOOT_KEYPOINTS`): "sole",
        the sole sites the labels use (the weights before issue 18), or "mediapipe" (shipped), where MediaPipe puts
        them on a flat
        foot, its heel about 4 cm above its foot_index (`synthetic.mediapipe_foot_keypoints`;
        docs/decisions/contact-training-data.md, "Foot keypoints").
    labels: the automatic label thresholds.
    """

    variants_per_clip: int = 32
    fps_range: tuple[float, float] = (12.0, 60.0)
    max_seconds: float = 8.0
    reverse_probability: float = 0.5
    playback_speed_range: tuple[float, float] = (0.8, 1.25)
    mirror_probability: float = 0.5
    stature_scale_range: tuple[float, float] = (0.85, 1.12)
    upper_body_scale_range: tuple[float, float] = (0.9, 1.1)
    arm_scale_range: tuple[float, float] = (0.9, 1.1)
    portrait_probability: float = 0.3
    noise: NoiseModel = field(default=TRAINING_NOISE)
    foot_keypoints: str = "mediapipe"
    labels: LabelSettings = field(default_factory=LabelSettings)


HELD_OUT_PLAYBACK: tuple[float, float] = (0.8, 1.25)
"""Playback speeds of the held-out (test and validation) sequences: every benchmark figure since issue 3 uses them,
whatever range the training data are played at."""


def held_out_settings(settings: SyntheticSettings = SyntheticSettings()) -> SyntheticSettings:
    """The settings of held-out sequences: `settings` with the playback speeds of HELD_OUT_PLAYBACK."""
    return replace(settings, playback_speed_range=HELD_OUT_PLAYBACK)


@dataclass
class SyntheticSequence:
    """One synthetic video's detector output and labels.

    name: "<clip>#<variant>". subject: CMU subject id.
    fps: frames per second. image_size: (width, height) pixels.
    keypoints_2d: (T, 33, 3) pixels + confidence. landmarks_3d: (T, 33, 3) metres, hip-relative, camera axes.
    contacts: (T, 4) bool, l heel, l toe, r heel, r toe. stationary: (T,) bool.
    hard: (T,) bool, frames of a raised heel or a skimming foot in the played motion (`labels.hard_frames`).
    """

    name: str
    subject: str
    fps: float
    image_size: tuple[int, int]
    keypoints_2d: np.ndarray
    landmarks_3d: np.ndarray
    contacts: np.ndarray
    stationary: np.ndarray
    hard: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.keypoints_2d)

    @property
    def valid(self) -> np.ndarray:
        return np.ones(self.num_frames, dtype=bool)


def mocap_files(mocap_root: str | os.PathLike) -> list[Path]:
    """Every BVH file under mocap_root (both the raw CMU and the CC3 folders), sorted by name."""
    files = sorted(Path(mocap_root).rglob("*.bvh"))
    if not files:
        raise InputError(f"{mocap_root}: no .bvh files found.")
    return files


def usable_clip(clip: MocapClip, settings: LabelSettings = LabelSettings()) -> bool:
    """False for clips whose automatic labels cannot be trusted:
    - uneven ground (the loader could not level the floor: CMU 03_01, 03_02, "walk on uneven terrain");
    - a still foot hovering above the floor with no contact anywhere (no site labelled in contact while a site
      moves slower than HOVER_SPEED at 5-25 cm above the floor) in more than MAX_IMPLAUSIBLE_FRACTION of the
      frames: the person must be standing on something, so the floor or the foot geometry is off (the dancer
      on her toes in CMU 05_05, 05_06, 05_08, whose retargeted toe sites float 7-20 cm up);
    - feet more than 3 cm below the floor in more than MAX_IMPLAUSIBLE_FRACTION of the frames (CMU 02_03, a run
      retargeted without vertical root motion).
    """
    if any("not levelled" in note for note in clip.notes):
        return False
    contacts, _ = motion_labels(clip.positions, clip.fps, settings)
    sites = clip.positions[:, CONTACT_SITE_INDICES]
    speed = point_speed(sites, clip.fps, settings.contact_speed_interval, centred=False)
    height = sites[..., 2]
    hovering = ((speed < HOVER_SPEED) & (height > settings.contact_max_height) & (height < 0.25)).any(axis=1)
    unsupported = hovering & ~contacts.any(axis=1)
    sunk = sites[..., 2].min(axis=1) < -MAX_SINK
    return unsupported.mean() <= MAX_IMPLAUSIBLE_FRACTION and sunk.mean() <= MAX_IMPLAUSIBLE_FRACTION


def split_by_subject(files: list[Path],
                     test_subjects: tuple[str, ...] = TEST_SUBJECTS) -> tuple[list[Path], list[Path]]:
    """(train, test) files: a file is in test when its CMU subject (`cmu_subject`) is in test_subjects."""
    test = [f for f in files if cmu_subject(f) in test_subjects]
    train = [f for f in files if cmu_subject(f) not in test_subjects]
    return train, test


def vary_proportions(clip: MocapClip, rng: np.random.Generator, settings: SyntheticSettings) -> MocapClip:
    """The clip on a body of other proportions, with every foot-floor contact kept.

    The upper body (spine and above, arms) is scaled about the pelvis, the arms about the shoulders, then the
    whole body about the floor point below the clip's mean pelvis. Legs and feet keep their motion relative to
    the floor except for the uniform stature scale, so contacts stay contacts.
    """
    positions = clip.positions.copy()
    pelvis = positions[:, JOINT_INDEX["pelvis"]][:, None]
    upper_body_scale = rng.uniform(*settings.upper_body_scale_range)
    positions[:, _UPPER_BODY] = pelvis + upper_body_scale * (positions[:, _UPPER_BODY] - pelvis)
    arm_scale = rng.uniform(*settings.arm_scale_range)
    for side, arm in _ARMS.items():
        shoulder = positions[:, JOINT_INDEX[f"{side}_shoulder"]][:, None]
        positions[:, arm] = shoulder + arm_scale * (positions[:, arm] - shoulder)
    centre = np.append(clip.joint("pelvis")[:, :2].mean(axis=0), 0.0)
    positions = centre + rng.uniform(*settings.stature_scale_range) * (positions - centre)
    return replace(clip, positions=positions)


def _segment(clip: MocapClip, rng: np.random.Generator, max_seconds: float) -> MocapClip:
    """A random segment of at most max_seconds of the clip (the whole clip if it is shorter)."""
    length = int(round(max_seconds * clip.fps))
    if clip.num_frames <= length:
        return clip
    start = int(rng.integers(0, clip.num_frames - length + 1))
    part = slice(start, start + length)
    return replace(clip, positions=clip.positions[part], head_rotation=clip.head_rotation[part],
                   hand_rotations=clip.hand_rotations[part])


def _sequence_rng(seed: int, clip_name: str, variant: int) -> np.random.Generator:
    return np.random.default_rng([seed, zlib.crc32(clip_name.encode()), variant])


def synthesise(clip: MocapClip, variant: int, seed: int,
               settings: SyntheticSettings = SyntheticSettings()) -> SyntheticSequence:
    """One synthetic sequence of `clip` (see the module docstring); deterministic in (seed, clip.name, variant)."""
    rng = _sequence_rng(seed, f"{clip.skeleton}:{clip.name}", variant)
    clip = _segment(clip, rng, settings.max_seconds)
    if rng.random() < settings.reverse_probability:
        clip = replace(clip, positions=clip.positions[::-1], head_rotation=clip.head_rotation[::-1],
                       hand_rotations=clip.hand_rotations[::-1])
    clip = replace(clip, fps=clip.fps * float(rng.uniform(*settings.playback_speed_range)))
    contacts, stationary = motion_labels(clip.positions, clip.fps, settings.labels)
    hard = hard_frames(clip.positions[:, CONTACT_SITE_INDICES], clip.fps, contacts, settings.labels)
    body = vary_proportions(clip, rng, settings)
    fps = float(rng.uniform(*settings.fps_range))
    filmed = resample(body, fps)
    source_frames = np.minimum(np.rint(np.arange(filmed.num_frames) * clip.fps / fps).astype(int), clip.num_frames - 1)
    contacts, stationary, hard = contacts[source_frames], stationary[source_frames], hard[source_frames]
    image_size = (1080, 1920) if rng.random() < settings.portrait_probability else (1280, 720)
    K, R, t = random_camera(filmed, rng, image_size)
    observations, _ = make_observations(filmed, K, R, t, rng, settings.noise, image_size, settings.foot_keypoints)
    keypoints_2d, landmarks_3d = observations.keypoints_2d, observations.landmarks_3d
    if rng.random() < settings.mirror_probability:
        keypoints_2d = mirror_keypoints(keypoints_2d, image_size[0])
        landmarks_3d = landmarks_3d[:, list(MIRRORED)] * np.array([-1.0, 1.0, 1.0])
        contacts = contacts[:, MIRRORED_CONTACT_COLUMNS]
    return SyntheticSequence(
        name=f"{clip.name}#{variant}", subject=clip.subject, fps=fps, image_size=image_size,
        keypoints_2d=keypoints_2d.astype(np.float32), landmarks_3d=landmarks_3d.astype(np.float32),
        contacts=contacts, stationary=stationary, hard=hard,
    )


def load_clips(files: list[Path]) -> list[MocapClip]:
    """The usable clips (`usable_clip`) of the given BVH files."""
    return [clip for clip in map(load_mocap, files) if usable_clip(clip)]


def make_sequences(
    clips: list[MocapClip], seed: int, settings: SyntheticSettings = SyntheticSettings(), variants: int | None = None
) -> list[SyntheticSequence]:
    """`variants` (default settings.variants_per_clip) synthetic sequences of every clip, in clip order."""
    return list(iter_sequences(clips, seed, settings, variants))


def iter_sequences(
    clips: list[MocapClip], seed: int, settings: SyntheticSettings = SyntheticSettings(), variants: int | None = None
) -> Iterator[SyntheticSequence]:
    """`make_sequences` one at a time, so that a consumer keeping only what it needs of each holds no full list
    (the training set's sequences are several GB)."""
    count = settings.variants_per_clip if variants is None else variants
    return (synthesise(clip, variant, seed, settings) for clip in clips for variant in range(count))
