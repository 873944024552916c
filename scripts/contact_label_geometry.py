"""Check the derived heel and toe sites, and the floor, that the contact labels are computed from, against the
BVH's own joints.

Neither skeleton has a heel joint (`bvh_reader.sole_sites` derives heel and toe from the ankle, the MTP joint and
a flat-foot pitch measured per clip), and the floor is placed under the planted sites (`load_mocap`). Per clip
and foot this prints
- flat stance: where heel and toe are both still (under 0.2 m/s) and labelled in contact, the median heights of
  heel and toe (a floor or a heel in the wrong place shows as heights away from 0) and of the ankle joint;
- raised heel: where the toe is labelled in contact and the heel is not, 5-12 cm up and slower than the speed
  threshold (a stance on the ball of the foot, or a label error if the heel were really down): the median heel
  height, how far the BVH's ankle joint is above its flat-stance height (10th percentile and median), and the
  median ratio of ankle rise to heel rise. A foot that turns about its MTP joint raises the ankle by about 0.7
  times the heel (horizontal ankle-MTP over heel-MTP distance); a derived heel raised by a wrong pitch or floor
  would leave the ankle where it was.
With --plots DIR, one figure per clip: heights of the BVH's ankle, MTP and toe End Site (shifted by the loader's
floor) against the derived heel and toe, and the ankle -> MTP pitch.

    .venv/bin/python scripts/contact_label_geometry.py [--clips 131_02 006_08 ...] [--plots DIR]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import physmocap  # noqa: F401 - single-threaded BLAS
import numpy as np

from physmocap.contacts.labels import motion_labels
from physmocap.mocap import bvh_reader
from physmocap.mocap.bvh_reader import JOINT_INDEX, load_mocap

MOCAP = Path(__file__).resolve().parents[2] / "shared" / "data" / "mocap"
SIDES = ("left", "right")


def foot_table(clip: bvh_reader.MocapClip) -> list[str]:
    """One line per foot: flat-stance heights and the ankle's rise under raised heels (module docstring)."""
    positions = clip.positions
    contacts, _ = motion_labels(positions, clip.fps)
    lines = []
    for f, side in enumerate(SIDES):
        heel, toe, ankle = (positions[:, JOINT_INDEX[f"{side}_{part}"]] for part in ("heel", "toe", "ankle"))
        heel_down, toe_down = contacts[:, 2 * f], contacts[:, 2 * f + 1]
        still = bvh_reader._still(heel, clip.fps) & bvh_reader._still(toe, clip.fps)
        flat = heel_down & toe_down & still
        speed = np.linalg.norm(np.gradient(heel, axis=0), axis=1) * clip.fps
        raised = ~heel_down & toe_down & (heel[:, 2] > 0.05) & (heel[:, 2] < 0.12) & (speed < 1.0)
        if flat.sum() < 5:
            lines.append(f"  {side}: fewer than 5 flat-stance frames")
            continue
        text = (f"  {side}: flat stance {flat.sum()} frames, heel {100 * np.median(heel[flat, 2]):.1f} cm, toe "
                f"{100 * np.median(toe[flat, 2]):.1f} cm, ankle {100 * np.median(ankle[flat, 2]):.1f} cm")
        if raised.sum() >= 5:
            rise = ankle[raised, 2] - np.median(ankle[flat, 2])
            ratio = rise / (heel[raised, 2] - np.median(heel[flat, 2]))
            text += (f"; raised heel {raised.sum()} frames at {100 * np.median(heel[raised, 2]):.1f} cm, ankle up "
                     f"{100 * np.percentile(rise, 10):.1f} / {100 * np.median(rise):.1f} cm (p10 / median), "
                     f"ratio {np.median(ratio):.2f}")
        lines.append(text)
    return lines


def plot_clip(path: Path, clip: bvh_reader.MocapClip, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    bvh = bvh_reader.read_bvh(path)
    layout = bvh_reader._skeleton_layout(bvh, str(path))
    world = bvh_reader.forward_kinematics(bvh, layout.units_to_metres)[0] @ bvh_reader.BVH_TO_WORLD.T
    world = world[len(world) - clip.num_frames:]
    # the loader's vertical shift (floor, levelling) at the ankle
    shift = world[:, bvh.index(layout.points["left_ankle"]), 2] - clip.joint("left_ankle")[:, 2]
    time = np.arange(clip.num_frames) / clip.fps
    figure, axes = plt.subplots(3, 1, figsize=(14, 10), sharex=True)
    for f, side in enumerate(SIDES):
        ankle = world[:, bvh.index(layout.points[f"{side}_ankle"])]
        mtp = world[:, bvh.index(layout.toe_bases[f])]
        end = [j for j, joint in enumerate(bvh.joints) if joint.parent == bvh.index(layout.toe_bases[f])]
        axis = axes[f]
        axis.plot(time, 100 * (ankle[:, 2] - shift), label="BVH ankle")
        axis.plot(time, 100 * (mtp[:, 2] - shift), label="BVH MTP")
        if end:
            axis.plot(time, 100 * (world[:, end[0], 2] - shift), label="BVH toe child / End Site")
        axis.plot(time, 100 * clip.joint(f"{side}_heel")[:, 2], "k", lw=2, label="derived heel")
        axis.plot(time, 100 * clip.joint(f"{side}_toe")[:, 2], "m", lw=2, label="derived toe")
        axis.axhline(0.0, color="k", lw=0.5)
        axis.axhline(5.0, color="k", ls=":")
        axis.set_ylim(-8, 30)
        axis.set_ylabel(f"{side}, cm above the floor")
        along = mtp - ankle
        axes[2].plot(time, np.degrees(np.arcsin(-along[:, 2] / np.linalg.norm(along, axis=1))),
                     label=f"{side} ankle -> MTP pitch, degrees")
    axes[0].legend(ncol=5, loc="upper right")
    axes[2].legend()
    axes[2].set_xlabel("s")
    axes[0].set_title(f"{clip.name} ({clip.skeleton})")
    figure.tight_layout()
    figure.savefig(out / f"foot_geometry_{clip.name}.png", dpi=70)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", nargs="*", help="clip names (default: all)")
    parser.add_argument("--plots", type=Path, help="write one figure per clip here")
    args = parser.parse_args()
    for path in sorted(MOCAP.rglob("*.bvh")):
        if args.clips and path.stem not in args.clips:
            continue
        clip = load_mocap(path)
        print(f"{clip.name} ({clip.skeleton}, {clip.fps:.0f} fps)")
        print("\n".join(foot_table(clip)))
        if args.plots is not None:
            args.plots.mkdir(parents=True, exist_ok=True)
            plot_clip(path, clip, args.plots)


if __name__ == "__main__":
    main()
