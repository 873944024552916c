"""Where MediaPipe puts the heel, ankle and foot_index keypoints of a flat standing foot, against where the
synthetic training data put them on the Daz and the CC3 skeletons in the same motions (issue 18).

Real: the four calibrated, synchronised Pose2Sim views of a man balancing on his left leg (the right foot is up
throughout, the left flat), triangulated (linear DLT, `measure_mediapipe_noise.triangulate`) from `--views`
(default 2, 3, 4: the views without hand labels; the labelled view 1 is only reported). Frames where the left
ankle is within 5 cm of its median (the standing foot; this drops a foot swap of one view) give the flat foot's
geometry in its own frame: Z up (the Qualisys world's floor is z = const), forward the horizontal heel ->
foot_index direction.

Synthetic: the landmarks `synthetic.landmarks_from_clip` makes (heel and foot_index from the sole sites, ankle the
joint) of the Daz and CC3 retargets of the training subjects 1, 2, 5, 7 (paired and aligned in time as in
`contact_daz_geometry.py`), in flat stances (the CC3 labels put the foot's heel and toe in contact, all its sites
slower than STILL_SPEED on both skeletons) and in flat one-legged stances (besides, the other foot's heel and toe
lifted on the CC3 labels).

Printed per source, medians (cm, and over the heel -> foot_index horizontal length F): heel above foot_index,
ankle above heel, heel behind and foot_index ahead of the ankle (horizontal), and the pitch of the heel ->
foot_index line (degrees, positive: heel higher). Then in 2D, through each real camera: MediaPipe's heel below its
foot_index and below its ankle (image y, in person sizes, `features.person_size`), against the synthetic median
flat foot of each skeleton scaled to the real F and set on the real foot (its ankle, its heading), projected with
the same camera. Last, per training folder: the share of foot-frames with the toe in contact and the heel lifted
(`labels.hard_frames`' raised heel), which teaches the networks what a heel raised a few cm looks like.

    PYTHONPATH=src .venv/bin/python scripts/contact_foot_keypoints.py [--views 2,3,4] [--foot-keypoints mediapipe]
        [--no-folders]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from contact_daz_geometry import SUBJECTS, best_shift, overlap  # noqa: E402
from measure_mediapipe_noise import pose2sim_cameras, triangulate  # noqa: E402

from physmocap.contacts.dataset import TEST_SUBJECTS, load_clips, mocap_files  # noqa: E402
from physmocap.contacts.features import person_size, select_keypoints  # noqa: E402
from physmocap.contacts.labels import CONTACT_SITE_INDICES, RAISED_HEEL_MAX_HEIGHT, motion_labels  # noqa: E402
from physmocap.contacts.real_videos import REAL_VIDEOS, cached_detection  # noqa: E402
from physmocap.landmarks import LANDMARK_INDEX  # noqa: E402
from physmocap.mocap.bvh_reader import STILL_SPEED, cmu_subject, load_mocap  # noqa: E402
from physmocap.mocap.synthetic import FOOT_KEYPOINTS, landmarks_from_clip, project  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"
DETECTIONS = REPO / "runs" / "contacts" / "detections"
STANDING_ANKLE_RADIUS = 0.05  # m: frames whose left ankle is further from its median are not the standing foot
FOOT_PARTS = ("ankle", "heel", "foot_index")
SHAPE_COLUMNS = ("heel above foot_index", "ankle above heel", "heel behind ankle", "foot_index ahead of ankle")


def foot_frame_shape(ankle: np.ndarray, heel: np.ndarray, toe: np.ndarray) -> np.ndarray:
    """(N, 6) per foot-frame (points (N, 3), Z up): heel above foot_index, ankle above heel, heel behind the
    ankle, foot_index ahead of it (horizontal, along the heel -> foot_index heading), F (the heel -> foot_index
    horizontal length), all metres, and the heel -> foot_index pitch, degrees (positive: heel higher)."""
    flat = (toe - heel)[:, :2]
    length = np.linalg.norm(flat, axis=1)
    heading = flat / length[:, None]
    behind = np.sum((ankle - heel)[:, :2] * heading, axis=1)
    ahead = np.sum((toe - ankle)[:, :2] * heading, axis=1)
    rise = heel[:, 2] - toe[:, 2]
    return np.stack([rise, ankle[:, 2] - heel[:, 2], behind, ahead, length, np.degrees(np.arctan2(rise, length))],
                    axis=1)


def describe(name: str, shape: np.ndarray) -> str:
    median = np.median(shape, axis=0)
    parts = ", ".join(f"{column} {100 * median[k]:.1f} cm ({median[k] / median[4]:.3f} F)"
                      for k, column in enumerate(SHAPE_COLUMNS))
    return f"{name} ({len(shape)} foot-frames): {parts}; F {100 * median[4]:.1f} cm, pitch {median[5]:.1f} deg"


def real_standing_foot(views: list[int]) -> tuple[np.ndarray, np.ndarray, dict[int, object], list]:
    """Triangulated (T, 3, 3) left ankle, heel, foot_index of the Pose2Sim views, the standing frames (T,) bool,
    every view's observations and the cameras."""
    videos = {video.name: video for video in REAL_VIDEOS}
    observations = {k: cached_detection(videos[f"pose2sim_cam0{k}"], SHARED / "videos", DETECTIONS)
                    for k in range(1, 5)}
    cameras = pose2sim_cameras()
    projections = [cameras[k - 1][0] @ np.hstack([cameras[k - 1][1], cameras[k - 1][2][:, None]]) for k in views]
    pixels = np.stack([observations[k].keypoints_2d[..., :2] for k in views])
    points = triangulate(projections, pixels)
    foot = points[:, [LANDMARK_INDEX[f"left_{part}"] for part in FOOT_PARTS]]
    standing = np.linalg.norm(foot[:, 0] - np.median(foot[:, 0], axis=0), axis=1) < STANDING_ANKLE_RADIUS
    return foot, standing, observations, cameras


