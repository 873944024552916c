"""Per-site agreement of the Daz skeleton's contact labels with the CC3 skeleton's, and the sole sites' heights in
flat stances on both (issue 18).

The same CMU motions exist on both skeletons for the training subjects 1, 2, 5, 7 (cmu_daz_cgspeed/SS_TT.bvh and
cmu_iclone_cc3_retarget/0SS_TT.bvh). The CC3 labels are the reference: for each site (left/right heel/toe), the
contact recall (CC3 in contact, Daz too) and the lift recall (CC3 lifted, Daz too) of the Daz labels, after the
best time shift within +-1 s. A flat stance is a frame where the CC3 labels put the heel and toe of a foot in
contact and both are slower than STILL_SPEED on both skeletons; the script prints, on each skeleton, the median
height of each site above the floor there, the heel-minus-toe height, the ankle's height above the heel site (per
pair, and the per-pair Daz minus CC3 gap that `DAZ_TOE_BASE_ABOVE_SOLE` was fitted to) and the horizontal heel-ankle
and ankle-toe distances. Test subjects (6, 9, 94, 131) are never read.

    PYTHONPATH=src .venv/bin/python scripts/contact_daz_geometry.py [--data ../shared/data/mocap]
        [--toe-base-above-sole 0.20 --default-pitch 15]   (the geometry before the fit)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physmocap.contacts.labels import CONTACT_SITE_INDICES, CONTACT_SITES, motion_labels
from physmocap.mocap import bvh_reader
from physmocap.mocap.bvh_reader import (
    HEEL_BEHIND_ANKLE,
    JOINT_INDEX,
    STILL_SPEED,
    TOE_AHEAD_OF_TOE_BASE,
    MocapClip,
    load_mocap,
)

SUBJECTS = ("1", "2", "5", "7")


def best_shift(a: np.ndarray, b: np.ndarray, max_shift: int) -> int:
    """The shift of b against a (frames) that makes most (frame, site) labels equal: a[t + s] ~ b[t] for s >= 0."""
    def share(shift: int) -> float:
        lo_a, lo_b = max(0, shift), max(0, -shift)
        n = min(len(a) - lo_a, len(b) - lo_b)
        return float((a[lo_a:lo_a + n] == b[lo_b:lo_b + n]).mean()) if n >= 30 else 0.0
    return max(range(-max_shift, max_shift + 1), key=share)


def overlap(a: np.ndarray, b: np.ndarray, shift: int) -> tuple[np.ndarray, np.ndarray]:
    """The overlapping frames of a and b at a time shift (`best_shift`)."""
    lo_a, lo_b = max(0, shift), max(0, -shift)
    n = min(len(a) - lo_a, len(b) - lo_b)
    return a[lo_a:lo_a + n], b[lo_b:lo_b + n]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared/data/mocap"))
    parser.add_argument("--toe-base-above-sole", type=float, default=bvh_reader.DAZ_TOE_BASE_ABOVE_SOLE,
                        help="Daz End Site above the sole, fraction of ankle -> End Site (0.20 before the fit)")
    parser.add_argument("--default-pitch", type=float, default=bvh_reader.DAZ_DEFAULT_FOOT_PITCH_DEGREES,
                        help="Daz flat-foot pitch of never-still feet, degrees (15 before the fit)")
    args = parser.parse_args()
    # `_daz_layout` reads these module settings at each load: measure other values without editing the reader.
    bvh_reader.DAZ_TOE_BASE_ABOVE_SOLE = args.toe_base_above_sole
    bvh_reader.DAZ_DEFAULT_FOOT_PITCH_DEGREES = args.default_pitch
    root = Path(args.data)
    daz_labels, cc3_labels, daz_heights, cc3_heights, flat = [], [], [], [], []
    shapes: dict[str, list[np.ndarray]] = {"Daz": [], "CC3": []}
    ankle_gaps: list[float] = []  # per pair with flat stances: Daz minus CC3 median ankle height above the heel site
    for path in sorted((root / "cmu_daz_cgspeed").glob("*.bvh")):
        twin = root / "cmu_iclone_cc3_retarget" / f"0{path.name}"
        daz = load_mocap(path)
        if daz.subject not in SUBJECTS or not twin.is_file():
            continue
        cc3 = load_mocap(twin)
        if abs(daz.fps - cc3.fps) > 1e-6:
            print(f"{path.name}: frame rates differ ({daz.fps}, {cc3.fps}), skipped")
            continue
        daz_contacts, _ = motion_labels(daz.positions, daz.fps)
        cc3_contacts, _ = motion_labels(cc3.positions, cc3.fps)
        shift = best_shift(daz_contacts, cc3_contacts, int(daz.fps))
        a, b = overlap(daz_contacts, cc3_contacts, shift)
        daz_sites, cc3_sites = overlap(daz.positions[:, CONTACT_SITE_INDICES], cc3.positions[:, CONTACT_SITE_INDICES],
                                       shift)
        still = [np.linalg.norm(np.gradient(sites, axis=0), axis=-1) * daz.fps < STILL_SPEED
                 for sites in (daz_sites, cc3_sites)]
        # (T, 2) a foot in flat stance: CC3 heel and toe in contact, all four of its sites still.
        flat_foot = np.stack([b[:, 2 * f] & b[:, 2 * f + 1] & still[0][:, 2 * f:2 * f + 2].all(axis=1)
                              & still[1][:, 2 * f:2 * f + 2].all(axis=1) for f in range(2)], axis=1)
        daz_labels.append(a)
        cc3_labels.append(b)
        daz_heights.append(daz_sites[..., 2])
        cc3_heights.append(cc3_sites[..., 2])
        flat.append(flat_foot)
        for name, clip in (("Daz", daz), ("CC3", cc3)):
            shapes[name].append(_foot_shape(clip.positions, shift if name == "Daz" else -shift, flat_foot))
        pitches = " / ".join(",".join(f"{_flat_pitch_degrees(clip, side):.0f}" for side in ("left", "right"))
                             for clip in (daz, cc3))
        line = (f"{path.name} vs {twin.name}: shift {shift}, agreement {(a == b).mean():.3f}, "
                f"flat-foot pitch (left,right) Daz / CC3 {pitches} degrees")
        if flat_foot.any():
            ankle = [float(np.median(shapes[name][-1][:, 0])) for name in ("Daz", "CC3")]
            ankle_gaps.append(ankle[0] - ankle[1])
            level = [100 * _heel_minus_toe(sites[..., 2], flat_foot) for sites in (daz_sites, cc3_sites)]
            line += (f", flat stances: heel minus toe height Daz {level[0]:.1f} cm, CC3 {level[1]:.1f} cm; ankle above "
                     f"heel site Daz {100 * ankle[0]:.1f} cm, CC3 {100 * ankle[1]:.1f} cm ({int(flat_foot.sum())} "
                     "foot-frames)")
        print(line)
    a, b = np.concatenate(daz_labels), np.concatenate(cc3_labels)
    daz_z, cc3_z, flat_foot = np.concatenate(daz_heights), np.concatenate(cc3_heights), np.concatenate(flat)
    print(f"\n{len(daz_labels)} pairs, {len(a)} frames; overall agreement {(a == b).mean():.3f}")
    print("site        agreement  contact recall  lift recall  Daz contact share  CC3 contact share  "
          "flat-stance height Daz / CC3 (cm, median)")
    for column, site in enumerate(CONTACT_SITES):
        in_flat = flat_foot[:, column // 2]
        print(f"{site:<11} {(a[:, column] == b[:, column]).mean():9.3f}  {a[b[:, column], column].mean():14.3f}  "
              f"{(~a[~b[:, column], column]).mean():11.3f}  {a[:, column].mean():17.3f}  {b[:, column].mean():17.3f}  "
              f"{100 * np.median(daz_z[in_flat, column]):.1f} / {100 * np.median(cc3_z[in_flat, column]):.1f}")
    print(f"flat-stance heel minus toe height, median over {int(flat_foot.sum())} foot-frames: "
          f"Daz {100 * _heel_minus_toe(daz_z, flat_foot):.2f} cm, CC3 {100 * _heel_minus_toe(cc3_z, flat_foot):.2f} cm")
    gap_quartiles = 100 * np.percentile(ankle_gaps, [25, 50, 75])
    print(f"Daz minus CC3 flat-stance ankle height above the heel site, per pair: median {gap_quartiles[1]:.2f} cm, "
          f"quartiles {gap_quartiles[0]:.2f} / {gap_quartiles[2]:.2f} cm over {len(ankle_gaps)} pairs")
    for name, parts in shapes.items():
        ankle_up, heel_back, toe_ahead = np.median(np.concatenate(parts), axis=0)
        print(f"{name} flat-stance foot (median): ankle {100 * ankle_up:.1f} cm above the heel site, heel site "
              f"{100 * heel_back:.1f} cm behind it, toe site {100 * toe_ahead:.1f} cm ahead of it (horizontal)")


def _flat_pitch_degrees(clip: MocapClip, side: str) -> float:
    """The flat-foot pitch `load_mocap` gave a foot, read back from its rigid sole sites: with L the ankle -> MTP
    length, `sole_sites` puts the heel HEEL_BEHIND_ANKLE L behind the ankle along the sole and the toe
    L (cos p + HEEL_BEHIND_ANKLE + TOE_AHEAD_OF_TOE_BASE) ahead of the heel."""
    ankle, heel, toe = (clip.joint(f"{side}_{part}")[0] for part in ("ankle", "heel", "toe"))
    sole = np.linalg.norm(toe - heel)
    length = np.dot(ankle - heel, (toe - heel) / sole) / HEEL_BEHIND_ANKLE
    cos_pitch = sole / length - HEEL_BEHIND_ANKLE - TOE_AHEAD_OF_TOE_BASE
    return float(np.degrees(np.arccos(np.clip(cos_pitch, -1.0, 1.0))))


def _foot_shape(positions: np.ndarray, shift: int, flat_foot: np.ndarray) -> np.ndarray:
    """(N, 3) per flat-stance foot-frame: ankle height above the heel site, horizontal heel-ankle and ankle-toe
    distances (m). positions (T, 20, 3) of one skeleton, shift as in `overlap` (positive: this clip starts later)."""
    rows = []
    for side, f in (("left", 0), ("right", 1)):
        frames = np.flatnonzero(flat_foot[:, f]) + max(0, shift)
        ankle, heel, toe = (positions[frames, JOINT_INDEX[f"{side}_{part}"]] for part in ("ankle", "heel", "toe"))
        rows.append(np.stack([ankle[:, 2] - heel[:, 2], np.linalg.norm((ankle - heel)[:, :2], axis=1),
                              np.linalg.norm((toe - ankle)[:, :2], axis=1)], axis=1))
    return np.concatenate(rows)


def _heel_minus_toe(heights: np.ndarray, flat_foot: np.ndarray) -> float:
    """Median heel height minus toe height (m) over the flat-stance frames of both feet; heights (T, 4)."""
    differences = [heights[flat_foot[:, f], 2 * f] - heights[flat_foot[:, f], 2 * f + 1] for f in range(2)]
    joined = np.concatenate(differences)
    return float(np.median(joined)) if joined.size else float("nan")


if __name__ == "__main__":
    main()
