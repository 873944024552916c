"""Check the automatic contact labels of the Daz-skeleton CMU clips (issue 18).

For each clip of ../shared/data/mocap/{cmu_daz_cgspeed, cmu_daz_cgspeed_dance, cmu_raw_subject16}: frames, loader
notes, whether `usable_clip` accepts it, contact share, and the lowest sole site's height percentiles while in
contact. For the motions that are also on the CC3 avatar (subjects 1, 2, 5, 7), the agreement of the labels of the
same motion on both skeletons, after the best time shift within +-1 s.

    .venv/bin/python scripts/check_new_mocap.py [--data ../shared/data/mocap] > labels_check.txt
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physmocap.contacts.dataset import usable_clip
from physmocap.contacts.labels import CONTACT_SITE_INDICES, motion_labels
from physmocap.errors import InputError
from physmocap.mocap.bvh_reader import load_mocap


def agreement(a: np.ndarray, b: np.ndarray, max_shift: int) -> tuple[float, int]:
    """Best share of equal (frame, site) labels between a (T1, 4) and b (T2, 4) over time shifts."""
    best = (0.0, 0)
    for shift in range(-max_shift, max_shift + 1):
        lo_a, lo_b = max(0, shift), max(0, -shift)
        n = min(len(a) - lo_a, len(b) - lo_b)
        if n < 30:
            continue
        share = float((a[lo_a:lo_a + n] == b[lo_b:lo_b + n]).mean())
        best = max(best, (share, shift))
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=str(Path(__file__).resolve().parents[1].parent / "shared/data/mocap"))
    args = parser.parse_args()
    root = Path(args.data)
    rows, agreements = [], []
    for folder in ("cmu_daz_cgspeed", "cmu_daz_cgspeed_dance", "cmu_raw_subject16"):
        for path in sorted((root / folder).glob("*.bvh")):
            try:
                clip = load_mocap(path)
            except InputError as error:
                print(f"{folder}/{path.name}: NOT LOADED: {error}")
                continue
            contacts, _ = motion_labels(clip.positions, clip.fps)
            heights = clip.positions[:, CONTACT_SITE_INDICES, 2]
            in_contact = heights[contacts]
            usable = usable_clip(clip)
            rows.append((folder, clip.name, clip.subject, clip.num_frames, clip.fps, usable, contacts.mean()))
            line = (f"{folder}/{path.name}: subject {clip.subject}, {clip.num_frames} frames at {clip.fps:.0f} fps, "
                    f"usable {usable}, contact share {contacts.mean():.2f}, contact heights p5/p50/p95 "
                    + ("/".join(f"{100 * q:.1f}" for q in np.percentile(in_contact, [5, 50, 95])) + " cm"
                       if in_contact.size else "-")
                    + (f"; notes: {'; '.join(clip.notes)}" if clip.notes else ""))
            twin = root / "cmu_iclone_cc3_retarget" / f"0{path.name}"
            if folder == "cmu_daz_cgspeed" and twin.is_file():
                other = load_mocap(twin)
                other_contacts, _ = motion_labels(other.positions, other.fps)
                share, shift = agreement(contacts, other_contacts, int(clip.fps))
                agreements.append(share)
                line += f"; labels agree with CC3 {twin.name}: {share:.3f} (shift {shift})"
            print(line)
    usable = [r for r in rows if r[5]]
    print(f"\n{len(rows)} clips loaded, {len(usable)} usable, "
          f"{sum(r[3] / r[4] for r in usable) / 60:.1f} usable minutes")
    if agreements:
        print(f"Daz vs CC3 label agreement on the same motions: median {np.median(agreements):.3f}, "
              f"min {np.min(agreements):.3f} over {len(agreements)} pairs")


if __name__ == "__main__":
    main()