def synthetic_flat_feet(foot_keypoints: str) -> dict[str, dict[str, np.ndarray]]:
    """Skeleton -> {"flat", "one-legged"}: (N, 6) `foot_frame_shape` rows of the paired training clips, with the
    heel and foot_index keypoints of `landmarks_from_clip(clip, foot_keypoints)`."""
    root = SHARED / "mocap"
    rows: dict[str, dict[str, list[np.ndarray]]] = {s: {"flat": [], "one-legged": []} for s in ("Daz", "CC3")}
    for path in sorted((root / "cmu_daz_cgspeed").glob("*.bvh")):
        twin = root / "cmu_iclone_cc3_retarget" / f"0{path.name}"
        if cmu_subject(path) not in SUBJECTS or not twin.is_file():
            continue
        daz, cc3 = load_mocap(path), load_mocap(twin)
        if abs(daz.fps - cc3.fps) > 1e-6:
            continue
        daz_contacts, _ = motion_labels(daz.positions, daz.fps)
        cc3_contacts, _ = motion_labels(cc3.positions, cc3.fps)
        shift = best_shift(daz_contacts, cc3_contacts, int(daz.fps))
        _, reference = overlap(daz_contacts, cc3_contacts, shift)
        landmarks = overlap(landmarks_from_clip(daz, foot_keypoints), landmarks_from_clip(cc3, foot_keypoints), shift)
        sites = [overlap(daz.positions[:, CONTACT_SITE_INDICES], cc3.positions[:, CONTACT_SITE_INDICES], shift)[k]
                 for k in range(2)]
        still = [np.linalg.norm(np.gradient(s, axis=0), axis=-1) * daz.fps < STILL_SPEED for s in sites]
        for f, side in enumerate(("left", "right")):
            flat = (reference[:, 2 * f] & reference[:, 2 * f + 1] & still[0][:, 2 * f:2 * f + 2].all(axis=1)
                    & still[1][:, 2 * f:2 * f + 2].all(axis=1))
            other_up = ~reference[:, 2 * (1 - f)] & ~reference[:, 2 * (1 - f) + 1]
            for name, points in zip(("Daz", "CC3"), landmarks, strict=True):
                shape = foot_frame_shape(*(points[:, LANDMARK_INDEX[f"{side}_{part}"]] for part in FOOT_PARTS))
                rows[name]["flat"].append(shape[flat])
                rows[name]["one-legged"].append(shape[flat & other_up])
    return {name: {kind: np.concatenate(parts) for kind, parts in kinds.items()} for name, kinds in rows.items()}


def image_drops(ankle: np.ndarray, heel: np.ndarray, toe: np.ndarray, camera: tuple, scale: np.ndarray
                ) -> tuple[float, float]:
    """Median heel below foot_index and heel below ankle in the image (y down), person sizes; points (N, 3) world."""
    K, R, t = camera
    (a, h, f), _ = project(np.stack([ankle, heel, toe]), K, R, t)
    return float(np.median((h[:, 1] - f[:, 1]) / scale)), float(np.median((h[:, 1] - a[:, 1]) / scale))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", default="2,3,4", help="Pose2Sim views to triangulate from (1 has hand labels)")
    parser.add_argument("--foot-keypoints", choices=FOOT_KEYPOINTS, default="sole",
                        help="the synthetic heel and foot_index keypoints (SyntheticSettings.foot_keypoints)")
    parser.add_argument("--no-folders", action="store_true", help="skip the per-folder raised-heel shares")
    args = parser.parse_args()
    views = [int(v) for v in args.views.split(",")]
    foot, standing, observations, cameras = real_standing_foot(views)
    real = foot_frame_shape(*(foot[standing, k] for k in range(3)))
    print(describe(f"MediaPipe, Pose2Sim views {args.views} triangulated, standing left foot", real))
    synthetic = synthetic_flat_feet(args.foot_keypoints)
    for name, kinds in synthetic.items():
        for kind, shape in kinds.items():
            print(describe(f"synthetic {name}, {kind} stances", shape))

    print("\nIn 2D (image y down, person sizes): heel below foot_index / heel below ankle, median over the standing "
          "frames")
    real_median = np.median(real, axis=0)
    for k in range(1, 5):
        obs = observations[k]
        keypoints = obs.keypoints_2d[standing]
        scale = person_size(select_keypoints(keypoints, obs.valid[standing])[None])[0]
        xy = {part: keypoints[:, LANDMARK_INDEX[f"left_{part}"], :2] for part in FOOT_PARTS}
        seen = (np.median((xy["heel"][:, 1] - xy["foot_index"][:, 1]) / scale),
                np.median((xy["heel"][:, 1] - xy["ankle"][:, 1]) / scale))
        line = f"view {k}: MediaPipe {seen[0]:+.4f} / {seen[1]:+.4f}"
        ankle = foot[standing, 0]
        flat = (foot[standing, 2] - foot[standing, 1])[:, :2]
        heading = np.column_stack([flat / np.linalg.norm(flat, axis=1, keepdims=True), np.zeros(len(flat))])
        for name, kinds in synthetic.items():
            shape = np.median(kinds["flat"], axis=0) * real_median[4] / np.median(kinds["flat"], axis=0)[4]
            heel = ankle - shape[2] * heading - np.array([0.0, 0.0, shape[1]])
            toe = heel + real_median[4] * heading - np.array([0.0, 0.0, shape[0]])
            drops = image_drops(ankle, heel, toe, cameras[k - 1], scale)
            line += f"; synthetic {name} foot {drops[0]:+.4f} / {drops[1]:+.4f}"
        print(line)

    if args.no_folders:
        return
    print("\nRaised heels per training folder (subjects 1, 2, 5, 7 and every other non-test subject): share of "
          "foot-frames with the toe in contact and the heel lifted below RAISED_HEEL_MAX_HEIGHT, and their median "
          "heel height above the toe site")
    files = [f for f in mocap_files(SHARED / "mocap") if cmu_subject(f) not in TEST_SUBJECTS]
    for folder in sorted({f.parent.name for f in files}):
        shares, rises, frames = [], [], 0
        for clip in load_clips([f for f in files if f.parent.name == folder]):
            contacts, _ = motion_labels(clip.positions, clip.fps)
            sites = clip.positions[:, CONTACT_SITE_INDICES]
            for heel, toe in ((0, 1), (2, 3)):
                raised = contacts[:, toe] & ~contacts[:, heel] & (sites[:, heel, 2] < RAISED_HEEL_MAX_HEIGHT)
                shares.append(raised)
                rises.append(sites[raised, heel, 2] - sites[raised, toe, 2])
            frames += clip.num_frames
        share = np.concatenate(shares).mean()
        print(f"{folder}: {frames} frames, raised heel in {share:.3f} of foot-frames, heel "
              f"{100 * np.median(np.concatenate(rises)):.1f} cm above the toe site (median)")


if __name__ == "__main__":
    main()
